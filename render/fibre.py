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
"""

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import taichi as ti

from .camera import f32, unit, vec3f, vec4f
from .colour import sigma_for_colour, srgb_to_linear
from .runtime import buffer, ensure_init, upload

vec6f = ti.types.vector(6, ti.f32)

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


# dual scattering: Zinke et al. 2008's density factors
D_FORWARD, D_BACK = 0.7, 0.7


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


# -- the model in Taichi ------------------------------------------------------------------

_LOG_2PI = math.log(2.0 * math.pi)
_I0_COEFFS = [1.0 / (4.0 ** i * math.factorial(i) ** 2) for i in range(16)]  # I0 = sum c_i x^2i

@ti.func
def fexp(x: f32) -> f32:
    """e^x in float32, inline: within ~2 ulp of libm's expf for x in [-87.3, 88.3] (x is
    clamped to that range: e^-87.3 ~ 1e-38 stands for anything smaller). Shading evaluates
    ~30 exponentials per vertex and light, and each libm call spills every vector register."""
    xc = ti.math.clamp(x, f32(-87.3), f32(88.3))
    k = ti.floor(xc * f32(1.4426950408889634) + f32(0.5))
    r = xc - k * f32(0.693145751953125) - k * f32(1.428606765330187e-06)   # |r| <= ln2 / 2
    # the degree-6 Taylor polynomial in Estrin's form: about half the dependent operations of
    # Horner's (shading is bound by the latency of its chains of exponentials)
    r2 = r * r
    p = ((f32(1.0) + r) + r2 * (f32(0.5) + r * f32(1.0 / 6.0))
         + (r2 * r2) * ((f32(1.0 / 24.0) + r * f32(1.0 / 120.0)) + r2 * f32(1.0 / 720.0)))
    return p * ti.bit_cast((ti.cast(k, ti.i32) + 127) << 23, f32)


@ti.func
def asin_series(s: f32, z: f32) -> f32:
    """asin(s) for |s| <= 1/2, z = s^2: Cephes' minimax polynomial (relative error ~2e-7)."""
    p = ((((f32(4.2163199048e-2) * z + f32(2.4181311049e-2)) * z + f32(4.5470025998e-2)) * z
          + f32(7.4953002686e-2)) * z + f32(1.6666752422e-1))
    return s + s * z * p


@ti.func
def fasin(x: f32) -> f32:
    """asin(x) in float32, inline and branch-free (x in [-1, 1]): libm's asinf is a call, and
    each call spills every vector register of the shading loop. Above |x| = 1/2,
    asin|x| = pi/2 - 2 asin(sqrt((1 - |x|) / 2))."""
    a = ti.abs(x)
    big = a > f32(0.5)
    z = ti.select(big, f32(0.5) * (f32(1.0) - a), a * a)
    r = asin_series(ti.select(big, ti.sqrt(z), a), z)
    r = ti.select(big, f32(math.pi / 2) - f32(2.0) * r, r)
    return ti.select(x < f32(0.0), -r, r)


@ti.func
def facos(x: f32) -> f32:
    """acos(x) in float32, inline and branch-free (x in [-1, 1]; see `fasin`): above |x| =
    1/2 from the half angle, acos x = 2 asin(sqrt((1 - x) / 2)) (x > 0) or pi minus that of
    -x, so values near 0 and pi keep their relative accuracy; else pi/2 - asin x."""
    big = ti.abs(x) > f32(0.5)
    z = ti.select(big, f32(0.5) * (f32(1.0) - ti.abs(x)), x * x)
    r = asin_series(ti.select(big, ti.sqrt(z), x), z)
    return ti.select(big, ti.select(x > f32(0.0), f32(2.0) * r, f32(math.pi) - f32(2.0) * r),
                     f32(math.pi / 2) - r)


@ti.func
def log_i0(x: f32) -> f32:
    """log of the modified Bessel function I0(x), x >= 0: a series below 12, asymptotic above."""
    r = f32(0.0)
    if x > 12.0:
        r = x + f32(0.5) * (f32(-_LOG_2PI) - ti.log(x) + f32(1.0) / (f32(8.0) * x))
    else:
        val, x2i = f32(0.0), f32(1.0)
        for i in ti.static(range(16)):
            val += f32(_I0_COEFFS[i]) * x2i
            x2i *= x * x
        r = ti.log(val)
    return r


