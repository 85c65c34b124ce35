"""Multiple scattering through the hair after Zinke et al.'s dual scattering (2008) on top of
the fibre model (`fibre_lobes`): the light reaching a vertex directly, forward-scattered
through the fibres between it and the light (deep opacity map), and backscattered by the hair
behind it, from the per-absorption averages of `fibre.dual_table`; four constants fitted
against a path tracer (render/README.md, "Multiple scattering", has the model and the
comparison)."""

import math

import taichi as ti

from .camera import f32, vec3f
from .fibre import N_SIGMA
from .fibre_lobes import fasin, fexp, lobe_variance, sigma_coord

# Zinke et al. 2008's density factors d_f, d_b, and the two constants of the forward-scattered
# light: its transmittance falls by a_f per FORWARD_COUNT fibres of opacity, and the fraction
# FORWARD_DIRECTIONAL of it still arrives from the light's direction. The four are fitted
# against Mitsuba's path tracer on dense slabs of five hair colours lit from the front, the
# side and behind (tests/mitsuba_multiple.py; Zinke's d_f = d_b = 0.7, a_f per fibre and
# all of it spread out left light hair at 0.5-0.7 of the path tracer's luminance)
D_FORWARD, D_BACK = 0.4, 0.8
FORWARD_COUNT, FORWARD_DIRECTIONAL = 0.4, 0.1

# a fibre's dual-scattering constants per channel (`dual_constants`): forward variance
# beta_f^2, backscattered energy A_b, its shift Delta_b [rad] and variance sigma_b^2, log a_f
DualConstants = ti.types.struct(bf2=vec3f, a_back=vec3f, shift=vec3f, var_b=vec3f, log_af=vec3f)


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
    """Multiple scattering for one directional light after Zinke et al. 2008's dual scattering,
    per unit irradiance [1/sr], per channel:
    F = D (S + d_b w_b f_back) + T_s d_f (w S + (1 - w) S_G + pi d_b w_b f_back^G), with
    n = terms[0] fibres between the vertex and the light (deep opacity map), vis = terms[1]
    the mesh visibility, D = exp(-n) vis the direct fraction, T_s = max(a_f^(k n) - exp(-n),
    0) vis the forward-scattered light (k = FORWARD_COUNT), w = FORWARD_DIRECTIONAL the part
    of it still arriving from the light's direction (scattered by S), sigma_f^2 = n beta_f^2
    its longitudinal spread; f_back the backscatter of the hair behind the vertex (weight
    w_b = 1 - exp(-terms[2])) as a (Gaussian) longitudinal lobe of energy A_b shifted by
    Delta_b, spread cos(phi) / 2 over the backward half in azimuth (f_back^G: widened by
    sigma_f^2); S_G the light arriving spread out, a broadened lobe carrying the fibre's albedo
    isotropically in azimuth. Each lobe integrates over incident directions to its energy
    (A_b, the albedo)."""
    v0 = lobe_variance(beta_m)
    us = vec3f(sigma_coord(sigma[0]), sigma_coord(sigma[1]), sigma_coord(sigma[2]))
    dc = dual_constants(us, v0, alpha, dtab)
    theta_o = fasin(ti.math.clamp(t.dot(v), f32(-1.0), f32(1.0)))
    return dual_scattering_c(t, l, v, v0, s, albedo, terms, dc, theta_o)


@ti.func
def dual_constants(us: vec3f, v0: f32, alpha: f32, dtab: ti.template()):
    """The fibre's dual-scattering constants per channel (a DualConstants), from its
    absorption's table coordinates us, lobe variance v0 and cuticle tilt alpha: forward
    variance beta_f^2, backscattered energy A_b, its shift Delta_b and variance sigma_b^2, and
    log a_f."""
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
    return DualConstants(bf2=bf2_, a_back=a_back_, shift=shift_, var_b=var_b_, log_af=log_af_)


@ti.func
def dual_scattering_c(t: vec3f, l: vec3f, v: vec3f, v0: f32, s: vec3f, albedo: vec3f,
                      terms: vec3f, dc: ti.template(), theta_o: f32) -> vec3f:
    """`dual_scattering` with the fibre's `lobe_variance` v0 and `dual_constants` dc, and the
    view angle theta_o, given."""
    bf2, a_back, shift, var_b, log_af = dc.bf2, dc.a_back, dc.shift, dc.var_b, dc.log_af
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
        # exp(-n) < a_f^(k n) needs log a_f > -1 / k: hair dark in this channel forwards nothing
        scattered = ti.max(fexp(f32(FORWARD_COUNT) * n * log_af[c]) - fexp(-n), f32(0.0)) * vis
        if scattered > 1e-4:
            s_g = gauss_lobe(theta_i, theta_o, f32(4.0) * v0 + var_f) * albedo[c] * f32(0.5 / math.pi)
            f_back_g = a_back[c] * n_back * gauss_lobe(theta_i, theta_o + shift[c], var_b[c] + var_f)
            out[c] += scattered * f32(D_FORWARD) * (
                f32(FORWARD_DIRECTIONAL) * s[c] + f32(1.0 - FORWARD_DIRECTIONAL) * s_g
                + f32(math.pi * D_BACK) * back_w * f_back_g)
    return out
