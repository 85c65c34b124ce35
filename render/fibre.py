"""Physically based hair fibre scattering: the far-field model of Marschner et al. (2003) in the
energy-conserving form of d'Eon et al. (2011) and Chiang et al. (2016).

A fibre is a dielectric cylinder (index of refraction `ior`, absorption `sigma_a` per unit of
fibre *radius*) whose surface scales tilt by `alpha`. Light leaving it after p internal
segments forms lobe p: R (p = 0, surface reflection), TT (1), TRT (2) and the rest TRRT+ (3).
With the unit tangent T (root to tip), the direction to the light wi and to the eye wo,
theta = asin(w . T) is a direction's longitudinal angle and phi the azimuth between wi and wo
in the plane normal to T. The scattering function, averaged over the fibre's width (offset h
uniform in [-1, 1], since fibres are sub-pixel), is

    S(wi, wo) = sum_{p<3} M_p(theta_i, theta_o - shift_p) N_p(|theta_o|, phi)
                + M_3(theta_i, theta_o) A_3(|theta_o|) / (2 pi)          [1/sr]

and a directional light of irradiance E gives the fibre radiance L = E S (no cosine: the
fibre's projected width is already the pixel's coverage). M_p is d'Eon's longitudinal lobe of
variance v_p (v_0 from beta_m, v_1 = v_0 / 4, v_2 = v_3 = 4 v_0), shift_p = -2 alpha, alpha,
4 alpha for R, TT, TRT. N_p(phi) = 1/2 int A_p(h) D(phi - Phi_p(h)) dh is the h-averaged
azimuthal lobe with A_p the Fresnel/absorption attenuation and D Chiang's trimmed logistic of
scale s(beta_n); it depends on |theta_o|, phi and sigma_a only, so it is tabulated once per
(beta_n, ior) over (|theta_o|, phi, sigma) and a vertex costs a few table lookups per channel.
Uniform ambient radiance L_a gives L = L_a sum_p A_p(|theta_o|) (M_p integrates to 1).
This module holds the material and the model in numpy (the tables and the tests' reference);
the kernels' side is `fibre_lobes` (the lobes and attenuations in Taichi, the device tables,
`fibre_scattering`), `fibre_dual` (dual scattering) and `fibre_vertices` (the per-vertex
shading kernel of a frame).
"""

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .colour import sigma_for_colour, srgb_to_linear

# absorption of the two melanins per unit concentration and fibre radius (d'Eon et al. 2011)
EUMELANIN_SIGMA_A = np.array([0.419, 0.697, 1.37])
PHEOMELANIN_SIGMA_A = np.array([0.187, 0.4, 1.05])

# table grids: |theta_o| in [0, THETA_MAX], phi in [0, pi], sigma on u = log(1 + sigma / S0)
N_THETA, N_PHI, N_SIGMA = 32, 96, 24
THETA_MAX = math.radians(89.5)
SIGMA0, SIGMA_MAX = 0.25, 64.0
U_MAX = math.log1p(SIGMA_MAX / SIGMA0)


def colour_poly(beta_n: float) -> float:
    """Chiang et al. 2016, eq. 9: colour c of a hair volume ~ exp(-sqrt(sigma_a) * this)."""
    b = beta_n
    return 5.969 - 0.215 * b + 2.532 * b ** 2 - 10.73 * b ** 3 + 5.574 * b ** 4 + 0.245 * b ** 5


def sigma_from_colour(linear_rgb, beta_n: float) -> np.ndarray:
    """Absorption [1/radius] that makes a hair volume of linear colour `linear_rgb` (..., 3),
    clipped to [1e-6, 1]: Chiang's inversion sigma_a = (ln c / poly(beta_n))^2."""
    c = np.clip(np.asarray(linear_rgb, dtype=np.float64), 1e-6, 1.0)
    return (np.log(c) / colour_poly(beta_n)) ** 2


