"""The frame's fibre shading: every hair vertex under all directional lights in one pass,
single or dual scattering (`fibre_lobes`, `fibre_dual`); with a shading stride of 2, every
other vertex along each strand, the ones between interpolated (`mark_interpolated`,
`interpolate_skipped`)."""

import taichi as ti

from .bundles import FibreTableArgs, HairArgs, LightSetArgs
from .camera import f32, unit, vec3f, vec4f
from .fibre_dual import DualConstants, dual_constants, dual_scattering_c
from .fibre_lobes import fexp, fibre_constants, fibre_light, fibre_view, lobe_variance, sigma_coord
from .threads import spread, spread_run

# shading stride 2 interpolates a vertex only where its strand turns by at most this [deg]:
# shading follows the tangent, and on the benchmark's wavy hair (11 px segments at 1280x720)
# 20 deg keeps the hair's mean CIEDE2000 against shading every vertex at 0.28 (0.50 with no
# limit)
STRIDE_MAX_BEND = 20.0


@ti.kernel
def shade_fibre_vertices(n: ti.i32, hair: HairArgs, n_chunks: ti.i32, lights: LightSetArgs,
                         opacity: f32, eye: vec3f, ambient: vec3f, dual: ti.i32, density: f32,
                         shifts: ti.types.vector(8, ti.f32), tables: FibreTableArgs,
                         masked: ti.i32):
    """rgba[i] = (linear radiance of vertex i under the K directional lights of `lights`,
    light k from direction to_light[k] with `irradiance[k]` [W/m^2], plus the uniform
    `ambient` radiance; opacity), from the hair's (HairArgs) positions, absorption sigma and
    roughness beta_m and the fibre material's lobe tilts (`HairMaterial.shifts`) and device
    tables (FibreTableArgs). terms[k, i]: the vertex's (hair opacity towards light k, mesh
    visibility, hair opacity behind it) from `shadows.shadow_terms`. dual: multiple
    scattering (`fibre_dual.dual_scattering`, after Zinke's dual scattering); otherwise single scattering shadowed by
    exp(-density x opacity) x visibility. Tangent from the strand neighbours (root to tip). The
    view's part of the shading is computed once for all lights; the lights add in order after
    the first (with the ambient), as separate passes would. masked: only vertices with
    mark[i] > 0 (the others' rgba is left as it was). Shapes (V,). n_chunks threads, each
    over a run of vertices, the runs in `threads.spread`'s mixed order (the vertices to shade
    come in runs: in order, one CPU thread would get most of them)."""
    x, nbr, sigma, beta_m, mark, rgba = ti.static(hair.hair_x, hair.hair_nbr, hair.hair_sigma,
                                                  hair.hair_beta_m, hair.hair_mark, hair.hair_rgba)
    to_light, irradiance, terms = ti.static(lights.light_to, lights.light_irradiance,
                                            lights.light_terms)
    ntab, atab, dtab = ti.static(tables.fibre_ntab, tables.fibre_atab, tables.fibre_dtab)
    n_lights = to_light.shape[0]
    # consecutive vertices mostly belong to one strand and share its absorption and
    # roughness: each thread walks a run of vertices and recomputes the fibre's constants
    # (table coordinates, lobe constants, dual scattering's) only when they change; the same
    # inputs give the same bits, so the result does not depend on the runs
    span, factor = spread(n_chunks)
    for step in range(span * factor):
        lo, hi = spread_run(step, span, factor, n, n_chunks)
        sg_k, bm_k = vec3f(-1.0, -1.0, -1.0), f32(-1.0)
        us, v0, cv = vec3f(0.0, 0.0, 0.0), f32(1.0), vec3f(0.0, 0.0, 0.0)
        dc = DualConstants(bf2=vec3f(0.0, 0.0, 0.0), a_back=vec3f(0.0, 0.0, 0.0),
                           shift=vec3f(0.0, 0.0, 0.0), var_b=vec3f(0.0, 0.0, 0.0),
                           log_af=vec3f(0.0, 0.0, 0.0))
        for i in range(lo, hi):
            if masked and mark[i] <= 0:
                continue
            sg, bm = sigma[i], beta_m[i]
            if sg[0] != sg_k[0] or sg[1] != sg_k[1] or sg[2] != sg_k[2] or bm != bm_k:
                sg_k, bm_k = sg, bm
                us = vec3f(sigma_coord(sg[0]), sigma_coord(sg[1]), sigma_coord(sg[2]))
                v0 = lobe_variance(bm)
                cv = fibre_constants(v0)
                dc = dual_constants(us, v0, shifts[6], dtab)
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
                    f = dual_scattering_c(t, l, v, v0, s, albedo, tm, dc, vo[3])
                if k == 0:
                    c = irradiance[k] * f + ambient * albedo
                else:
                    c += irradiance[k] * f
            rgba[i] = vec4f(c[0], c[1], c[2], opacity)


@ti.kernel
def mark_interpolated(n: ti.i32, hair: HairArgs, min_cos: f32):
    """Shading stride 2: mark[i] = -1 (colour interpolated from its strand neighbours, not
    shaded) for every strand-interior vertex i at an odd place along its own strand (counted
    from the root, so every strand is strided alike wherever it starts in the buffer, and its
    ends are never interpolated) that is to be drawn (mark[i] > 0) and where the strand turns
    little (the cosine between its two segments >= min_cos), and mark its neighbours i - 1
    and i + 1 (even places, or strand ends) for shading. Shaded colour is interpolated along
    each segment when compositing anyway: this makes it linear over two segments instead of
    one. Segments are as long as a few pixels or more at the strand densities where shading
    costs (~9 px at 640x480, 11 px at 1280x720 in the benchmark), so a colour linear over two
    of them stays smooth. One thread per strand, started at its root (nbr[i][0] == i): the
    strand's vertices are written by it alone."""
    x, nbr, mark = ti.static(hair.hair_x, hair.hair_nbr, hair.hair_mark)
    for root in range(n):
        if nbr[root][0] == root:
            i = root + 1
            # this strand's interior vertices only: its last vertex is its own next neighbour,
            # the vertex after it (stepping by two from the one before) the next strand's root
            while i < n and nbr[i][0] == i - 1 and nbr[i][1] == i + 1:
                if mark[i] > 0 and unit(x[i] - x[i - 1]).dot(unit(x[i + 1] - x[i])) >= min_cos:
                    mark[i] = -1
                    mark[i - 1] = 1
                    mark[i + 1] = 1
                i += 2


@ti.kernel
def interpolate_skipped(n: ti.i32, hair: HairArgs):
    """rgba[i] of every vertex `mark_interpolated` marked -1: linear in arc length between
    its shaded neighbours i - 1 and i + 1. One thread per vertex."""
    x, mark, rgba = ti.static(hair.hair_x, hair.hair_mark, hair.hair_rgba)
    for i in range(n):
        if mark[i] < 0:
            la, lb = (x[i] - x[i - 1]).norm(), (x[i + 1] - x[i]).norm()
            s = la / ti.max(la + lb, f32(1e-30))
            rgba[i] = rgba[i - 1] * (f32(1.0) - s) + rgba[i + 1] * s
