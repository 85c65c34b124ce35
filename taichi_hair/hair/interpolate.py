"""Dense hair from guide strands.

Setup (once): the scalp chart, the Delaunay triangulation of the guide roots and the location of
every dense root in it come from `taichi_hair.hair.scalp`; each dense root also gets its nearest
guide for clumping and seeded per-strand variation, or, when rest shapes are given, its rest
edges and the guides' rest frames (see `Interpolator`).

Per frame (Taichi, ndarray arguments so each kernel compiles once per process; the head pose
travels as a [4] vec3 ndarray, rows of R then t, never as a scalar matrix argument, whose
type could be fixed at float32 before `taichi_hair.init` chose the precision):
  1. `_guide_frames`: Bishop frame of every guide edge by parallel transport from the root
     (one thread per guide: the transport is serial along the strand).
  2. `_dense_nodes`: one thread per dense strand: barycentric interpolation of the three guides'
     root-relative shapes, clump interpolation (one guide plus an offset carried in its Bishop
     frame, so it follows the guide's bending and twist), the per-strand blend of both, and
     frizz growing toward the tip.
     With rest shapes (an imported style), `_dense_from_edges` replaces it: one thread per
     dense strand: each rest edge turned by the rotations of the same edge of its guides (the
     clump guide and the triangle's three, blended) and laid end to end from the root.
  3. `_push_out_of_ellipsoid`: one thread per node: nodes closer to the head than a margin move
     out along the surface normal (only when the head is a sphere or ellipsoid).

Positions are metres; arrays are [strand, node, xyz]; node 0 is the root.
"""

import math
import time

import numpy as np
import taichi as ti

from ..rods.frames import parallel_transport
from ..rods.linalg import rotate_rows, unrotate_rows
from ..runtime import ensure_init, precision
from ..validation import choice, is_real
from .scalp import (ScalpChart, delaunay, locate, nearest, perpendicular,  # noqa: F401
                    sample_scalp_roots)

MODES = ("barycentric", "clump", "blend")

vec2 = ti.math.vec2
vec3 = ti.math.vec3
ivec5 = ti.types.vector(5, ti.i32)  # integer element types do not depend on the float precision
Vec3s1 = ti.types.ndarray(dtype=vec3, ndim=1)
Vec3s2 = ti.types.ndarray(dtype=vec3, ndim=2)
Scalars2 = ti.types.ndarray(dtype=float, ndim=2)  # `float` resolves when the kernel compiles


# ---------------------------------------------------------------- per-frame kernels

@ti.func
def _rotate(head: ti.template(), v):
    """R v for the head pose head[0..2] = rows of R (head[3] = t is not used)."""
    return rotate_rows(head[0], head[1], head[2], v)


@ti.func
def _unrotate(head: ti.template(), v):
    """R^T v for the head pose head[0..2] = rows of R."""
    return unrotate_rows(head[0], head[1], head[2], v)


@ti.kernel
def _guide_frames(x: Vec3s2, normal: Vec3s1, u_rest: Vec3s1, head: Vec3s1, t_out: Vec3s2, u_out: Vec3s2):
    """Bishop frame (t^j, u^j) of every guide edge j: u^0 is the rest reference u (carried by the
    head rotation, head [4] = rows of R then t) transported from the root normal to t^0, then
    edge to edge. One thread per guide; the transport is serial along its strand."""
    for g in range(x.shape[0]):
        t_prev, u = _rotate(head, normal[g]), _rotate(head, u_rest[g])
        for j in range(x.shape[1] - 1):
            e = x[g, j + 1] - x[g, j]
            t = t_prev
            if e.norm() > 1e-12:  # a zero-length edge keeps the previous tangent
                t = e.normalized()
            u = parallel_transport(u, t_prev, t)
            u = (u - u.dot(t) * t).normalized()  # round-off drift off the normal plane
            t_out[g, j], u_out[g, j] = t, u
            t_prev = t


@ti.func
def _at(x: ti.template(), g, q):
    """Position on guide g at fractional node index q (linear between nodes)."""
    k = ti.min(ti.cast(ti.floor(q), ti.i32), x.shape[1] - 2)
    f = q - k
    return (1.0 - f) * x[g, k] + f * x[g, k + 1]


