"""Colour conversions: sRGB <-> linear light, CIE L*a*b* (D65) and the CIEDE2000 difference.

sRGB values are what users pick, in [0, 1]; shading and the blending of thin fibres work in
linear light. L*a*b* and Delta E2000 measure how far a rendered colour is from an asked one.
"""

from functools import lru_cache
from pathlib import Path

import numpy as np

# the reference swatch's response per channel, written by `python -m render.swatch --write`
RESPONSE_PATH = Path(__file__).parent / "data" / "colour_response.npz"

# linear sRGB (D65) -> CIE XYZ
_RGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                        [0.2126729, 0.7151522, 0.0721750],
                        [0.0193339, 0.1191920, 0.9503041]])
_WHITE_D65 = np.array([0.95047, 1.0, 1.08883])


def srgb_to_linear(c) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear light, same shape, float64."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c) -> np.ndarray:
    """Linear light -> sRGB-encoded values, same shape, float64 (clipped to [0, 1])."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1.0 / 2.4) - 0.055)


def srgb_colour(name: str, value) -> np.ndarray:
    """`value` checked as one sRGB colour: 3 values in [0, 1], (3,) float64; a ValueError
    naming `name` otherwise."""
    c = np.asarray(value, dtype=np.float64)
    if c.shape != (3,) or not np.all((c >= 0.0) & (c <= 1.0)):
        raise ValueError(f"{name} must be 3 sRGB values in [0, 1], got {value!r}")
    return c


def linear_to_lab(rgb) -> np.ndarray:
    """Linear sRGB (..., 3) -> CIE L*a*b* (..., 3) under D65 (L* in [0, 100])."""
    xyz = np.asarray(rgb, dtype=np.float64) @ _RGB_TO_XYZ.T / _WHITE_D65
    d = 6.0 / 29.0
    f = np.where(xyz > d ** 3, np.cbrt(xyz), xyz / (3.0 * d * d) + 4.0 / 29.0)
    return np.stack([116.0 * f[..., 1] - 16.0, 500.0 * (f[..., 0] - f[..., 1]),
                     200.0 * (f[..., 1] - f[..., 2])], axis=-1)


def delta_e2000(lab1, lab2) -> np.ndarray:
    """CIEDE2000 colour difference of L*a*b* colours (..., 3) (Sharma et al. 2005), (...)."""
    l1, a1, b1 = np.moveaxis(np.asarray(lab1, dtype=np.float64), -1, 0)
    l2, a2, b2 = np.moveaxis(np.asarray(lab2, dtype=np.float64), -1, 0)
    c_bar = 0.5 * (np.hypot(a1, b1) + np.hypot(a2, b2))
    g = 0.5 * (1.0 - np.sqrt(c_bar ** 7 / (c_bar ** 7 + 25.0 ** 7)))
    a1p, a2p = (1.0 + g) * a1, (1.0 + g) * a2
    c1p, c2p = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1p = np.degrees(np.arctan2(b1, a1p)) % 360.0
    h2p = np.degrees(np.arctan2(b2, a2p)) % 360.0
    dl, dc = l2 - l1, c2p - c1p
    dh = h2p - h1p
    dh = np.where(dh > 180.0, dh - 360.0, np.where(dh < -180.0, dh + 360.0, dh))
    dh = np.where(c1p * c2p == 0.0, 0.0, dh)
    dH = 2.0 * np.sqrt(c1p * c2p) * np.sin(np.radians(0.5 * dh))
    l_bar, cp_bar = 0.5 * (l1 + l2), 0.5 * (c1p + c2p)
    hsum = h1p + h2p
    h_bar = np.where(np.abs(h1p - h2p) > 180.0,
                     np.where(hsum < 360.0, 0.5 * (hsum + 360.0), 0.5 * (hsum - 360.0)),
                     0.5 * hsum)
    h_bar = np.where(c1p * c2p == 0.0, hsum, h_bar)
    t = (1.0 - 0.17 * np.cos(np.radians(h_bar - 30.0)) + 0.24 * np.cos(np.radians(2.0 * h_bar))
         + 0.32 * np.cos(np.radians(3.0 * h_bar + 6.0)) - 0.20 * np.cos(np.radians(4.0 * h_bar - 63.0)))
    s_l = 1.0 + 0.015 * (l_bar - 50.0) ** 2 / np.sqrt(20.0 + (l_bar - 50.0) ** 2)
    s_c = 1.0 + 0.045 * cp_bar
    s_h = 1.0 + 0.015 * cp_bar * t
    r_c = 2.0 * np.sqrt(cp_bar ** 7 / (cp_bar ** 7 + 25.0 ** 7))
    r_t = -np.sin(np.radians(60.0 * np.exp(-(((h_bar - 275.0) / 25.0) ** 2)))) * r_c
    return np.sqrt((dl / s_l) ** 2 + (dc / s_c) ** 2 + (dH / s_h) ** 2
                   + r_t * (dc / s_c) * (dH / s_h))


def response_sigma_grid() -> np.ndarray:
    """Absorptions sigma_a [1/fibre radius] at which the swatch response is tabulated: 0 to 64,
    uniform in log(1 + sigma_a / 0.1) (dense where light hair changes fast), (24,)."""
    return np.minimum(0.1 * np.expm1(np.linspace(0.0, np.log1p(64.0 / 0.1), 24)), 64.0)


@lru_cache(maxsize=1)
def _response() -> tuple[np.ndarray, np.ndarray]:
    data = np.load(RESPONSE_PATH)
    return data["sigma"], data["response"]


def body_colour(linear, white, black) -> np.ndarray:
    """The hair colour a swatch's mean linear radiance `linear` (..., 3) stands for: its light
    above that of fully absorbing fibres (`black`: the colourless surface reflection, which
    no pigment changes), relative to that of unpigmented fibres (`white`), per channel."""
    w, b = np.asarray(white, np.float64), np.asarray(black, np.float64)
    return (np.asarray(linear, np.float64) - b) / (w - b)


def sigma_for_colour(linear_rgb) -> np.ndarray:
    """Absorption sigma_a (..., 3) [1/fibre radius] whose reference swatch (`render.swatch`)
    has body colour (`body_colour`) `linear_rgb` (..., 3) with the default fibre parameters:
    each channel's stored response inverted, linear in (log(1 + sigma_a / 0.1), log colour)
    between grid points; black asks for the grid's last absorption."""
    sigma, f = _response()
    u = np.log1p(sigma / 0.1)
    c = np.clip(np.asarray(linear_rgb, dtype=np.float64), 1e-9, 1.0)
    rel = body_colour(f, f[0], f[-1])
    out = np.empty(c.shape)
    for ch in range(3):
        # the response falls with sigma_a to ~0 (a few sigma_a in): interpolate over the grid
        # points where it still falls, in increasing log colour; darker asks get the next point
        r = rel[:, ch]
        keep = [0]
        for k in range(1, len(r)):
            if 1e-6 < r[k] < r[keep[-1]]:
                keep.append(k)
            else:
                break
        keep = np.array(keep)
        darkest = u[min(keep[-1] + 1, len(u) - 1)]
        out[..., ch] = 0.1 * np.expm1(np.interp(np.log(c[..., ch]), np.log(r[keep][::-1]),
                                                 u[keep][::-1], left=darkest, right=0.0))
    return out