@ti.func
def m_lobe(sin_i: f32, cos_i: f32, sin_o: f32, cos_o: f32, v: f32) -> f32:
    """d'Eon's longitudinal lobe in float32, stable for small variances v."""
    return m_lobe_c(sin_i, cos_i, sin_o, cos_o, f32(1.0) / v, variance_constant(v))


@ti.func
def variance_constant(v: f32) -> f32:
    """1 / v + log(v (1 - exp(-2 / v))): the part of log M that depends on v alone."""
    inv_v = f32(1.0) / v
    return inv_v + ti.log(v * (f32(1.0) - ti.exp(f32(-2.0) * inv_v)))


@ti.func
def m_lobe_c(sin_i: f32, cos_i: f32, sin_o: f32, cos_o: f32, inv_v: f32, c_v: f32) -> f32:
    """`m_lobe` with 1 / v and c_v = `variance_constant(v)` given (they depend on the fibre
    alone): M = I0(a) exp(-b - c_v), a = cos_i cos_o / v, b = sin_i sin_o / v; below a = 12 the
    I0 series multiplies the exponential, above it the asymptote I0(a) ~ e^(a + 1/(8a)) /
    sqrt(2 pi a) does (no logarithm: libm's logf is a call)."""
    a = cos_i * cos_o * inv_v
    b = sin_i * sin_o * inv_v
    r = f32(0.0)
    if a > 12.0:
        r = fexp(a + f32(1.0) / (f32(8.0) * a) - b - c_v) * ti.rsqrt(f32(2.0 * math.pi) * a)
    else:
        val, x2i = f32(0.0), f32(1.0)
        for i in ti.static(range(16)):
            val += f32(_I0_COEFFS[i]) * x2i
            x2i *= a * a
        r = val * fexp(-b - c_v)
    return r


@ti.func
def lobe_variance(beta_m: f32) -> f32:
    """v_0 of the R lobe for longitudinal roughness beta_m (floored at 1e-4)."""
    v0 = beta_m * (f32(0.726) + f32(0.812) * beta_m) + f32(3.7) * ti.pow(beta_m, 20)
    return ti.max(v0 * v0, f32(1e-4))


@ti.func
def sigma_coord(sigma: f32) -> f32:
    return ti.log(f32(1.0) + sigma * f32(1.0 / SIGMA0)) * f32((N_SIGMA - 1) / U_MAX)


@ti.func
def n_lookup(ntab: ti.template(), p: ti.i32, ut: f32, up: f32, us: f32) -> f32:
    """Lobe p's table of logarithms at continuous indices (theta, phi, sigma), interpolated
    trilinearly and exponentiated: linear in log N along sigma is exact for values exponential
    in sigma (absorption), and it follows the logistic's exponential tails in phi."""
    it = ti.min(ti.cast(ut, ti.i32), N_THETA - 2)
    ip = ti.min(ti.cast(up, ti.i32), N_PHI - 2)
    js = ti.min(ti.cast(us, ti.i32), N_SIGMA - 2)
    ft, fp, fs = ut - ti.cast(it, f32), up - ti.cast(ip, f32), us - ti.cast(js, f32)
    # the table is flat (row-major p, theta, phi, sigma): constant strides, one base index
    base = ((p * N_THETA + it) * N_PHI + ip) * N_SIGMA + js
    r = f32(0.0)
    for a, b, c in ti.static(ti.ndrange(2, 2, 2)):
        w = ((ft * a + (f32(1.0) - ft) * (1 - a)) * (fp * b + (f32(1.0) - fp) * (1 - b))
             * (fs * c + (f32(1.0) - fs) * (1 - c)))
        r += w * ntab[base + (a * N_PHI + b) * N_SIGMA + c]
    return fexp(r)