@ti.func
def _edge(q, n_nodes):
    """Edge whose frame carries node position q: the edge arriving at q (edge 0 at the root)."""
    return ti.math.clamp(ti.cast(ti.ceil(q), ti.i32) - 1, 0, n_nodes - 2)


@ti.func
def _hash01(key, i):
    """Two uniform numbers in [-1, 1) from (strand key, node), fixed across frames."""
    h = ti.cast(key, ti.u32) * ti.u32(0x9E3779B1) + ti.cast(i, ti.u32)
    out = vec2(0.0)
    for k in ti.static(range(2)):
        h = (h ^ (h >> 16)) * ti.u32(0x7FEB352D)
        h = (h ^ (h >> 15)) * ti.u32(0x846CA68B)
        h = h ^ (h >> 16)
        out[k] = ti.cast(ti.cast(h >> 8, ti.i32), float) / 8388608.0 - 1.0
    return out


@ti.kernel
def _dense_nodes(x: Vec3s2, t: Vec3s2, u: Vec3s2, idx: ti.types.ndarray(dtype=ivec5, ndim=1),
                 w: Vec3s1, rel: Vec3s2, local: Vec3s1, par: Scalars2, head: Vec3s1, out: Vec3s2):
    """Dense nodes out[d, i] [m]. idx[d] = (3 triangle guides, clump guide, frizz key); w[d] the
    triangle weights; rel[d, k] = rest dense root - rest root of guide k (triangle, then clump);
    local[d] the clump offset in the clump guide's rest root frame (u, v, normal);
    par[d, :] = (blend, start node, node step, frizz amplitude [m], clump offset scale at the
    tip); head [4] the head pose (rows of R, then t).
    One thread per dense strand: the terms shared by its nodes are computed once, then the
    nodes (independent of each other) in a loop."""
    n = x.shape[1]
    for d in range(out.shape[0]):
        blend, q0, step, frizz, tip = par[d, 0], par[d, 1], par[d, 2], par[d, 3], par[d, 4]
        k0, k1, k2, g, key = idx[d][0], idx[d][1], idx[d][2], idx[d][3], idx[d][4]
        wd, off = w[d], local[d]
        # each guide carries the dense root rigidly with the head from its own root
        base_b = (wd[0] * (x[k0, 0] + _rotate(head, rel[d, 0]) - _at(x, k0, q0))
                  + wd[1] * (x[k1, 0] + _rotate(head, rel[d, 1]) - _at(x, k1, q0))
                  + wd[2] * (x[k2, 0] + _rotate(head, rel[d, 2]) - _at(x, k2, q0)))
        j0 = _edge(q0, n)
        # the root offset is subtracted as carried by the start frame, so node 0 is the root
        base_c = (x[g, 0] + _rotate(head, rel[d, 3]) - _at(x, g, q0)
                  - (off[0] * u[g, j0] + off[1] * t[g, j0].cross(u[g, j0]) + off[2] * t[g, j0]))
        for i in range(n):
            q = q0 + i * step
            s = i / (n - 1.0)
            xb = base_b + wd[0] * _at(x, k0, q) + wd[1] * _at(x, k1, q) + wd[2] * _at(x, k2, q)
            j = _edge(q, n)
            uj, tj = u[g, j], t[g, j]
            vj = tj.cross(uj)
            xc = base_c + _at(x, g, q) + (1.0 + (tip - 1.0) * s) * (off[0] * uj + off[1] * vj + off[2] * tj)
            fz = vec3(0.0)
            if frizz > 0.0:
                noise = _hash01(key, i)
                fz = frizz * s * s * (noise[0] * uj + noise[1] * vj)
            out[d, i] = (1.0 - blend) * xb + blend * xc + fz


