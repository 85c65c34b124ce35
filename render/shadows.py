"""Self-shadowing from the key light: a deep opacity map (Yuksel & Keyser 2008) for hair and a
depth map for meshes, both in an orthographic view along the light fitted to the scene.

Hair is splatted from the light twice. Pass one keeps, per texel, the depth z0 of the hair
nearest the light. Pass two adds each fibre sample's opacity into the depth slab that holds it,
slabs starting at z0 and growing geometrically (thin where the outer hair is, thick inside).
A prefix sum over slabs gives the opacity accumulated in front of any depth; light reaching a
point is T = exp(-density * opacity), times the fraction of the 2x2 texels where no mesh lies
nearer the light. Each fibre sample carries the fraction of a texel's area its width covers,
so the opacity of a fixed amount of hair does not depend on the map's resolution.
"""

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import taichi as ti

from .bundles import ShadowMapArgs
from .camera import OrthoView, f32, mat4f, project, project_vertices, vec3f, vec4f
from .raster import clear_keys_2d, key_depth, raster_triangles
from .runtime import buffer, chunks, upload
from .threads import spread, spread_rows, spread_run

# fixed-point steps per unit of opacity in the deep opacity map: a sample adds at most about 1
# (one texel covered along one texel), so 2^24 keeps float32's resolution and a texel can sum
# 2^39 units (far more fibres than a head has) in an int64
OPACITY_STEPS = 16777216.0

_cleared: dict = {}   # map name -> its fixed-point slab buffer, known to be all 0 before a splat


@dataclass(frozen=True, kw_only=True)
class ShadowSettings:
    """enabled: cast shadows from the key light. resolution: side of the light's maps in texels,
    in [16, 8192]. layers: opacity slabs per texel, in [1, 32]. first_layer: thickness of the
    first slab as a fraction of the scene's diameter, in (0, 1]; each next slab is `growth`
    (>= 1) times thicker. density >= 0: scales hair opacity in shadows (lower for light hair,
    which transmits more). mesh_shadows: meshes occlude the light too (for hair and themselves).
    """

    enabled: bool = True
    resolution: int = 512
    layers: int = 8
    first_layer: float = 1.0 / 256.0
    growth: float = 2.0
    density: float = 1.0
    mesh_shadows: bool = True

    def __post_init__(self):
        if not (int(self.resolution) == self.resolution and 16 <= self.resolution <= 8192):
            raise ValueError(f"resolution must be an integer in [16, 8192] texels, got {self.resolution}")
        if not (int(self.layers) == self.layers and 1 <= self.layers <= 32):
            raise ValueError(f"layers must be an integer in [1, 32], got {self.layers}")
        if not 0.0 < self.first_layer <= 1.0:
            raise ValueError(f"first_layer must be in (0, 1] of the scene diameter, got {self.first_layer}")
        if not self.growth >= 1.0:
            raise ValueError(f"growth must be >= 1, got {self.growth}")
        if not self.density >= 0.0:
            raise ValueError(f"density must be >= 0, got {self.density}")

    def bounds(self, diameter: float) -> np.ndarray:
        """Slab boundaries [m] behind the first hair, (layers + 1,) float32, from 0."""
        thickness = self.first_layer * diameter * self.growth ** np.arange(self.layers)
        return np.concatenate([[0.0], np.cumsum(thickness)]).astype(np.float32)


class ShadowMap(NamedTuple):
    """Device data for `transmittance`: the light's view/proj, z0 (R, R) [m], cumulative
    opacity (R, R, L), slab bounds (L + 1,) [m], mesh depth keys (R, R), and
    params = (enabled, density, depth bias [m], texel size [m])."""

    view: np.ndarray
    proj: np.ndarray
    z0: ti.Ndarray
    opacity: ti.Ndarray
    bounds: ti.Ndarray
    mesh_key: ti.Ndarray
    params: np.ndarray

    def args(self) -> ShadowMapArgs:
        """The map's arrays as one kernel argument (view, proj and params go beside it)."""
        return ShadowMapArgs(shadow_z0=self.z0, shadow_opacity=self.opacity,
                             shadow_bounds=self.bounds, shadow_mesh_key=self.mesh_key)


@ti.kernel
def clear_shadow(z0: ti.types.ndarray(dtype=f32, ndim=2),
                 opacity: ti.types.ndarray(dtype=f32, ndim=3),
                 fixed: ti.types.ndarray(dtype=ti.i64, ndim=3), full: ti.i32):
    """z0 = empty (no hair in front); full: also opacity and the fixed-point slabs = 0
    (otherwise `accumulate_slabs` of the last map left fixed at 0 and overwrites opacity)."""
    spread_rows(z0.shape[0], z0.shape[1], clear_texel, (z0, opacity, fixed, full))