@ti.func
def a_lookup(atab: ti.template(), k: ti.i32, ut: f32, us: f32) -> f32:
    """Row k of the attenuation table (logarithms) at continuous indices (theta, sigma)."""
    it = ti.min(ti.cast(ut, ti.i32), N_THETA - 2)
    js = ti.min(ti.cast(us, ti.i32), N_SIGMA - 2)
    ft, fs = ut - ti.cast(it, f32), us - ti.cast(js, f32)
    base = (k * N_THETA + it) * N_SIGMA + js   # flat, row-major (k, theta, sigma)
    r = f32(0.0)
    for a, c in ti.static(ti.ndrange(2, 2)):
        r += ((ft * a + (f32(1.0) - ft) * (1 - a)) * (fs * c + (f32(1.0) - fs) * (1 - c))
              * atab[base + a * N_SIGMA + c])
    return fexp(r)


@ti.func
def fibre_terms(t: vec3f, l: vec3f, v: vec3f, sigma: vec3f, beta_m: f32, shifts: ti.template(),
                ntab: ti.template(), atab: ti.template()):
    """(S(l, v) [1/sr], albedo under uniform light) of a fibre with unit tangent t, both vec3f."""
    v0 = lobe_variance(beta_m)
    us = vec3f(sigma_coord(sigma[0]), sigma_coord(sigma[1]), sigma_coord(sigma[2]))
    return fibre_terms_c(t, l, v, us, v0, fibre_constants(v0), shifts, ntab, atab)


@ti.func
def fibre_constants(v0: f32) -> vec3f:
    """`variance_constant` of the lobes' variances v0 (R), v0 / 4 (TT), 4 v0 (TRT, TRRT+)."""
    return vec3f(variance_constant(v0), variance_constant(f32(0.25) * v0),
                 variance_constant(f32(4.0) * v0))


@ti.func
def fibre_terms_c(t: vec3f, l: vec3f, v: vec3f, us: vec3f, v0: f32, cv: vec3f,
                  shifts: ti.template(), ntab: ti.template(), atab: ti.template()):
    """`fibre_terms` with the fibre's constants given: us the absorption's table coordinates
    per channel (`sigma_coord`), v0 its `lobe_variance`, cv its `fibre_constants`."""
    vo, tilt, albedo, a3 = fibre_view(t, v, us, shifts, atab)
    return fibre_light(t, l, v, vo, tilt, a3, us, v0, cv, ntab), albedo


@ti.func
def fibre_view(t: vec3f, v: vec3f, us: vec3f, shifts: ti.template(), atab: ti.template()):
    """What of `fibre_terms` depends on the view alone (shared by all lights): vo = (sin
    theta_o, cos theta_o, theta table coordinate, theta_o), the tilted view angles of R, TT
    and TRT (sin, cos each), the albedo and the TRRT+ attenuation A_3 per channel."""
    sin_o = ti.math.clamp(t.dot(v), f32(-1.0), f32(1.0))
    cos_o = ti.sqrt(ti.max(f32(1.0) - sin_o * sin_o, f32(0.0)))
    ut = ti.min(fasin(ti.abs(sin_o)), f32(THETA_MAX)) * f32((N_THETA - 1) / THETA_MAX)
    tilt = vec6f(sin_o * shifts[1] - cos_o * shifts[0],
                 ti.abs(cos_o * shifts[1] + sin_o * shifts[0]),
                 sin_o * shifts[3] + cos_o * shifts[2],
                 ti.abs(cos_o * shifts[3] - sin_o * shifts[2]),
                 sin_o * shifts[5] + cos_o * shifts[4],
                 ti.abs(cos_o * shifts[5] - sin_o * shifts[4]))
    albedo, a3 = vec3f(0.0, 0.0, 0.0), vec3f(0.0, 0.0, 0.0)
    for c in ti.static(range(3)):
        a3[c] = a_lookup(atab, 1, ut, us[c])
        albedo[c] = a_lookup(atab, 0, ut, us[c])
    return vec4f(sin_o, cos_o, ut, fasin(sin_o)), tilt, albedo, a3