@ti.func
def _nearest_on_ellipsoid(p, r):
    """Nearest point of the axis-aligned ellipsoid with semi-axes r to p (both in its frame):
    x = p r^2 / (r^2 + s) with s the root of sum (p r / (r^2 + s))^2 = 1, by bisection."""
    rmin = ti.min(r[0], r[1], r[2])
    lo, hi = -rmin * rmin, 0.0
    if ((p / r) ** 2).sum() > 1.0:
        lo, hi = 0.0, ti.max(r[0], r[1], r[2]) * p.norm()
    # each halving gains a bit: 30 take the bracket (at most the head's size squared) below
    # float32's resolution of the root, float64 needs 60
    for _ in range(ti.static(30 if precision() == "float32" else 60)):
        mid = 0.5 * (lo + hi)
        if ((p * r / (r * r + mid)) ** 2).sum() > 1.0:
            lo = mid
        else:
            hi = mid
    y = p * r * r / (r * r + 0.5 * (lo + hi))
    # on the medial axis the root escapes the bracket: scale back onto the surface
    return y / ti.sqrt(((y / r) ** 2).sum())


@ti.kernel
def _push_out_of_ellipsoid(out: Vec3s2, head: Vec3s1, shape: Vec3s1):
    """Move non-root nodes closer than the margin to the ellipsoid to its surface point + margin
    along the normal. shape [3] = (rest centre [m], semi-axes [m] along the rest axes, (margin
    [m], 0, 0)); the head pose head [4] (rows of R, then t) carries centre and axes.
    One thread per (strand, node)."""
    radii, margin = shape[1], shape[2][0]
    centre = _rotate(head, shape[0]) + head[3]
    reach = ti.max(radii[0], radii[1], radii[2]) + margin
    # the ellipsoid grown by the margin lies inside the ellipsoid scaled by 1 + margin / (its
    # least semi-axis) (support functions: h(u) + margin <= h(u) (1 + margin / r_min)), so a
    # node outside that one (with room for rounding) needs no nearest-point search
    grown = (1.0 + margin / ti.min(radii[0], radii[1], radii[2])) * radii
    for d, i in ti.ndrange(out.shape[0], out.shape[1]):
        rel = out[d, i] - centre
        if i > 0 and rel.norm() < reach:
            p = _unrotate(head, rel)
            if ((p / grown) ** 2).sum() > 1.0 + 1e-3:
                continue
            if p.norm() < 1e-9 * reach:  # the centre itself: leave along the shortest axis
                rmin = ti.min(radii[0], radii[1], radii[2])
                p = 1e-6 * reach * ti.cast(radii == rmin, float).normalized()
            y = p * radii[0] / p.norm()  # sphere: closed form
            if radii[0] != radii[1] or radii[1] != radii[2]:
                y = _nearest_on_ellipsoid(p, radii)
            inside = ((p / radii) ** 2).sum() < 1.0
            dist = (p - y).norm() * ti.select(inside, -1.0, 1.0)
            if dist < margin:
                out[d, i] = centre + _rotate(head, y + margin * (y / (radii * radii)).normalized())


@ti.func
def _turned(e, t0, u0, t1, u1):
    """e turned by the rotation taking the frame (u0, t0 x u0, t0) to (u1, t1 x u1, t1)."""
    v0, v1 = t0.cross(u0), t1.cross(u1)
    return e.dot(u0) * u1 + e.dot(v0) * v1 + e.dot(t0) * t1


@ti.kernel
def _dense_from_edges(x: Vec3s2, t: Vec3s2, u: Vec3s2, t_rest: Vec3s2, u_rest: Vec3s2,
                      idx: ti.types.ndarray(dtype=ivec5, ndim=1), w: Vec3s1, rel: Vec3s2,
                      par: Scalars2, head: Vec3s1, edges: Vec3s2, out: Vec3s2):
    """Dense nodes out[d, i] [m] of strands with rest shapes: the root as in `_dense_nodes`, then
    each rest edge edges[d, j] [m] turned by the rotation of edge j of each of its guides
    (Bishop frame at rest t_rest, u_rest -> now t, u), blended with weights (1 - blend) w[d]
    (triangle) and blend (clump guide), and rescaled to its rest length: inextensible, exact
    at rest and rigid under a rigid head motion. One thread per dense strand, serial along it."""
    for d in range(out.shape[0]):
        blend, wd = par[d, 0], w[d]
        weight = ti.Vector([(1.0 - blend) * wd[0], (1.0 - blend) * wd[1], (1.0 - blend) * wd[2], blend])
        root = vec3(0.0)
        for k in ti.static(range(4)):
            root += weight[k] * (x[idx[d][k], 0] + _rotate(head, rel[d, k]))
        out[d, 0] = root
        g = idx[d][3]
        for j in range(out.shape[1] - 1):
            e = edges[d, j]
            turned = vec3(0.0)
            for k in ti.static(range(4)):
                m = idx[d][k]
                turned += weight[k] * _turned(e, t_rest[m, j], u_rest[m, j], t[m, j], u[m, j])
            if turned.norm() < 1e-6 * e.norm():  # guides turned opposite ways: follow the clump
                turned = _turned(e, t_rest[g, j], u_rest[g, j], t[g, j], u[g, j])
            out[d, j + 1] = out[d, j] + turned * (e.norm() / turned.norm())