@ti.func
def clear_texel(z0: ti.template(), opacity: ti.template(), fixed: ti.template(), full: ti.i32,
                i: ti.i32, j: ti.i32):
    """`clear_shadow` for texel (i, j)."""
    z0[i, j] = f32(3.0e38)
    if full:
        for k in range(opacity.shape[2]):
            opacity[i, j, k] = f32(0.0)
            fixed[k, i, j] = 0


@ti.func
def bilinear(p: vec4f, size: ti.i32):
    """Lower-left texel (i, j) and weights (fx, fy) of the 2x2 block around screen point p."""
    u, v = p[0] - f32(0.5), p[1] - f32(0.5)
    i, j = ti.cast(ti.floor(u), ti.i32), ti.cast(ti.floor(v), ti.i32)
    i = ti.math.clamp(i, 0, size - 2)
    j = ti.math.clamp(j, 0, size - 2)
    fx = ti.math.clamp(u - ti.cast(i, f32), f32(0.0), f32(1.0))
    fy = ti.math.clamp(v - ti.cast(j, f32), f32(0.0), f32(1.0))
    return i, j, fx, fy


@ti.func
def corner_weight(fx: f32, fy: f32, dx: ti.i32, dy: ti.i32) -> f32:
    wx = ti.select(dx == 0, f32(1.0) - fx, fx)
    wy = ti.select(dy == 0, f32(1.0) - fy, fy)
    return wx * wy


@ti.func
def texel_of(p: vec4f, size: ti.i32):
    """Texel (i, j) holding screen point p, clamped to the map."""
    i = ti.math.clamp(ti.cast(ti.floor(p[0]), ti.i32), 0, size - 1)
    j = ti.math.clamp(ti.cast(ti.floor(p[1]), ti.i32), 0, size - 1)
    return i, j


@ti.func
def slab_of(bounds: ti.template(), layers: ti.i32, dz: f32) -> ti.i32:
    """The slab holding depth dz [m] behind z0: the last k < layers with bounds[k] <= dz (0
    if none). The bounds increase, so that is how many of bounds[1:layers] are <= dz: a
    count with a fixed trip, no data-dependent exit to mispredict."""
    slab = 0
    for k in range(1, layers):
        slab += ti.select(bounds[k] <= dz, 1, 0)
    return slab


