"""The colour a hair colour means: the reference swatch, its measurement, and the response table.

A hair colour asked for (sRGB in [0, 1], `Hair(colours=...)` or `HairMaterial.from_colour`)
is defined as the **mean colour of the reference swatch** rendered with it:

- the swatch: a dense slab of hanging, slightly wavy strands (80 um fibres, 6 x 6 cm, 1 cm
  deep, opaque: a pixel's hair alpha > 0.99), seen face-on from the direction
  `VIEW` = (0, 1, 0.25) with z up, as the shipped scenes see their subjects;
- the light: `three_point_lights(VIEW)`, the lights every shipped scene is rendered with
  (warm key, cool fill, rim, ambient), black background, default `RenderSettings`;
- the measurement: the mean linear radiance of the central half of the swatch's pixels,
  encoded as sRGB.

Under these lights each colour channel's radiance depends only on that channel's absorption
sigma_a (the fibre shading and the dual scattering work per channel; opacity and shadows do
not depend on colour), so the response is one monotone curve per channel, F_c(sigma_a).
`measure_response` renders the swatch for a grid of sigma_a (three grid points per render,
one per channel) and `write_response` stores the curves in render/data/colour_response.npz
(`python -m render.swatch --write`; rerun it when the shading changes: tests/test_render.py
checks that asked colours still come back within Delta E2000 3). `render.colour` inverts the
stored curves.
"""

import argparse
from pathlib import Path

import numpy as np

from .camera import Camera
from .colour import (RESPONSE_PATH, body_colour, delta_e2000, linear_to_lab, linear_to_srgb,
                     response_sigma_grid, srgb_to_linear)
from .fibre import HairMaterial
from .frame import render_buffers
from .geometry import Hair
from .shading import three_point_lights

VIEW = (0.0, 1.0, 0.25)
UP = (0.0, 0.0, 1.0)


def _frame():
    d = np.asarray(VIEW, float) / np.linalg.norm(VIEW)
    right = np.cross(-d, UP)
    right /= np.linalg.norm(right)
    up = np.cross(right, -d)
    return d, right, up


def swatch_points(n_strands: int = 8000, n_segments: int = 24, seed: int = 0) -> np.ndarray:
    """The reference swatch's strands [m], (n_strands, n_segments + 1, 3): hanging along the
    view's up, spread 6 cm across and 1 cm in depth behind the origin, wavy by +-1.5 mm."""
    rng = np.random.default_rng(seed)
    d, right, up = _frame()
    s = np.linspace(-0.03, 0.03, n_segments + 1)[None, :, None]
    across = rng.uniform(-0.03, 0.03, size=(n_strands, 1, 1))
    depth = rng.uniform(0.0, 0.01, size=(n_strands, 1, 1))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(n_strands, 1, 1))
    wave = 0.0015 * np.sin(2.0 * np.pi * s / 0.02 + phase)
    return (up * s + right * (across + wave) - d * depth).astype(np.float64)


def swatch_camera(size: int = 64) -> Camera:
    """A size x size camera 1 m away along VIEW seeing the swatch's central 4 cm."""
    d, _, _ = _frame()
    fov = float(np.degrees(2.0 * np.arctan(0.02)))
    return Camera(eye=tuple(d * 1.0), target=(0.0, 0.0, 0.0), up=UP, fov_y=fov, width=size,
                  height=size)


def swatch_linear(hair_kwargs: dict, size: int = 64, seed: int = 0) -> np.ndarray:
    """Mean linear radiance (3,) of the central half of the reference swatch rendered with
    `Hair(points=swatch, widths=8e-5, **hair_kwargs)`; refuses a swatch that is not opaque."""
    hair = Hair(points=swatch_points(seed=seed), widths=8e-5, **hair_kwargs)
    out = render_buffers(swatch_camera(size), hair=hair, lights=three_point_lights(VIEW, UP),
                         background=(0.0, 0.0, 0.0))
    q = size // 4
    centre = (slice(q, size - q), slice(q, size - q))
    if out["alpha"][centre].min() < 0.99:
        raise RuntimeError(f"reference swatch not opaque: min alpha {out['alpha'][centre].min():.3f}")
    return out["rgb"][centre].reshape(-1, 3).mean(axis=0).astype(np.float64)