@ti.func
def fibre_light(t: vec3f, l: vec3f, v: vec3f, vo: vec4f, tilt: vec6f, a3: vec3f,
                us: vec3f, v0: f32, cv: vec3f, ntab: ti.template()) -> vec3f:
    """S(l, v) [1/sr] given the view's part (`fibre_view`) and the fibre's constants."""
    sin_o, cos_o, ut = vo[0], vo[1], vo[2]
    sin_i = ti.math.clamp(t.dot(l), f32(-1.0), f32(1.0))
    cos_i = ti.sqrt(ti.max(f32(1.0) - sin_i * sin_i, f32(0.0)))
    lp, vp = l - sin_i * t, v - sin_o * t
    den = ti.sqrt(lp.dot(lp) * vp.dot(vp))
    cphi = f32(1.0)
    if den > 1e-12:
        cphi = ti.math.clamp(lp.dot(vp) / den, f32(-1.0), f32(1.0))
    up = facos(cphi) * f32((N_PHI - 1) / math.pi)
    inv_v0 = f32(1.0) / v0
    m_r = m_lobe_c(sin_i, cos_i, tilt[0], tilt[1], inv_v0, cv[0])
    m_tt = m_lobe_c(sin_i, cos_i, tilt[2], tilt[3], f32(4.0) * inv_v0, cv[1])
    m_trt = m_lobe_c(sin_i, cos_i, tilt[4], tilt[5], f32(0.25) * inv_v0, cv[2])
    m_rest = m_lobe_c(sin_i, cos_i, sin_o, cos_o, f32(0.25) * inv_v0, cv[2]) * f32(0.5 / math.pi)
    r = m_r * n_lookup(ntab, 0, ut, up, f32(0.0))
    s = vec3f(r, r, r)
    for c in ti.static(range(3)):
        s[c] += (m_tt * n_lookup(ntab, 1, ut, up, us[c]) + m_trt * n_lookup(ntab, 2, ut, up, us[c])
                 + m_rest * a3[c])
    return s


@ti.kernel
def _fibre_kernel(n: ti.i32, t: ti.types.ndarray(dtype=vec3f, ndim=1),
                  l: ti.types.ndarray(dtype=vec3f, ndim=1),
                  v: ti.types.ndarray(dtype=vec3f, ndim=1), sigma: vec3f, beta_m: f32,
                  shifts: ti.types.vector(8, ti.f32),
                  ntab: ti.types.ndarray(dtype=f32, ndim=1),
                  atab: ti.types.ndarray(dtype=f32, ndim=1),
                  out: ti.types.ndarray(dtype=vec3f, ndim=1),
                  albedo: ti.types.ndarray(dtype=vec3f, ndim=1)):
    for i in range(n):
        s, a = fibre_terms(unit(t[i]), unit(l[i]), unit(v[i]), sigma, beta_m, shifts, ntab, atab)
        out[i] = s
        albedo[i] = a


_device_tables: dict = {}


def upload_tables(material: HairMaterial) -> tuple:
    """Device copies (flat, row-major) of the logarithms of the material's (N, A) tables and
    of its dual scattering table, kept across frames (a few materials)."""
    key = (round(float(material.beta_n), 6), round(float(material.ior), 6))
    if key not in _device_tables:
        if len(_device_tables) >= 8:
            _device_tables.clear()
        n_tab, a_tab = (np.log(np.maximum(t, 1e-30)).astype(np.float32) for t in fibre_tables(*key))
        d_tab = dual_table(*key)
        devices = []
        for t in (n_tab, a_tab, d_tab):   # flattened, row-major: the lookups index them flat
            flat = np.ascontiguousarray(t, dtype=np.float32).ravel()
            dev = ti.ndarray(f32, flat.shape)
            dev.from_numpy(flat)
            devices.append(dev)
        _device_tables[key] = tuple(devices)
    return _device_tables[key]