# ---------------------------------------------------------------- the interpolator

class Interpolator:
    """Dense strands [D, n_nodes] from guides [G, n_nodes] (all in metres).

    guide_roots, guide_normals: [G, 3] rest root positions and outward scalp normals (G >= 3).
    dense_roots: [D, 3] rest root positions of the dense strands on the scalp.
    mode: "barycentric" (three guides of the enclosing triangle), "clump" (nearest guide plus
        the root offset carried in its Bishop frame) or "blend" (per-strand mix, `blend`).
    blend: weight of the clump result in [0, 1], a scalar or an array [D] (mode "blend" only).
    clump_radius: distance [m] from its guide a clumped strand narrows to at the tip (None:
        keep the root offset all along).
    frizz: mean amplitude [m] of per-node noise at the tip (grows as (i / (N-1))^2; per-strand
        amplitude uniform in [0.5, 1.5] x frizz), fixed across frames.
    length_variation: strands are shortened by a factor uniform in [1 - length_variation, 1]
        (in [0, 1)); curl_phase_variation: each strand starts up to this many edges into the
        guides' shape (in [0, (n_nodes - 1) / 2]), which shifts the phase of curls.
    seed: seeds all per-strand variation.
    Keep clump offsets (root spacing, clump_radius) well below the guides' radius of curvature:
    an offset d carried in the frame of a curve of curvature k scales the strand's curvature
    by 1 / (1 - k d cos(angle)), so a clump wider than a curl is no longer a ringlet.
    head: None; a sphere or ellipsoid (centre [3] m, radius m or semi-axes [3] m, axis-aligned
        at rest), which pushes non-root nodes out to its surface + head_margin [m] in a kernel;
        or a callable mapping points [M, 3] to pushed points [M, 3] (runs on the host).
    rest_guides [G, n_nodes, 3], rest_shapes [D, n_nodes, 3] (m), given together: the guides'
        rest positions and the shapes the dense strands must have when the guides are there
        (an imported hairstyle). The root is placed as in the modes above; every rest edge j
        then turns as edge j of the strand's guides turns (the rotation of their Bishop
        frames from rest, blended with the mode's weights) and keeps its rest length, and the
        edges are laid end to end: at rest the output is rest_shapes (to round-off), a rigid
        head motion moves it rigidly, and dense strands are inextensible however far they lie
        from their guides. Node 0 of rest_shapes must be dense_roots (within 1e-6 m); frizz,
        length_variation, curl_phase_variation and clump_radius do not apply. A head collider
        still acts on top: rest nodes within head_margin of it are moved.
    """

    def __init__(self, guide_roots, guide_normals, dense_roots, n_nodes, *, mode="blend",
                 blend=0.5, clump_radius=None, frizz=0.0, length_variation=0.0,
                 curl_phase_variation=0.0, seed=0, head=None, head_margin=0.002,
                 rest_guides=None, rest_shapes=None):
        ensure_init()
        roots, normals, dense = _check_setup(guide_roots, guide_normals, dense_roots, n_nodes)
        self.n_guides, self.n_dense, self.n_nodes = len(roots), len(dense), int(n_nodes)
        rest = _check_rest(rest_guides, rest_shapes, roots, dense, self.n_nodes)
        varied = frizz or length_variation or curl_phase_variation or clump_radius is not None
        if rest is not None and varied:
            raise ValueError("frizz, length_variation, curl_phase_variation and clump_radius must keep "
                             "their defaults with rest_shapes (the rest shapes fix every strand)")
        self._head, self._ellipsoid = _check_head(head, head_margin)
        self._dtype = np.float32 if precision() == "float32" else np.float64
        centre = None if self._ellipsoid is None else self._ellipsoid[0]
        chart = ScalpChart.fit(roots, normals, centre)
        try:
            self.triangles = delaunay(chart.project(roots, "guide_roots"))
        except ValueError as exc:
            raise ValueError(f"guide_roots cannot be triangulated on the scalp: {exc}") from None
        tri_of, self.weights = locate(chart.project(dense, "dense_roots"), chart.project(roots),
                                      self.triangles)
        self.corners, self.guide_of = self.triangles[tri_of], nearest(dense, roots)
        par, keys = _variation(self.n_dense, self.n_nodes, mode, blend, clump_radius, frizz,
                               length_variation, curl_phase_variation, seed,
                               np.linalg.norm(dense - roots[self.guide_of], axis=1))
        self._upload_strands(roots, normals, dense, par, keys)
        self._pose = _upload(np.vstack([np.eye(3), np.zeros(3)]), vec3, (4,), self._dtype)
        if self._ellipsoid is not None:
            c, r = self._ellipsoid
            self._shape = _upload([c, r, (float(head_margin), 0.0, 0.0)], vec3, (3,), self._dtype)
        g, d, n = self.n_guides, self.n_dense, self.n_nodes
        self._t, self._u = ti.ndarray(vec3, (g, n - 1)), ti.ndarray(vec3, (g, n - 1))
        self._out = ti.ndarray(vec3, (d, n))
        self._edges = None
        if rest is not None:
            self._fit_rest_edges(*rest)

    def _upload_strands(self, roots, normals, dense, par, keys):
        """Upload the per-strand geometry and parameters (see `_dense_nodes`)."""
        d, g = self.n_dense, self.n_guides
        u_rest = perpendicular(normals)
        offset = dense - roots[self.guide_of]
        frame = np.stack([u_rest, np.cross(normals, u_rest), normals], axis=1)[self.guide_of]
        local = np.einsum("dj,dkj->dk", offset, frame)  # offset in the guide's (u, v, normal)
        rel = dense[:, None, :] - roots[np.concatenate([self.corners, self.guide_of[:, None]], axis=1)]
        self._w = _upload(self.weights, vec3, (d,), self._dtype)
        self._rel = _upload(rel, vec3, (d, 4), self._dtype)
        self._local = _upload(local, vec3, (d,), self._dtype)
        self._normal = _upload(normals, vec3, (g,), self._dtype)
        self._u_rest = _upload(u_rest, vec3, (g,), self._dtype)
        self._idx = _upload(np.concatenate([self.corners, self.guide_of[:, None], keys[:, None]], axis=1),
                            ivec5, (d,), np.int32)
        self._par = ti.ndarray(float, (d, 5))  # `float` resolves to the precision now, not at import
        self._par.from_numpy(np.ascontiguousarray(par, dtype=self._dtype))

    def _fit_rest_edges(self, rest_guides, rest_shapes):
        """Store the dense rest edges [D, n_nodes - 1] and the guides' rest Bishop frames."""
        g, n = self.n_guides, self.n_nodes
        self._t_rest, self._u_rest_frames = ti.ndarray(vec3, (g, n - 1)), ti.ndarray(vec3, (g, n - 1))
        _guide_frames(self._guides_in(rest_guides), self._normal, self._u_rest, self._pose,
                      self._t_rest, self._u_rest_frames)  # the pose is still the identity
        self._edges = _upload(np.diff(rest_shapes, axis=1), vec3, (self.n_dense, n - 1), self._dtype)

    def interpolate(self, guide_positions, head_rotation=None, head_translation=None, out=None):
        """Dense node positions [D, n_nodes, 3] (m) as numpy.

        guide_positions: numpy [G, n_nodes, 3] (m) or a ti.ndarray of vec3 [G, n_nodes] in this
            process's precision. Node 0 is the root.
        head_rotation [3, 3], head_translation [3] (m): the head's rigid motion from rest
            (default identity); it carries the root frames and the head collider.
        out: optional numpy [D, n_nodes, 3] of this precision's dtype to fill (else a new array).
        On the CPU the kernels write straight into the numpy array (no copy)."""
        shape = (self.n_dense, self.n_nodes, 3)
        if out is None:
            out = np.empty(shape, dtype=self._dtype)
        elif not (isinstance(out, np.ndarray) and out.shape == shape and out.dtype == self._dtype
                  and out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous {np.dtype(self._dtype).name} array "
                             f"{list(shape)}, got {getattr(out, 'dtype', None)} {list(np.shape(out))}")
        self._run(guide_positions, out, head_rotation, head_translation)
        if self._head is not None:
            out[:, 1:] = self._collide_on_host(out[:, 1:])
        return out

    def interpolate_ndarray(self, guide_positions, head_rotation=None, head_translation=None):
        """As `interpolate`, into this interpolator's ti.ndarray of vec3 [D, n_nodes] (m), which
        stays on the device and is overwritten by the next call. A callable head collider makes
        a round trip through numpy."""
        self._run(guide_positions, self._out, head_rotation, head_translation)
        if self._head is not None:
            pts = self._out.to_numpy()
            pts[:, 1:] = self._collide_on_host(pts[:, 1:])
            self._out.from_numpy(pts)
        return self._out

    def _run(self, guide_positions, out, head_rotation, head_translation):
        x = self._guides_in(guide_positions)
        rot = _check_rotation(head_rotation)
        trans = np.zeros(3) if head_translation is None else np.asarray(head_translation, np.float64)
        if trans.shape != (3,) or not np.all(np.isfinite(trans)):
            raise ValueError(f"head_translation must be 3 finite numbers (m), got {head_translation!r}")
        self._pose.from_numpy(np.vstack([rot, trans]).astype(self._dtype))
        _guide_frames(x, self._normal, self._u_rest, self._pose, self._t, self._u)
        if self._edges is None:
            _dense_nodes(x, self._t, self._u, self._idx, self._w, self._rel, self._local, self._par,
                         self._pose, out)
        else:
            _dense_from_edges(x, self._t, self._u, self._t_rest, self._u_rest_frames, self._idx,
                              self._w, self._rel, self._par, self._pose, self._edges, out)
        if self._ellipsoid is not None:
            _push_out_of_ellipsoid(out, self._pose, self._shape)

    def _collide_on_host(self, pts):
        moved = np.asarray(self._head(pts.reshape(-1, 3)), dtype=pts.dtype)
        if moved.shape != (pts.size // 3, 3):
            raise ValueError(f"head collider must return an array [M, 3] like its input [{pts.size // 3}, 3], "
                             f"got {list(moved.shape)}")
        return moved.reshape(pts.shape)

    def _guides_in(self, guide_positions):
        want = (self.n_guides, self.n_nodes)
        if isinstance(guide_positions, ti.Ndarray):
            if tuple(guide_positions.shape) != want:
                raise ValueError(f"guide_positions must have shape {list(want)} (vec3), got "
                                 f"{list(guide_positions.shape)}")
            return guide_positions
        arr = np.asarray(guide_positions)
        if arr.shape != want + (3,):
            raise ValueError(f"guide_positions must have shape {list(want + (3,))}, got {list(arr.shape)}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("guide_positions must be finite, got NaN or inf")
        return np.ascontiguousarray(arr, dtype=self._dtype)


def _upload(array, dtype, shape, np_dtype):
    nd = ti.ndarray(dtype, shape)
    nd.from_numpy(np.ascontiguousarray(np.asarray(array).reshape(shape + (-1,)), dtype=np_dtype))
    return nd


def _as_points(name, value, rows=None):
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or (rows is not None and len(arr) != rows):
        raise ValueError(f"{name} must have shape [{'M' if rows is None else rows}, 3], got {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got NaN or inf")
    return arr


def _check_setup(guide_roots, guide_normals, dense_roots, n_nodes):
    roots = _as_points("guide_roots", guide_roots)
    if len(roots) < 3:
        raise ValueError(f"guide_roots must hold at least 3 guides, got {len(roots)}")
    normals = _as_points("guide_normals", guide_normals, len(roots))
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("guide_normals must be non-zero vectors, got a zero normal")
    dense = _as_points("dense_roots", dense_roots)
    if len(dense) < 1:
        raise ValueError("dense_roots must hold at least 1 root, got 0")
    if not (isinstance(n_nodes, (int, np.integer)) and n_nodes >= 3):
        raise ValueError(f"n_nodes must be an integer >= 3, got {n_nodes!r}")
    return roots, normals / norm, dense


def _check_rest(rest_guides, rest_shapes, roots, dense, n_nodes):
    """(rest_guides [G, n, 3], rest_shapes [D, n, 3]) float64, or None when neither is given."""
    if rest_guides is None and rest_shapes is None:
        return None
    if rest_guides is None or rest_shapes is None:
        raise ValueError("rest_guides and rest_shapes must be given together (or neither), got "
                         f"only {'rest_guides' if rest_shapes is None else 'rest_shapes'}")
    out = []
    for name, value, r in (("rest_guides", rest_guides, roots), ("rest_shapes", rest_shapes, dense)):
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != (len(r), n_nodes, 3):
            raise ValueError(f"{name} must have shape [{len(r)}, {n_nodes}, 3], got {list(arr.shape)}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got NaN or inf")
        gap = np.linalg.norm(arr[:, 0] - r, axis=1).max()
        if gap > 1e-6:
            root_name = "guide_roots" if name == "rest_guides" else "dense_roots"
            raise ValueError(f"{name}[:, 0] must be {root_name} (within 1e-6 m), got {gap:.3g} m away")
        out.append(arr)
    return out


def _check_head(head, margin):
    if not (is_real(margin) and math.isfinite(margin) and margin >= 0):
        raise ValueError(f"head_margin must be a finite number >= 0 m, got {margin!r}")
    if head is None or callable(head):
        return head, None
    try:
        centre, radii = head
        centre = np.asarray(centre, dtype=np.float64).reshape(3)
        radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (3,)).copy()
    except (TypeError, ValueError):
        raise ValueError(f"head must be None, a callable or (centre [3] m, radius or radii [3] m), "
                         f"got {head!r}") from None
    if not (np.all(np.isfinite(centre)) and np.all(np.isfinite(radii)) and np.all(radii > 0)):
        raise ValueError(f"head centre must be finite and its radii > 0 m, got {centre}, {radii}")
    return None, (centre, radii)


def _check_rotation(rotation):
    if rotation is None:
        return np.eye(3)
    rot = np.asarray(rotation, dtype=np.float64)
    if rot.shape != (3, 3) or not np.allclose(rot.T @ rot, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise ValueError(f"head_rotation must be a 3x3 rotation matrix (orthonormal, det +1), got {rotation!r}")
    return rot


def _variation(n_dense, n_nodes, mode, blend, clump_radius, frizz, length_variation,
               curl_phase_variation, seed, offset_length):
    """Per-strand parameters [D, 5] (see `_dense_nodes`) and frizz keys [D], all seeded."""
    choice("mode", mode, MODES)
    beta = np.asarray(blend, dtype=np.float64) if mode == "blend" else np.asarray(float(mode == "clump"))
    beta = np.full(n_dense, beta) if beta.ndim == 0 else beta
    if beta.shape != (n_dense,) or not np.all((beta >= 0) & (beta <= 1)):
        raise ValueError(f"blend must be a scalar or an array [{n_dense}] with values in [0, 1], got {blend!r}")
    for name, value, lo, hi, unit in (("frizz", frizz, 0.0, math.inf, "m"),
                                      ("length_variation", length_variation, 0.0, 1.0, ""),
                                      ("curl_phase_variation", curl_phase_variation, 0.0,
                                       (n_nodes - 1) / 2, "edges")):
        if not (is_real(value) and lo <= value <= hi and not (hi == 1.0 and value == 1.0)):
            raise ValueError(f"{name} must be a number in [{lo:g}, {hi:g}{')' if hi == 1.0 else ']'} "
                             f"{unit}, got {value!r}".replace(" ,", ","))
    if clump_radius is not None and not (is_real(clump_radius) and 0 <= clump_radius < math.inf):
        raise ValueError(f"clump_radius must be None or a finite number >= 0 m, got {clump_radius!r}")
    rng = np.random.default_rng(seed)
    u_len, u_phase, u_frizz = rng.random(n_dense), rng.random(n_dense), rng.random(n_dense)
    keys = rng.integers(0, 2**31 - 1, n_dense)
    phase = curl_phase_variation * u_phase
    step = (1.0 - length_variation * u_len) * (n_nodes - 1 - phase) / (n_nodes - 1)
    tip = np.ones(n_dense)
    if clump_radius is not None:
        tip = np.minimum(1.0, clump_radius / np.maximum(offset_length, 1e-12))
    par = np.stack([beta, phase, step, frizz * (0.5 + u_frizz), tip], axis=1)
    return par, keys


# ---------------------------------------------------------------- small helpers and benchmark

def _curly_guides(roots, normals, n_nodes, length=0.2, curl_radius=0.01, pitch=0.02):
    """Helices [G, n_nodes, 3] (m) growing along the normals from the roots (benchmark data)."""
    rise = pitch / (2 * math.pi)
    s = (np.linspace(0.0, length, n_nodes) / math.hypot(curl_radius, rise))[None, :, None]
    side = perpendicular(normals)[:, None]
    return (roots[:, None] + curl_radius * (np.cos(s) - 1.0) * side + rise * s * normals[:, None]
            + curl_radius * np.sin(s) * np.cross(normals[:, None], side))


def bench_interpolation(n_dense=100_000, n_nodes=32, n_guides=1000, repeats=5) -> dict:
    """Time one interpolation frame (blend mode, frizz, sphere head). Returns setup seconds,
    first-call seconds (kernel compilation included), compile seconds (first call minus a
    steady frame) and the median ms per frame over `repeats` after a warm-up, both for the
    ti.ndarray result and with the copy to numpy."""
    ensure_init()
    g_roots, g_normals = sample_scalp_roots(n_guides)
    d_roots, _ = sample_scalp_roots(n_dense)
    guides = _curly_guides(g_roots, g_normals, n_nodes)
    start = time.perf_counter()
    interp = Interpolator(g_roots, g_normals, d_roots, n_nodes, mode="blend", blend=0.5,
                          clump_radius=0.003, frizz=0.001, length_variation=0.1,
                          head=((0.0, 0.0, 0.0), 0.1))
    setup = time.perf_counter() - start

    def frame(numpy):
        t0 = time.perf_counter()
        out = interp.interpolate(guides) if numpy else interp.interpolate_ndarray(guides)
        ti.sync()
        return time.perf_counter() - t0, out

    first, _ = frame(False)
    frame(True)
    device = float(np.median([frame(False)[0] for _ in range(repeats)]))
    host = float(np.median([frame(True)[0] for _ in range(repeats)]))
    return {"n_dense": n_dense, "n_nodes": n_nodes, "n_guides": n_guides,
            "precision": precision(), "setup_s": setup, "first_call_s": first,
            "compile_s": max(first - device, 0.0), "ms_per_frame_ndarray": 1e3 * device,
            "ms_per_frame_numpy": 1e3 * host}


def _main(argv=None):
    from ..runtime import init
    from ..validation import cli_int, one_line_parser_class
    parser = one_line_parser_class()(description="Benchmark dense hair interpolation.")
    for name, default, low, high in (("n-dense", 100_000, 1, 10_000_000), ("n-nodes", 32, 3, 10_000),
                                     ("n-guides", 1000, 1, 1_000_000), ("repeats", 5, 1, 1000)):
        parser.add_argument(f"--{name}", type=cli_int(f"--{name}", low, high), default=default)
    parser.add_argument("--arch", default="cpu")
    parser.add_argument("--precision", default="float32", choices=["float32", "float64"])
    args = parser.parse_args(argv)
    init(args.arch, args.precision)
    result = bench_interpolation(args.n_dense, args.n_nodes, args.n_guides, args.repeats)
    width = max(len(k) for k in result)
    for key, value in result.items():
        print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")


if __name__ == "__main__":
    _main()