@ti.kernel
def splat_hair_depth(n: ti.i32, seg: ti.types.ndarray(dtype=ti.i32, ndim=1),
                     screen: ti.types.ndarray(dtype=vec4f, ndim=1),
                     z0: ti.types.ndarray(dtype=f32, ndim=2)):
    """z0 (R, R) = min depth [m] of the hair samples in each texel. One thread per segment,
    sampled about once per texel along its length."""
    size = z0.shape[0]
    for e in range(n):
        a, b = screen[seg[e]], screen[seg[e] + 1]
        ns = ti.max(1, ti.cast(ti.ceil(ti.sqrt((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2)), ti.i32))
        for s in range(ns):
            p = a + (b - a) * ((ti.cast(s, f32) + f32(0.5)) / ti.cast(ns, f32))
            i, j = texel_of(p, size)
            # most samples lie behind the front: a plain read spares them the atomic
            if p[2] < z0[j, i]:
                ti.atomic_min(z0[j, i], p[2])


@ti.kernel
def splat_hair_opacity(n: ti.i32, seg: ti.types.ndarray(dtype=ti.i32, ndim=1),
                       screen: ti.types.ndarray(dtype=vec4f, ndim=1),
                       width: ti.types.ndarray(dtype=f32, ndim=1), alpha: f32, texel: f32,
                       z0: ti.types.ndarray(dtype=f32, ndim=2),
                       bounds: ti.types.ndarray(dtype=f32, ndim=1),
                       fixed: ti.types.ndarray(dtype=ti.i64, ndim=3)):
    """Add each hair sample's opacity, alpha * (fraction of a texel its width [m] covers) *
    (its length in texels), into the slab (L, R, R) that holds it behind its texel's z0: in
    fixed point (OPACITY_STEPS per unit), whose integer sums do not depend on the order the
    threads add in, so a frame renders to the same bytes every time (float atomics did not)."""
    size, layers = z0.shape[0], fixed.shape[0]
    for e in range(n):
        k = seg[e]
        a, b = screen[k], screen[k + 1]
        length = ti.sqrt((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2)
        ns = ti.max(1, ti.cast(ti.ceil(length), ti.i32))
        for s in range(ns):
            t = (ti.cast(s, f32) + f32(0.5)) / ti.cast(ns, f32)
            p = a + (b - a) * t
            w = width[k] + (width[k + 1] - width[k]) * t
            i, j = texel_of(p, size)
            dz = p[2] - z0[j, i]
            slab = slab_of(bounds, layers, dz)
            amount = alpha * ti.min(w / texel, f32(1.0)) * length / ti.cast(ns, f32)
            ti.atomic_add(fixed[slab, j, i], ti.cast(ti.round(amount * OPACITY_STEPS), ti.i64))


@ti.kernel
def accumulate_slabs(fixed: ti.types.ndarray(dtype=ti.i64, ndim=3),
                     opacity: ti.types.ndarray(dtype=f32, ndim=3)):
    """Prefix-sum the slabs of each texel: opacity[i, j, k] = hair opacity up to slab k's end
    (from the fixed-point sums), and set the sums back to 0 for the next map: zeroing them
    here, while their cache lines are loaded, spares the next map a pass over them."""
    spread_rows(opacity.shape[0], opacity.shape[1], accumulate_texel, (fixed, opacity))


@ti.func
def accumulate_texel(fixed: ti.template(), opacity: ti.template(), i: ti.i32, j: ti.i32):
    """`accumulate_slabs` for texel (i, j)."""
    total = ti.i64(0)
    for k in range(opacity.shape[2]):
        total += fixed[k, i, j]
        fixed[k, i, j] = 0
        opacity[i, j, k] = ti.cast(total, f32) / f32(OPACITY_STEPS)


@ti.func
def column_opacity(z0: ti.template(), opacity: ti.template(), bounds: ti.template(),
                   i: ti.i32, j: ti.i32, depth: f32) -> f32:
    """Hair opacity in front of `depth` [m] in texel (i, j), linear within a slab."""
    result = f32(0.0)
    dz = depth - z0[j, i]
    if dz > 0.0:
        layers = opacity.shape[2]
        slab = slab_of(bounds, layers, dz)
        before = f32(0.0)
        if slab > 0:
            before = opacity[j, i, slab - 1]
        frac = ti.math.clamp((dz - bounds[slab]) / (bounds[slab + 1] - bounds[slab]),
                             f32(0.0), f32(1.0))
        result = before + (opacity[j, i, slab] - before) * frac
    return result


@ti.func
def shadow_terms(p: vec3f, view: mat4f, proj: vec4f, sm: ti.template(), params: vec4f) -> vec3f:
    """(hair opacity in front of p towards the light ~ fibres crossed, fraction of the light
    not blocked by meshes in [0, 1], hair opacity behind p in its column) at world point p [m],
    bilinear over the 2x2 texels around it; (0, 1, 0) when shadows are off. view, proj, sm,
    params: the light's map (`ShadowMap`; sm its ShadowMapArgs)."""
    z0, opacity, bounds, mesh_key = ti.static(sm.shadow_z0, sm.shadow_opacity, sm.shadow_bounds,
                                              sm.shadow_mesh_key)
    result = vec3f(0.0, 1.0, 0.0)
    if params[0] > 0.0:
        s = project(view, proj, p)
        i, j, fx, fy = bilinear(s, z0.shape[0])
        hair, lit, behind = f32(0.0), f32(0.0), f32(0.0)
        last = opacity.shape[2] - 1
        for dy, dx in ti.static(ti.ndrange(2, 2)):
            w = corner_weight(fx, fy, dx, dy)
            front = column_opacity(z0, opacity, bounds, i + dx, j + dy, s[2])
            hair += w * front
            behind += w * ti.max(opacity[j + dy, i + dx, last] - front, f32(0.0))
            if key_depth(mesh_key[j + dy, i + dx]) > s[2] - params[2]:
                lit += w
        result = vec3f(hair, lit, behind)
    return result


@ti.func
def transmittance(p: vec3f, view: mat4f, proj: vec4f, sm: ti.template(), params: vec4f) -> f32:
    """Fraction in [0, 1] of the key light reaching world point p [m]:
    exp(-density x hair opacity in front) x mesh visibility. view, proj, sm, params: the
    light's map, as `shadow_terms` takes it."""
    t = shadow_terms(p, view, proj, sm, params)
    return ti.exp(-params[1] * t[0]) * t[1]


@ti.func
def tent_weight(f: f32, d: ti.i32) -> f32:
    """Weight of texel g + d, d in {-1, 0, 1}, of the tent three texels wide around a point a
    fraction f in [0, 1) into texel g: the mean of the bilinear weights half a texel either way,
    ((1 - f) / 2, 1 / 2, f / 2)."""
    return ti.select(d == 0, f32(0.5), ti.select(d < 0, f32(0.5) * (f32(1.0) - f), f32(0.5) * f))


@ti.func
def filtered_transmittance(p: vec3f, view: mat4f, proj: vec4f, sm: ti.template(),
                           params: vec4f) -> f32:
    """`transmittance` at world point p [m] filtered wider for surfaces: hair opacity and mesh
    visibility averaged over the 3 x 3 texels around p with tent weights (`tent_weight`: the
    mean of the 2 x 2 bilinear lookups half a texel either way on each axis). A surface the
    light grazes stretches one texel over several pixels; there a 2 x 2 lookup's edge follows
    the texel grid in visible steps, the tent ramps it over about three texels instead. 1 when
    shadows are off."""
    z0, opacity, bounds, mesh_key = ti.static(sm.shadow_z0, sm.shadow_opacity, sm.shadow_bounds,
                                              sm.shadow_mesh_key)
    result = f32(1.0)
    if params[0] > 0.0:
        s = project(view, proj, p)
        size = z0.shape[0]
        gx, gy = ti.floor(s[0]), ti.floor(s[1])
        fx, fy = s[0] - gx, s[1] - gy
        i0, j0 = ti.cast(gx, ti.i32), ti.cast(gy, ti.i32)
        hair, lit = f32(0.0), f32(0.0)
        for dy, dx in ti.static(ti.ndrange((-1, 2), (-1, 2))):
            i = ti.math.clamp(i0 + dx, 0, size - 1)
            j = ti.math.clamp(j0 + dy, 0, size - 1)
            w = tent_weight(fx, dx) * tent_weight(fy, dy)
            hair += w * column_opacity(z0, opacity, bounds, i, j, s[2])
            if key_depth(mesh_key[j, i]) > s[2] - params[2]:
                lit += w
        result = ti.exp(-params[1] * hair) * lit
    return result


@ti.kernel
def points_shadow_terms(n: ti.i32, x: ti.types.ndarray(dtype=vec3f, ndim=1), view: mat4f,
                        proj: vec4f, sm: ShadowMapArgs, params: vec4f, masked: ti.i32,
                        mark: ti.types.ndarray(dtype=ti.i32, ndim=1), row: ti.i32,
                        n_chunks: ti.i32, out: ti.types.ndarray(dtype=vec3f, ndim=2)):
    """out[row, i] = shadow_terms at x[i] [m] (one row per light), shapes (n,); masked: only
    where mark[i] > 0. n_chunks threads, each over a run of points, the runs in
    `threads.spread`'s mixed order (marked points come in runs)."""
    span, factor = spread(n_chunks)
    for step in range(span * factor):
        lo, hi = spread_run(step, span, factor, n, n_chunks)
        for k in range(lo, hi):
            if not masked or mark[k] > 0:
                out[row, k] = shadow_terms(x[k], view, proj, sm, params)


@ti.kernel
def points_transmittance(n: ti.i32, x: ti.types.ndarray(dtype=vec3f, ndim=1), view: mat4f,
                         proj: vec4f, sm: ShadowMapArgs, params: vec4f, masked: ti.i32,
                         mark: ti.types.ndarray(dtype=ti.i32, ndim=1), n_chunks: ti.i32,
                         out: ti.types.ndarray(dtype=f32, ndim=1)):
    """out[i] = transmittance at x[i] [m], shapes (n,); masked: only where mark[i] > 0.
    n_chunks threads over runs of points, as `points_shadow_terms`."""
    span, factor = spread(n_chunks)
    for step in range(span * factor):
        lo, hi = spread_run(step, span, factor, n, n_chunks)
        for k in range(lo, hi):
            if not masked or mark[k] > 0:
                out[k] = transmittance(x[k], view, proj, sm, params)


@ti.kernel
def bounding_box(n: ti.i32, x: ti.types.ndarray(dtype=vec3f, ndim=1), n_chunks: ti.i32,
                 box: ti.types.ndarray(dtype=f32, ndim=1)):
    """box = (min x, min y, min z, max x, max y, max z) of x[:n] [m]. Each of n_chunks
    threads reduces a contiguous chunk in registers, then one atomic per chunk and bound
    (atomics on fixed addresses per point cost 70 ns a point on the CPU)."""
    for k in ti.static(range(3)):
        box[k] = f32(3.0e38)
        box[k + 3] = f32(-3.0e38)
    span, factor = spread(n_chunks)   # fewer chunks than 512 per CPU thread: spread them
    for step in range(span * factor):
        first, end = spread_run(step, span, factor, n, n_chunks)
        if first < end:
            lo, hi = vec3f(3.0e38, 3.0e38, 3.0e38), vec3f(-3.0e38, -3.0e38, -3.0e38)
            for i in range(first, end):
                lo = ti.min(lo, x[i])
                hi = ti.max(hi, x[i])
            for k in ti.static(range(3)):
                ti.atomic_min(box[k], lo[k])
                ti.atomic_max(box[k + 3], hi[k])


def _scene_sphere(parts: list[dict]) -> tuple[np.ndarray, float]:
    """Centre [m] and radius [m] of a sphere around the bounding box of the uploaded points."""
    boxes = []
    for d in parts:
        box = buffer("scene_box", f32, (6,))
        bounding_box(d["n_vertices"], d["x"], chunks(d["n_vertices"], 64, 1024), box)
        boxes.append(box.to_numpy().astype(np.float64).reshape(2, 3))
    lo, hi = np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)
    return 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)) * 1.01, 1e-6)