def fibre_scattering(material: HairMaterial, tangents, to_light, to_eye) -> dict:
    """Evaluate the render kernels' own fibre shading, for inspection and tests.

    tangents, to_light, to_eye: (n, 3) or (3,) directions (normalised here), broadcast.
    Returns {"S": (n, 3) scattering function [1/sr] (radiance per unit irradiance),
    "albedo": (n, 3) radiance per unit uniform ambient radiance}.
    """
    ensure_init()
    t, l, v = np.broadcast_arrays(*(np.atleast_2d(np.asarray(a, np.float32))
                                    for a in (tangents, to_light, to_eye)))
    n = len(t)
    out = buffer("fibre_out", vec3f, (n,), 3)
    alb = buffer("fibre_albedo", vec3f, (n,), 3)
    ntab, atab, _ = upload_tables(material)
    _fibre_kernel(n, upload("fibre_t", np.ascontiguousarray(t), vec3f, 3),
                  upload("fibre_l", np.ascontiguousarray(l), vec3f, 3),
                  upload("fibre_v", np.ascontiguousarray(v), vec3f, 3),
                  material.absorption().astype(np.float32), np.float32(material.beta_m),
                  material.shifts(), ntab, atab, out, alb)
    return {"S": out.to_numpy(), "albedo": alb.to_numpy()}


@ti.func
def d_lookup(dtab: ti.template(), k: ti.i32, us: f32) -> f32:
    js = ti.min(ti.cast(us, ti.i32), N_SIGMA - 2)
    fs = us - ti.cast(js, f32)
    return dtab[k * N_SIGMA + js] * (f32(1.0) - fs) + dtab[k * N_SIGMA + js + 1] * fs


@ti.func
def gauss_lobe(theta_i: f32, theta_o: f32, var: f32) -> f32:
    """Gaussian stand-in for a broad d'Eon lobe of variance var: peak at theta_i = -theta_o,
    unit integral over theta_i (cheaper than `m_lobe`; used for dual scattering's lobes)."""
    d = theta_i + theta_o
    return fexp(-d * d / (f32(2.0) * var)) * ti.rsqrt(f32(2.0 * math.pi) * var)


@ti.func
def dual_scattering(t: vec3f, l: vec3f, v: vec3f, sigma: vec3f, beta_m: f32, s: vec3f,
                    albedo: vec3f, terms: vec3f, alpha: f32, dtab: ti.template()) -> vec3f:
    """Zinke et al. 2008's dual scattering for one directional light, per unit irradiance:
    F = D (S + d_b f_back) + max(T_f - D, 0) d_f (S_G + d_b f_back^G), with n = terms[0]
    fibres between the vertex and the light (deep opacity map), D = exp(-n) vis the direct
    fraction, T_f = d_f a_f^n vis the forward-scattered transmittance, sigma_f^2 = n beta_f^2
    its longitudinal spread; f_back the backscatter of the hair behind the vertex (weight
    1 - exp(-terms[2])) as a (Gaussian) longitudinal lobe of energy A_b shifted by Delta_b, spread cos(phi) / 2
    over the backward half in azimuth; S_G the light arriving spread out, a broadened lobe
    carrying the fibre's albedo isotropically in azimuth. Each term integrates over incident
    directions to its energy (A_b, the albedo)."""
    v0 = lobe_variance(beta_m)
    us = vec3f(sigma_coord(sigma[0]), sigma_coord(sigma[1]), sigma_coord(sigma[2]))
    bf2, a_back, shift, var_b, log_af = dual_constants(us, v0, alpha, dtab)
    theta_o = fasin(ti.math.clamp(t.dot(v), f32(-1.0), f32(1.0)))
    return dual_scattering_c(t, l, v, v0, s, albedo, terms, bf2, a_back, shift, var_b, log_af,
                             theta_o)


