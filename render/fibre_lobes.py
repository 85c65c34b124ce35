"""The fibre scattering model of `render.fibre` in Taichi: the longitudinal lobes M_p, the
azimuthal lobes and attenuations looked up in the material's tables (uploaded once per
material), S(wi, wo) and the albedo per vertex, and `fibre_scattering` to evaluate them from
numpy. float32 throughout, with inline exp / asin / acos (`fexp`, `fasin`, `facos`): libm's
are calls, and each call spills every vector register of the shading loop."""

import math

import numpy as np
import taichi as ti

from .bundles import FibreTableArgs
from .camera import f32, unit, vec3f, vec4f
from .fibre import (N_PHI, N_SIGMA, N_THETA, SIGMA0, THETA_MAX, U_MAX, HairMaterial, dual_table,
                    fibre_tables)
from .runtime import buffer, ensure_init, upload

vec6f = ti.types.vector(6, ti.f32)

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


def table_args(material: HairMaterial) -> FibreTableArgs:
    """The material's device tables (`upload_tables`) as one kernel argument."""
    ntab, atab, dtab = upload_tables(material)
    return FibreTableArgs(fibre_ntab=ntab, fibre_atab=atab, fibre_dtab=dtab)


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