def build_shadow_map(settings: ShadowSettings, to_light, hair: dict | None,
                     mesh: dict | None) -> ShadowMap:
    """Render the light's maps. hair/mesh: dicts of uploaded device arrays from `render.frame`
    (both: x, width, n_vertices; hair also: seg, n_segments,
    opacity; mesh also: faces, n_faces) or None. Disabled settings or an empty scene give a map that lets all
    light through."""
    parts = [d for d in (hair, mesh) if d is not None]
    enabled = settings.enabled and bool(parts)
    r = settings.resolution if enabled else 16
    layers = settings.layers
    # a light without shadows gets small maps of its own: sharing the names with the shadowed
    # lights' maps would reallocate those (tens of MB) at every change between the two
    name = "shadow" if enabled else "shadow_off"
    z0 = buffer(f"{name}_z0", f32, (r, r))
    opacity = buffer(f"{name}_opacity", f32, (r, r, layers))
    # slab-major, unlike `opacity`: a strand's samples one texel apart then mostly land in the
    # cache line of the sample before (texel-major, each sample would miss on a line of its own)
    fixed = buffer(f"{name}_opacity_fixed", ti.i64, (layers, r, r))
    mesh_key = buffer(f"{name}_mesh_key", ti.i64, (r, r))
    # a map with hair leaves its slab sums at 0 and fills all of opacity (`accumulate_slabs`):
    # only new buffers and maps without hair need clearing in full (the 24 MB of a 512^2 x 8
    # map cost a pass of ~10 ms per light on the CPU)
    splats = enabled and hair is not None
    clean = _cleared.pop(name, None) is fixed
    clear_shadow(z0, opacity, fixed, int(not (splats and clean)))
    if not splats:
        _cleared[name] = fixed
    clear_keys_2d(mesh_key)
    if not enabled:
        bounds = upload(f"{name}_bounds", settings.bounds(1.0), f32)
        return ShadowMap(np.eye(4, dtype=np.float32), np.array([1, 0, 0, 1], np.float32), z0,
                         opacity, bounds, mesh_key, np.zeros(4, np.float32))
    centre, radius = _scene_sphere(parts)
    light = OrthoView(to_light=np.asarray(to_light, float), centre=centre, radius=radius,
                      resolution=r)
    view, proj = light.matrices()
    bounds = upload("shadow_bounds", settings.bounds(2.0 * radius), f32)
    if mesh is not None and settings.mesh_shadows:
        ls = buffer("shadow_mesh_screen", vec4f, (max(mesh["n_vertices"], 1),), 4)
        scratch = buffer("shadow_mesh_width_px", f32, (max(mesh["n_vertices"], 1),))
        project_vertices(mesh["n_vertices"], mesh["x"], mesh["width"], view, proj, ls, scratch)
        raster_triangles(mesh["n_faces"], ls, mesh["faces"], 0.0, mesh_key)
    if hair is not None:
        ls = buffer("shadow_hair_screen", vec4f, (hair["n_vertices"],), 4)
        scratch = buffer("shadow_hair_width_px", f32, (hair["n_vertices"],))
        project_vertices(hair["n_vertices"], hair["x"], hair["width"], view, proj, ls, scratch)
        splat_hair_depth(hair["n_segments"], hair["seg"], ls, z0)
        splat_hair_opacity(hair["n_segments"], hair["seg"], ls, hair["width"], hair["opacity"],
                           light.texel_size, z0, bounds, fixed)
        accumulate_slabs(fixed, opacity)
        _cleared[name] = fixed
    params = np.array([1.0, settings.density, 2.0 * light.texel_size, light.texel_size],
                      dtype=np.float32)
    return ShadowMap(view, proj, z0, opacity, bounds, mesh_key, params)