@ti.func
def dual_constants(us: vec3f, v0: f32, alpha: f32, dtab: ti.template()):
    """The fibre's dual-scattering constants per channel, from its absorption's table
    coordinates us, lobe variance v0 and cuticle tilt alpha: forward variance beta_f^2,
    backscattered energy A_b, its shift Delta_b and variance sigma_b^2, and log a_f."""
    bf2_, a_back_, shift_, var_b_, log_af_ = (vec3f(0.0, 0.0, 0.0), vec3f(0.0, 0.0, 0.0),
                                              vec3f(0.0, 0.0, 0.0), vec3f(0.0, 0.0, 0.0),
                                              vec3f(0.0, 0.0, 0.0))
    for c in ti.static(range(3)):
        af, ab = d_lookup(dtab, 0, us[c]), d_lookup(dtab, 1, us[c])
        bf2, bb2 = d_lookup(dtab, 2, us[c]) * v0, d_lookup(dtab, 3, us[c]) * v0
        alpha_f, alpha_b = d_lookup(dtab, 4, us[c]) * alpha, d_lookup(dtab, 5, us[c]) * alpha
        af2, ab2 = af * af, ab * ab
        den = ti.max(f32(1.0) - af2, f32(1e-3))
        a_back_[c] = ab * af2 / den + ab * ab2 * af2 / (den * den * den)
        shift_[c] = (alpha_b * (f32(1.0) - f32(2.0) * ab2 / (den * den))
                     + alpha_f * (f32(2.0) * den * den + f32(4.0) * af2 * ab2) / (den * den * den))
        sd_b = ((f32(1.0) + f32(D_BACK) * af2)
                * (ab * ti.sqrt(f32(2.0) * bf2 + bb2) + ab * ab2 * ti.sqrt(f32(2.0) * bf2 + f32(3.0) * bb2))
                / ti.max(ab + ab * ab2 * (f32(2.0) * ti.sqrt(bf2) + f32(3.0) * ti.sqrt(bb2)), f32(1e-6)))
        bf2_[c] = bf2
        var_b_[c] = ti.max(sd_b * sd_b, f32(1e-4))
        log_af_[c] = ti.log(ti.max(af, f32(1e-6)))
    return bf2_, a_back_, shift_, var_b_, log_af_


@ti.func
def dual_scattering_c(t: vec3f, l: vec3f, v: vec3f, v0: f32, s: vec3f, albedo: vec3f,
                      terms: vec3f, bf2: vec3f, a_back: vec3f, shift: vec3f, var_b: vec3f,
                      log_af: vec3f, theta_o: f32) -> vec3f:
    """`dual_scattering` with the fibre's `lobe_variance` v0 and `dual_constants`, and the
    view angle theta_o, given."""
    n, vis = terms[0], terms[1]
    sin_i = ti.math.clamp(t.dot(l), f32(-1.0), f32(1.0))
    sin_o = ti.math.clamp(t.dot(v), f32(-1.0), f32(1.0))
    theta_i = fasin(sin_i)
    direct = fexp(-n) * vis
    back_w = f32(1.0) - fexp(-terms[2])
    lp, vp = l - sin_i * t, v - sin_o * t
    den_phi = ti.sqrt(lp.dot(lp) * vp.dot(vp))
    cphi = f32(1.0)
    if den_phi > 1e-12:
        cphi = ti.math.clamp(lp.dot(vp) / den_phi, f32(-1.0), f32(1.0))
    n_back = f32(0.5) * ti.max(cphi, f32(0.0))   # azimuth of backscatter: cos(phi) / 2, back half
    out = vec3f(0.0, 0.0, 0.0)
    for c in ti.static(range(3)):
        var_f = n * bf2[c]
        out[c] = direct * s[c]
        if direct * back_w > 1e-4:
            out[c] += (direct * f32(D_BACK) * back_w * a_back[c] * n_back
                       * gauss_lobe(theta_i, theta_o + shift[c], var_b[c]))
        t_f = f32(D_FORWARD) * fexp(n * log_af[c]) * vis
        if t_f - direct > 1e-4:
            s_g = gauss_lobe(theta_i, theta_o, f32(4.0) * v0 + var_f) * albedo[c] * f32(0.5 / math.pi)
            f_back_g = a_back[c] * n_back * gauss_lobe(theta_i, theta_o + shift[c], var_b[c] + var_f)
            out[c] += (t_f - direct) * f32(D_FORWARD) * (s_g + f32(D_BACK) * f_back_g)
    return out