def colour_from_sigma(sigma_a, beta_n: float) -> np.ndarray:
    """Inverse of `sigma_from_colour`: linear colour of a hair volume, (..., 3)."""
    return np.exp(-np.sqrt(np.asarray(sigma_a, dtype=np.float64)) * colour_poly(beta_n))


def longitudinal_variance(beta_m):
    """v_0 of the R lobe for longitudinal roughness beta_m in (0, 1] (Chiang et al. 2016)."""
    b = np.asarray(beta_m, dtype=np.float64)
    return (0.726 * b + 0.812 * b ** 2 + 3.7 * b ** 20) ** 2


def logistic_scale(beta_n: float) -> float:
    """Scale s of the azimuthal logistic for azimuthal roughness beta_n (Chiang et al. 2016)."""
    return math.sqrt(math.pi / 8.0) * (0.265 * beta_n + 1.194 * beta_n ** 2 + 5.372 * beta_n ** 22)


@dataclass(frozen=True, kw_only=True)
class HairMaterial:
    """A hair fibre's optics.

    eumelanin, pheomelanin >= 0: pigment concentrations (black ~8, brown ~1.3, blonde ~0.3 with
        a little pheomelanin, red: pheomelanin ~1-3); sigma_a = eu * (0.419, 0.697, 1.37)
        + pheo * (0.187, 0.4, 1.05) per unit fibre radius. `sigma_a` (3 values >= 0) given
        instead overrides them (`from_colour` sets it).
    beta_m, beta_n in [0.05, 1]: longitudinal and azimuthal roughness.
    alpha_deg in [-10, 10]: cuticle scale tilt [degrees]. ior in (1, 3]: index of refraction.
    melanin_variation >= 0: per-strand log-normal spread (std of the log) of the absorption;
    roughness_variation >= 0: the same for beta_m; seed: the variation's random seed.
    """

    eumelanin: float = 1.3
    pheomelanin: float = 0.0
    beta_m: float = 0.3
    beta_n: float = 0.3
    alpha_deg: float = 2.0
    ior: float = 1.55
    sigma_a: tuple | None = None
    melanin_variation: float = 0.0
    roughness_variation: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for n in ("eumelanin", "pheomelanin", "melanin_variation", "roughness_variation"):
            if not getattr(self, n) >= 0.0:
                raise ValueError(f"{n} must be >= 0, got {getattr(self, n)}")
        for n in ("beta_m", "beta_n"):
            if not 0.05 <= getattr(self, n) <= 1.0:
                raise ValueError(f"{n} must be in [0.05, 1], got {getattr(self, n)}")
        if not -10.0 <= self.alpha_deg <= 10.0:
            raise ValueError(f"alpha_deg must be in [-10, 10] degrees, got {self.alpha_deg}")
        if not 1.0 < self.ior <= 3.0:
            raise ValueError(f"ior must be in (1, 3], got {self.ior}")
        if self.sigma_a is not None:
            s = np.asarray(self.sigma_a, dtype=np.float64)
            if s.shape != (3,) or not np.all((s >= 0.0) & (s <= SIGMA_MAX)):
                raise ValueError(f"sigma_a must be 3 values in [0, {SIGMA_MAX}] per fibre "
                                 f"radius, got {self.sigma_a!r}")
            object.__setattr__(self, "sigma_a", tuple(float(v) for v in s))

    @classmethod
    def from_colour(cls, rgb, beta_n: float = 0.3, **kwargs) -> "HairMaterial":
        """The material whose hair renders as colour `rgb` (sRGB in [0, 1]): the body colour of
        the reference swatch (`render.swatch`), inverted through the stored response of the
        default fibre parameters (beta_m, beta_n, alpha_deg, ior); with other parameters (in
        beta_n or kwargs) Chiang et al.'s inversion, which renders lighter and greyer."""
        c = np.asarray(rgb, dtype=np.float64)
        if c.shape != (3,) or not np.all((c >= 0.0) & (c <= 1.0)):
            raise ValueError(f"rgb must be 3 sRGB values in [0, 1], got {rgb!r}")
        d = cls()
        default = (beta_n == d.beta_n and all(kwargs.get(k, getattr(d, k)) == getattr(d, k)
                                              for k in ("beta_m", "alpha_deg", "ior")))
        lin = srgb_to_linear(c)
        sigma = np.minimum(sigma_for_colour(lin) if default else sigma_from_colour(lin, beta_n),
                           SIGMA_MAX)
        return cls(sigma_a=tuple(sigma), beta_n=beta_n, **kwargs)

    def absorption(self) -> np.ndarray:
        """sigma_a [1/fibre radius], (3,) float64."""
        if self.sigma_a is not None:
            return np.array(self.sigma_a)
        return self.eumelanin * EUMELANIN_SIGMA_A + self.pheomelanin * PHEOMELANIN_SIGMA_A

    def colour(self) -> np.ndarray:
        """Linear colour of a volume of this hair (Chiang's forward map), (3,)."""
        return colour_from_sigma(self.absorption(), self.beta_n)

    def strands(self, n_strands: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-strand (sigma_a (S, 3), beta_m (S,)) with the seeded variation."""
        rng = np.random.default_rng(self.seed)
        scale = np.exp(self.melanin_variation * rng.standard_normal(n_strands))
        rough = np.exp(self.roughness_variation * rng.standard_normal(n_strands))
        sigma = np.minimum(self.absorption()[None, :] * scale[:, None], SIGMA_MAX)
        return sigma, np.clip(self.beta_m * rough, 0.05, 1.0)

    def shifts(self) -> np.ndarray:
        """(sin 2a, cos 2a, sin a, cos a, sin 4a, cos 4a, a [rad], 0) for the lobes' tilts."""
        a = math.radians(self.alpha_deg)
        return np.array([math.sin(2 * a), math.cos(2 * a), math.sin(a), math.cos(a),
                         math.sin(4 * a), math.cos(4 * a), a, 0.0], dtype=np.float32)


# -- the model in numpy (tables and the reference for tests) ----------------------------------

def fresnel(cos_i, eta: float):
    """Unpolarised Fresnel reflectance from air into a dielectric of index eta."""
    cos_i = np.clip(cos_i, 0.0, 1.0)
    sin_t = np.sqrt(np.maximum(1.0 - cos_i ** 2, 0.0)) / eta
    cos_t = np.sqrt(np.maximum(1.0 - sin_t ** 2, 0.0))
    r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 0.5 * (r_par ** 2 + r_perp ** 2)


def attenuations(sin_theta_o, h, sigma, eta: float):
    """A_p for p = 0..3 at view angle theta_o, offset h, absorption sigma (broadcasting);
    returns (A (4, ...), gamma_o, gamma_t)."""
    sin_o = np.asarray(sin_theta_o, dtype=np.float64)
    cos_o = np.sqrt(np.maximum(1.0 - sin_o ** 2, 1e-12))
    cos_t = np.sqrt(1.0 - (sin_o / eta) ** 2)
    eta_p = np.sqrt(eta ** 2 - sin_o ** 2) / cos_o
    gamma_o = np.arcsin(np.clip(h, -1.0, 1.0))
    gamma_t = np.arcsin(np.clip(h / eta_p, -1.0, 1.0))
    f = fresnel(cos_o * np.cos(gamma_o), eta)
    trans = np.exp(-np.asarray(sigma) * (2.0 * np.cos(gamma_t) / cos_t))
    a1 = (1.0 - f) ** 2 * trans
    a2 = a1 * f * trans
    a3 = a2 * f * trans / (1.0 - f * trans)
    return np.stack(np.broadcast_arrays(f, a1, a2, a3)), gamma_o, gamma_t


def trimmed_logistic(x, s: float):
    """Chiang's logistic of scale s on [-pi, pi], normalised; x wrapped into [-pi, pi]."""
    x = np.abs(np.mod(np.asarray(x) + np.pi, 2.0 * np.pi) - np.pi)
    e = np.exp(-x / s)
    norm = 1.0 / (1.0 + math.exp(-math.pi / s)) - 1.0 / (1.0 + math.exp(math.pi / s))
    return e / (s * (1.0 + e) ** 2) / norm


def longitudinal(sin_i, cos_i, sin_o, cos_o, v):
    """d'Eon's M_p(theta_i, theta_o) of variance v: integrates to 1 against cos(theta_i)."""
    a = cos_i * cos_o / v
    b = sin_i * sin_o / v
    with np.errstate(over="ignore"):
        log_i0 = np.where(a > 12.0, a + 0.5 * (-np.log(2 * np.pi) + np.log(1 / np.maximum(a, 1e-30))
                                               + 1.0 / (8.0 * np.maximum(a, 1e-30))),
                          np.log(np.i0(np.minimum(a, 12.0))))
    return np.exp(log_i0 - b - 1.0 / v + np.log(2.0) + np.log(1.0 / (2.0 * v))
                  - np.log1p(-np.exp(-2.0 / v)))


def sigma_grid() -> np.ndarray:
    """The table's absorption nodes [1/radius], (N_SIGMA,)."""
    return SIGMA0 * np.expm1(np.linspace(0.0, U_MAX, N_SIGMA))


def theta_grid() -> np.ndarray:
    return np.linspace(0.0, THETA_MAX, N_THETA)


def phi_grid() -> np.ndarray:
    return np.linspace(0.0, np.pi, N_PHI)


def _gamma_nodes(beta_n: float) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint nodes gamma_o in (-pi/2, pi/2) and weights for (1/2) int dh = (1/2) int cos g dg,
    fine enough that Phi_p moves less than s/4 between nodes."""
    n = int(min(max(256, math.ceil(16.0 * math.pi / logistic_scale(beta_n))), 4096))
    g = (np.arange(n) + 0.5) / n * np.pi - 0.5 * np.pi
    return g, 0.5 * np.cos(g) * (np.pi / n)


@lru_cache(maxsize=16)
def fibre_tables(beta_n: float, ior: float) -> tuple[np.ndarray, np.ndarray]:
    """(N (3, N_THETA, N_PHI, N_SIGMA): h-averaged azimuthal lobes R, TT, TRT [1/rad],
    A (2, N_THETA, N_SIGMA): sum of all A_p (the albedo under uniform light) and A_3), float32."""
    s = logistic_scale(beta_n)
    g, w = _gamma_nodes(beta_n)
    sin_o = np.sin(theta_grid())[:, None, None]                       # (T, 1, 1)
    sigma = sigma_grid()[None, :, None]                               # (1, S, 1)
    a, gamma_o, gamma_t = attenuations(sin_o, np.sin(g)[None, None, :], sigma, ior)  # (4, T, S, G)
    phi = phi_grid()
    n_tab = np.empty((3, N_THETA, N_PHI, N_SIGMA))
    for p in range(3):
        big_phi = 2 * p * gamma_t[:, 0, :] - 2 * gamma_o[0, 0, :] + p * np.pi       # (T, G)
        d = trimmed_logistic(phi[None, :, None] - big_phi[:, None, :], s)            # (T, P, G)
        n_tab[p] = np.einsum("tpg,tsg->tps", d * w, a[p])
    a_tab = np.stack([(a * w).sum(axis=-1).sum(axis=0), (a[3] * w).sum(axis=-1)])
    return n_tab.astype(np.float32), a_tab.astype(np.float32)



@lru_cache(maxsize=16)
def dual_table(beta_n: float, ior: float) -> np.ndarray:
    """Per absorption node (N_SIGMA), the fibre's averages for dual scattering (Zinke et al.
    2008), (6, N_SIGMA) float32: a_f, a_b (energy scattered forward |phi| > pi/2 and backward,
    averaged over theta with weight cos theta), k_f, k_b (their lobe-weighted longitudinal
    variance in units of v_0) and s_f, s_b (their lobe-weighted shift in units of alpha)."""
    n_tab, a_tab = fibre_tables(beta_n, ior)
    n_tab, a_tab = n_tab.astype(np.float64), a_tab.astype(np.float64)
    phi = phi_grid()
    back = phi <= np.pi / 2
    dphi = np.gradient(phi)
    a_b = [2 * (n_tab[p] * (dphi * back)[None, :, None]).sum(axis=1) for p in range(3)]
    a_f = [2 * (n_tab[p] * (dphi * ~back)[None, :, None]).sum(axis=1) for p in range(3)]
    a_b.append(0.5 * a_tab[1])
    a_f.append(0.5 * a_tab[1])
    w = np.cos(theta_grid())[:, None]
    avg = lambda x: (x * w).sum(axis=0) / w.sum()                       # over theta -> (S,)
    k, sh = (1.0, 0.25, 4.0, 4.0), (-2.0, 1.0, 4.0, 0.0)
    af, ab = avg(sum(a_f)), avg(sum(a_b))
    rows = [af, ab,
            sum(avg(a_f[p]) * k[p] for p in range(4)) / np.maximum(af, 1e-12),
            sum(avg(a_b[p]) * k[p] for p in range(4)) / np.maximum(ab, 1e-12),
            sum(avg(a_f[p]) * sh[p] for p in range(4)) / np.maximum(af, 1e-12),
            sum(avg(a_b[p]) * sh[p] for p in range(4)) / np.maximum(ab, 1e-12)]
    return np.array(rows, dtype=np.float32)


def scattering_reference(material: HairMaterial, tangent, to_light, to_eye, n_h: int = 2048):
    """S(wi, wo) [1/sr], (3,), straight from the formulas (no tables): the test oracle."""
    t, wi, wo = (np.asarray(x, float) / np.linalg.norm(x) for x in (tangent, to_light, to_eye))
    sin_i, sin_o = wi @ t, wo @ t
    cos_i, cos_o = math.sqrt(max(1 - sin_i ** 2, 0)), math.sqrt(max(1 - sin_o ** 2, 0))
    pi_, po_ = wi - sin_i * t, wo - sin_o * t
    cphi = pi_ @ po_ / max(np.linalg.norm(pi_) * np.linalg.norm(po_), 1e-12)
    phi = math.acos(np.clip(cphi, -1.0, 1.0))
    h = (np.arange(n_h) + 0.5) / n_h * 2.0 - 1.0
    sigma = material.absorption()[:, None]
    a, gamma_o, gamma_t = attenuations(sin_o, h[None, :], sigma, material.ior)
    s = logistic_scale(material.beta_n)
    v0 = float(longitudinal_variance(material.beta_m))
    v = [v0, v0 / 4, 4 * v0, 4 * v0]
    sh = material.shifts()
    tilts = [(sin_o * sh[1] - cos_o * sh[0], cos_o * sh[1] + sin_o * sh[0]),
             (sin_o * sh[3] + cos_o * sh[2], cos_o * sh[3] - sin_o * sh[2]),
             (sin_o * sh[5] + cos_o * sh[4], cos_o * sh[5] - sin_o * sh[4])]
    out = np.zeros(3)
    for p in range(3):
        m = longitudinal(sin_i, cos_i, tilts[p][0], abs(tilts[p][1]), v[p])
        d = trimmed_logistic(phi - (2 * p * gamma_t - 2 * gamma_o + p * np.pi), s)
        out += m * (a[p] * d).mean(axis=-1)
    out += longitudinal(sin_i, cos_i, sin_o, cos_o, v[3]) * a[3].mean(axis=-1) / (2 * np.pi)
    return out