def swatch_ends(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The swatch's mean linear radiance (3,) with unpigmented (sigma_a = 0: white) and with
    fully absorbing (the grid's last sigma_a: black) fibres of the default material."""
    m = HairMaterial()
    end = float(response_sigma_grid()[-1])
    return tuple(swatch_linear({"material": HairMaterial(sigma_a=(s, s, s), beta_m=m.beta_m,
                                                         beta_n=m.beta_n)}, seed=seed)
                 for s in (0.0, end))


def swatch_colour(colour, seed: int = 0, ends=None) -> np.ndarray:
    """The rendered colour, sRGB (3,), of hair colour `colour` (sRGB): `body_colour` of the
    reference swatch rendered with `Hair(colours=colour)`; ends: `swatch_ends(seed)` if given."""
    white, black = swatch_ends(seed) if ends is None else ends
    return linear_to_srgb(body_colour(swatch_linear({"colours": colour}, seed=seed), white, black))


def measure_response(material: HairMaterial = HairMaterial()) -> np.ndarray:
    """F_c(sigma_a) (len(response_sigma_grid()), 3): the swatch's linear radiance per channel
    for each grid absorption, with the other parameters of `material`."""
    grid = response_sigma_grid()
    out = np.zeros((len(grid), 3))
    # render r carries grid point r + c in channel c: every grid point is measured in every
    # channel (the lights are tinted, so the channels' curves differ)
    for r in range(len(grid)):
        sigma = tuple(grid[(r + c) % len(grid)] for c in range(3))
        m = HairMaterial(sigma_a=sigma, beta_m=material.beta_m, beta_n=material.beta_n,
                         alpha_deg=material.alpha_deg, ior=material.ior)
        rgb = swatch_linear({"material": m})
        for c in range(3):
            out[(r + c) % len(grid), c] = rgb[c]
    return out


def write_response(path: Path = RESPONSE_PATH) -> np.ndarray:
    """Measure the default material's response and store it (sigma grid, F) at `path`."""
    f = measure_response()
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, sigma=response_sigma_grid(), response=f)
    return f


COLOURS = {"platinum": (0.90, 0.84, 0.70), "golden blonde": (0.78, 0.60, 0.36),
           "auburn": (0.55, 0.25, 0.13), "wind_straight brown": (0.55, 0.38, 0.20),
           "dark brown": (0.22, 0.13, 0.07), "black": (0.06, 0.05, 0.05)}


def colour_table(colours: dict = COLOURS, seed: int = 1) -> list[dict]:
    """Asked vs rendered swatch colour for each named sRGB colour (a swatch of another seed than
    the response's): {"name", "asked", "rendered" (sRGB), "delta_e" (CIEDE2000)}."""
    rows, ends = [], swatch_ends(seed)
    for name, asked in colours.items():
        got = swatch_colour(asked, seed=seed, ends=ends)
        de = float(delta_e2000(linear_to_lab(srgb_to_linear(asked)), linear_to_lab(srgb_to_linear(got))))
        rows.append({"name": name, "asked": np.asarray(asked), "rendered": got, "delta_e": de})
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", action="store_true", help="measure and store the response table")
    args = p.parse_args(argv)
    if args.write:
        write_response()
        print(f"wrote {RESPONSE_PATH}")
    print("| colour | asked (sRGB) | rendered (sRGB) | Delta E2000 |")
    print("|---|---|---|---|")
    for r in colour_table():
        fmt = lambda c: "(" + ", ".join(f"{v:.2f}" for v in c) + ")"
        print(f"| {r['name']} | {fmt(r['asked'])} | {fmt(r['rendered'])} | {r['delta_e']:.2f} |")


if __name__ == "__main__":
    main()