@ti.kernel
def shade_fibre_vertices(n: ti.i32, x: ti.types.ndarray(dtype=vec3f, ndim=1),
                         nbr: ti.types.ndarray(dtype=ti.types.vector(2, ti.i32), ndim=1),
                         sigma: ti.types.ndarray(dtype=vec3f, ndim=1),
                         beta_m: ti.types.ndarray(dtype=f32, ndim=1),
                         n_chunks: ti.i32,
                         n_lights: ti.i32, to_light: ti.types.ndarray(dtype=vec3f, ndim=1),
                         irradiance: ti.types.ndarray(dtype=vec3f, ndim=1),
                         terms: ti.types.ndarray(dtype=vec3f, ndim=2), opacity: f32,
                         eye: vec3f, ambient: vec3f, dual: ti.i32, density: f32,
                         shifts: ti.types.vector(8, ti.f32),
                         ntab: ti.types.ndarray(dtype=f32, ndim=1),
                         atab: ti.types.ndarray(dtype=f32, ndim=1),
                         dtab: ti.types.ndarray(dtype=f32, ndim=1),
                         masked: ti.i32, mark: ti.types.ndarray(dtype=ti.i32, ndim=1),
                         rgba: ti.types.ndarray(dtype=vec4f, ndim=1)):
    """rgba[i] = (linear radiance of vertex i under n_lights directional lights, light k from
    direction to_light[k] with `irradiance[k]` [W/m^2], plus the uniform `ambient` radiance;
    opacity). terms[k, i]: the vertex's (hair opacity towards light k, mesh visibility, hair
    opacity behind it) from `shadows.shadow_terms`. dual: Zinke's dual scattering
    (`dual_scattering`); otherwise single scattering shadowed by exp(-density x opacity) x
    visibility. Tangent from the strand neighbours (root to tip). The view's part of the
    shading is computed once for all lights; the lights add in order after the first (with
    the ambient), as separate passes would. masked: only vertices with mark[i] != 0 (the
    others' rgba is left as it was). Shapes (V,). n_chunks threads, each over a run of
    vertices."""
    # consecutive vertices mostly belong to one strand and share its absorption and
    # roughness: each thread walks a run of vertices and recomputes the fibre's constants
    # (table coordinates, lobe constants, dual scattering's) only when they change; the same
    # inputs give the same bits, so the result does not depend on the runs
    chunk = (n + n_chunks - 1) // n_chunks
    for ch in range(n_chunks):
        sg_k, bm_k = vec3f(-1.0, -1.0, -1.0), f32(-1.0)
        us, v0, cv = vec3f(0.0, 0.0, 0.0), f32(1.0), vec3f(0.0, 0.0, 0.0)
        bf2, a_back, shift, var_b, log_af = (vec3f(0.0, 0.0, 0.0), vec3f(0.0, 0.0, 0.0),
                                             vec3f(0.0, 0.0, 0.0), vec3f(0.0, 0.0, 0.0),
                                             vec3f(0.0, 0.0, 0.0))
        for i in range(ch * chunk, ti.min(n, (ch + 1) * chunk)):
            if masked and mark[i] == 0:
                continue
            sg, bm = sigma[i], beta_m[i]
            if sg[0] != sg_k[0] or sg[1] != sg_k[1] or sg[2] != sg_k[2] or bm != bm_k:
                sg_k, bm_k = sg, bm
                us = vec3f(sigma_coord(sg[0]), sigma_coord(sg[1]), sigma_coord(sg[2]))
                v0 = lobe_variance(bm)
                cv = fibre_constants(v0)
                bf2, a_back, shift, var_b, log_af = dual_constants(us, v0, shifts[6], dtab)
            t = unit(x[nbr[i][1]] - x[nbr[i][0]])
            v = unit(eye - x[i])
            vo, tilt, albedo, a3 = fibre_view(t, v, us, shifts, atab)
            c = vec3f(0.0, 0.0, 0.0)
            for k in range(n_lights):
                l = to_light[k]
                s = fibre_light(t, l, v, vo, tilt, a3, us, v0, cv, ntab)
                tm = terms[k, i]
                f = s * (fexp(-density * tm[0]) * tm[1])
                if dual:
                    f = dual_scattering_c(t, l, v, v0, s, albedo, tm, bf2, a_back, shift,
                                          var_b, log_af, vo[3])
                if k == 0:
                    c = irradiance[k] * f + ambient * albedo
                else:
                    c += irradiance[k] * f
            rgba[i] = vec4f(c[0], c[1], c[2], opacity)
