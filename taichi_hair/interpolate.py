"""Dense hair from guide strands.

Setup (numpy, once): the guide roots are mapped to a 2D chart of the scalp (azimuthal
equidistant about the roots' mean direction seen from the head centre) and triangulated
(Bowyer-Watson Delaunay); each dense root gets its containing triangle and barycentric weights
(the nearest point of the nearest triangle when it lies outside), its nearest guide for
clumping, and seeded per-strand variation.

Per frame (Taichi, ndarray arguments so each kernel compiles once per process):
  1. `_guide_frames`: Bishop frame of every guide edge by parallel transport from the root
     (one thread per guide: the transport is serial along the strand).
  2. `_dense_nodes`: one thread per dense strand: barycentric interpolation of the three guides'
     root-relative shapes, clump interpolation (one guide plus an offset carried in its Bishop
     frame, so it follows the guide's bending and twist), the per-strand blend of both, and
     frizz growing toward the tip.
  3. `_push_out_of_ellipsoid`: one thread per node: nodes closer to the head than a margin move
     out along the surface normal (only when the head is a sphere or ellipsoid).

Positions are metres; arrays are [strand, node, xyz]; node 0 is the root.
"""

from collections import Counter
from dataclasses import dataclass
import math
import time

import numpy as np
import taichi as ti

from .runtime import ensure_init, precision

MAX_POLAR_DEG = 170.0  # the scalp chart folds up at the antipode of the roots' mean direction
MODES = ("barycentric", "clump", "blend")

vec2 = ti.math.vec2
vec3 = ti.math.vec3
ivec3 = ti.types.vector(3, ti.i32)
ivec5 = ti.types.vector(5, ti.i32)
vec5 = ti.types.vector(5, float)


# ---------------------------------------------------------------- setup: chart and triangulation

@dataclass(frozen=True)
class ScalpChart:
    """Map from scalp points [M, 3] (m) to 2D chart coordinates [M, 2] (m).

    spherical: azimuthal equidistant about `axis` seen from `centre` (angle from the axis times
    `radius`, along the azimuth); otherwise the orthogonal projection on the plane through
    `centre` normal to `axis`. e1, e2 span the chart's directions."""

    centre: np.ndarray
    axis: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    radius: float
    spherical: bool

    @classmethod
    def fit(cls, roots, normals, centre=None) -> "ScalpChart":
        """Chart for roots [G, 3] with outward normals [G, 3]; the head centre, when not given, is
        the point nearest (least squares) to all normal lines; a nearly flat scalp (parallel
        normals) gets the planar chart."""
        spherical = True
        if centre is None:
            proj = np.eye(3)[None] - normals[:, :, None] * normals[:, None, :]
            a, b = proj.sum(0), np.einsum("gij,gj->i", proj, roots)
            eig = np.linalg.eigvalsh(a)
            spherical = eig[0] > 1e-3 * eig[-1]  # parallel normals do not meet
            centre = np.linalg.solve(a, b) if spherical else roots.mean(0)
        centre = np.asarray(centre, dtype=np.float64)
        if spherical:
            rel = roots - centre
            axis = (rel / np.linalg.norm(rel, axis=1, keepdims=True)).mean(0)
        else:
            axis = normals.mean(0)
        axis = axis / np.linalg.norm(axis)
        e1 = _perpendicular(axis[None])[0]
        radius = float(np.linalg.norm(roots - centre, axis=1).mean()) if spherical else 1.0
        return cls(centre, axis, e1, np.cross(axis, e1), radius, bool(spherical))

    def project(self, points, name="points") -> np.ndarray:
        """Chart coordinates [M, 2] (m) of points [M, 3]; ValueError for points the chart folds."""
        rel = np.asarray(points, dtype=np.float64) - self.centre
        x, y = rel @ self.e1, rel @ self.e2
        if not self.spherical:
            return np.stack([x, y], axis=1)
        polar = np.arctan2(np.hypot(x, y), rel @ self.axis)
        if polar.max(initial=0.0) > math.radians(MAX_POLAR_DEG):
            raise ValueError(f"{name} must lie within {MAX_POLAR_DEG:g} degrees of the roots' mean "
                             f"direction seen from the head centre, got "
                             f"{math.degrees(polar.max()):.1f} degrees")
        azimuth = np.arctan2(y, x)
        return self.radius * polar[:, None] * np.stack([np.cos(azimuth), np.sin(azimuth)], axis=1)


def _perpendicular(n):
    """A unit vector perpendicular to each unit vector n [M, 3] (deterministic)."""
    helper = np.where(np.abs(n[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(n, helper)
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _circumcircles(p, tri):
    """Circumcentres [T, 2] and squared radii [T] of triangles `tri` [T, 3] over points p."""
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    ab, ac = b - a, c - a
    d = 2.0 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    sb, sc = (ab ** 2).sum(1), (ac ** 2).sum(1)
    off = np.stack([ac[:, 1] * sb - ab[:, 1] * sc, ab[:, 0] * sc - ac[:, 0] * sb], axis=1) / d[:, None]
    return a + off, (off ** 2).sum(1)


def _orient(a, b, c):
    """Twice the signed area of (a, b, c): > 0 counter-clockwise."""
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def delaunay(points) -> np.ndarray:
    """Delaunay triangles [T, 3] (counter-clockwise vertex indices) of 2D points [M, 2].

    Bowyer-Watson with a large enclosing triangle; O(M^2), fine for thousands of guides. The
    cavity of each insertion is grown until every boundary edge faces the new point, so
    round-off on nearly cocircular points (regular grids) cannot produce overlapping triangles."""
    pts = np.asarray(points, dtype=np.float64)
    lo, span = pts.min(0), np.ptp(pts, axis=0).max()
    if len(pts) < 3 or not span > 0:
        raise ValueError(f"points must hold at least 3 distinct 2D points, got {len(pts)}")
    if len(np.unique(pts, axis=0)) < len(pts):
        raise ValueError("points must be distinct, got duplicates")
    p = np.concatenate([(pts - lo) / span, [[-1e4, -1e4], [3e4, -1e4], [-1e4, 3e4]]])
    m = len(pts)
    tri = np.array([[m, m + 1, m + 2]])
    cc, r2 = _circumcircles(p, tri)
    for i in range(m):
        bad = ((cc - p[i]) ** 2).sum(1) < r2
        if not bad.any():  # round-off: fall back on the triangle that contains the point
            bad[np.argmax([min(_orient(p[a], p[b], p[i]), _orient(p[b], p[c], p[i]),
                               _orient(p[c], p[a], p[i])) for a, b, c in tri])] = True
        edges = _cavity_boundary(p, tri, bad, i)
        new = np.array([[a, b, i] for a, b in edges])
        ncc, nr2 = _circumcircles(p, new)
        tri, cc, r2 = (np.concatenate([tri[~bad], new]), np.concatenate([cc[~bad], ncc]),
                       np.concatenate([r2[~bad], nr2]))
    keep = (tri < m).all(1)
    if not keep.any():
        raise ValueError("points are collinear: no triangle can be built")
    return tri[keep]


def _cavity_boundary(p, tri, bad, i):
    """Boundary edges (a, b) of the cavity `bad` (grown in place until every edge sees p[i])."""
    for _ in range(len(tri)):
        edges = [e for a, b, c in tri[bad].tolist() for e in ((a, b), (b, c), (c, a))]
        count = Counter(frozenset(e) for e in edges)  # an interior edge is shared by two
        edges = [e for e in edges if count[frozenset(e)] == 1]
        hidden = [e for e in edges if _orient(p[e[0]], p[e[1]], p[i]) <= 0.0]
        if not hidden:
            return edges
        a, b = hidden[0]
        across = (((tri[:, 0] == b) & (tri[:, 1] == a)) | ((tri[:, 1] == b) & (tri[:, 2] == a))
                  | ((tri[:, 2] == b) & (tri[:, 0] == a))) & ~bad
        bad |= across
    raise RuntimeError("Delaunay cavity did not close")  # unreachable: the cavity only grows


@ti.kernel
def _locate(p: ti.types.ndarray(dtype=vec2, ndim=1), v: ti.types.ndarray(dtype=vec2, ndim=1),
            tri: ti.types.ndarray(dtype=ivec3, ndim=1), out_tri: ti.types.ndarray(dtype=ti.i32, ndim=1),
            out_w: ti.types.ndarray(dtype=vec3, ndim=1)):
    """Nearest triangle of each chart point p [D] (distance 0 when inside) and the barycentric
    weights of the nearest point of that triangle. One thread per point, all triangles scanned,
    bounding boxes first."""
    for d in p:
        best, best_t, best_w = 1e30, 0, vec3(1.0, 0.0, 0.0)
        for t in range(tri.shape[0]):
            a, b, c = v[tri[t][0]], v[tri[t][1]], v[tri[t][2]]
            gap = ti.max(ti.min(a, b, c) - p[d], p[d] - ti.max(a, b, c), 0.0)
            if gap.norm() < best:
                dist, w = _nearest_in_triangle(p[d], a, b, c)
                if dist < best:
                    best, best_t, best_w = dist, t, w
        out_tri[d], out_w[d] = best_t, best_w


@ti.func
def _nearest_in_triangle(x, a, b, c):
    """(distance, barycentric weights) of the point of triangle abc nearest to x (2D)."""
    ab, ac, ax = b - a, c - a, x - a
    det = ab[0] * ac[1] - ab[1] * ac[0]
    flat = det <= 0.0  # a sliver flattened by round-off: only its edges count
    det = ti.select(flat, 1.0, det)
    wb = (ax[0] * ac[1] - ax[1] * ac[0]) / det
    wc = (ab[0] * ax[1] - ab[1] * ax[0]) / det
    dist, w = 0.0, vec3(1.0 - wb - wc, wb, wc)
    if flat or ti.min(w[0], w[1], w[2]) < 0.0:
        dist = 1e30
        for k in ti.static(range(3)):
            s, e = ti.static(k, (k + 1) % 3)
            ps, pe = (a, b, c)[s], (a, b, c)[e]
            seg = pe - ps
            f = ti.math.clamp((x - ps).dot(seg) / seg.dot(seg), 0.0, 1.0)
            dk = (x - ps - f * seg).norm()
            if dk < dist:
                dist = dk
                w = vec3(0.0)
                w[s], w[e] = 1.0 - f, f
    return dist, w


# ---------------------------------------------------------------- per-frame kernels

@ti.func
def _transport(a, b, x):
    """Parallel transport of x from unit tangent a to unit tangent b (rotation about a x b)."""
    axb, c = a.cross(b), a.dot(b)
    out = x
    if c > -1.0 + 1e-12:  # antiparallel tangents: no unique rotation, keep x
        out = c * x + axb.cross(x) + axb.dot(x) * axb / (1.0 + c)
    return out


@ti.kernel
def _guide_frames(x: ti.types.ndarray(dtype=vec3, ndim=2), normal: ti.types.ndarray(dtype=vec3, ndim=1),
                  u_rest: ti.types.ndarray(dtype=vec3, ndim=1), rot: ti.math.mat3,
                  t_out: ti.types.ndarray(dtype=vec3, ndim=2), u_out: ti.types.ndarray(dtype=vec3, ndim=2)):
    """Bishop frame (t^j, u^j) of every guide edge j: u^0 is the rest reference u (carried by the
    head rotation `rot`) transported from the root normal to t^0, then edge to edge. One thread
    per guide; the transport is serial along its strand."""
    for g in range(x.shape[0]):
        t_prev, u = rot @ normal[g], rot @ u_rest[g]
        for j in range(x.shape[1] - 1):
            e = x[g, j + 1] - x[g, j]
            t = t_prev
            if e.norm() > 1e-12:  # a zero-length edge keeps the previous tangent
                t = e.normalized()
            u = _transport(t_prev, t, u)
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
def _dense_nodes(x: ti.types.ndarray(dtype=vec3, ndim=2), t: ti.types.ndarray(dtype=vec3, ndim=2),
                 u: ti.types.ndarray(dtype=vec3, ndim=2), idx: ti.types.ndarray(dtype=ivec5, ndim=1),
                 w: ti.types.ndarray(dtype=vec3, ndim=1), rel: ti.types.ndarray(dtype=vec3, ndim=2),
                 local: ti.types.ndarray(dtype=vec3, ndim=1), par: ti.types.ndarray(dtype=vec5, ndim=1),
                 rot: ti.math.mat3, out: ti.types.ndarray(dtype=vec3, ndim=2)):
    """Dense nodes out[d, i] [m]. idx[d] = (3 triangle guides, clump guide, frizz key); w[d] the
    triangle weights; rel[d, k] = rest dense root - rest root of guide k (triangle, then clump);
    local[d] the clump offset in the clump guide's rest root frame (u, v, normal);
    par[d] = (blend, start node, node step, frizz amplitude [m], clump offset scale at the tip).
    One thread per dense strand: the terms shared by its nodes are computed once, then the
    nodes (independent of each other) in a loop."""
    n = x.shape[1]
    for d in range(out.shape[0]):
        blend, q0, step, frizz, tip = par[d][0], par[d][1], par[d][2], par[d][3], par[d][4]
        k0, k1, k2, g, key = idx[d][0], idx[d][1], idx[d][2], idx[d][3], idx[d][4]
        wd, off = w[d], local[d]
        # each guide carries the dense root rigidly with the head from its own root
        base_b = (wd[0] * (x[k0, 0] + rot @ rel[d, 0] - _at(x, k0, q0))
                  + wd[1] * (x[k1, 0] + rot @ rel[d, 1] - _at(x, k1, q0))
                  + wd[2] * (x[k2, 0] + rot @ rel[d, 2] - _at(x, k2, q0)))
        j0 = _edge(q0, n)
        # the root offset is subtracted as carried by the start frame, so node 0 is the root
        base_c = (x[g, 0] + rot @ rel[d, 3] - _at(x, g, q0)
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
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if ((p * r / (r * r + mid)) ** 2).sum() > 1.0:
            lo = mid
        else:
            hi = mid
    y = p * r * r / (r * r + 0.5 * (lo + hi))
    # on the medial axis the root escapes the bracket: scale back onto the surface
    return y / ti.sqrt(((y / r) ** 2).sum())


@ti.kernel
def _push_out_of_ellipsoid(out: ti.types.ndarray(dtype=vec3, ndim=2), centre: vec3, radii: vec3,
                           rot: ti.math.mat3, margin: float):
    """Move non-root nodes closer than `margin` [m] to the ellipsoid (centre [m], semi-axes
    `radii` [m] along the columns of `rot`) to its surface point + margin along the normal.
    One thread per (strand, node)."""
    reach = ti.max(radii[0], radii[1], radii[2]) + margin
    for d, i in ti.ndrange(out.shape[0], out.shape[1]):
        rel = out[d, i] - centre
        if i > 0 and rel.norm() < reach:
            p = rot.transpose() @ rel
            if p.norm() < 1e-9 * reach:  # the centre itself: leave along the shortest axis
                rmin = ti.min(radii[0], radii[1], radii[2])
                p = 1e-6 * reach * ti.cast(radii == rmin, float).normalized()
            y = p * radii[0] / p.norm()  # sphere: closed form
            if radii[0] != radii[1] or radii[1] != radii[2]:
                y = _nearest_on_ellipsoid(p, radii)
            inside = ((p / radii) ** 2).sum() < 1.0
            dist = (p - y).norm() * ti.select(inside, -1.0, 1.0)
            if dist < margin:
                out[d, i] = centre + rot @ (y + margin * (y / (radii * radii)).normalized())


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
    """

    def __init__(self, guide_roots, guide_normals, dense_roots, n_nodes, *, mode="blend",
                 blend=0.5, clump_radius=None, frizz=0.0, length_variation=0.0,
                 curl_phase_variation=0.0, seed=0, head=None, head_margin=0.002):
        ensure_init()
        roots, normals, dense = _check_setup(guide_roots, guide_normals, dense_roots, n_nodes)
        self.n_guides, self.n_dense, self.n_nodes = len(roots), len(dense), int(n_nodes)
        self._head, self._ellipsoid = _check_head(head, head_margin)
        self._margin = float(head_margin)
        self._dtype = np.float32 if precision() == "float32" else np.float64
        centre = None if self._ellipsoid is None else self._ellipsoid[0]
        chart = ScalpChart.fit(roots, normals, centre)
        try:
            self.triangles = delaunay(chart.project(roots, "guide_roots"))
        except ValueError as exc:
            raise ValueError(f"guide_roots cannot be triangulated on the scalp: {exc}") from None
        tri_of, weights = self._locate(chart.project(dense, "dense_roots"), chart.project(roots))
        corners = self.triangles[tri_of]
        nearest = _nearest(dense, roots)
        u_rest = _perpendicular(normals)
        offset = dense - roots[nearest]
        local = np.stack([(offset * u_rest[nearest]).sum(1),
                          (offset * np.cross(normals, u_rest)[nearest]).sum(1),
                          (offset * normals[nearest]).sum(1)], axis=1)
        par, keys = _variation(self.n_dense, self.n_nodes, mode, blend, clump_radius, frizz,
                               length_variation, curl_phase_variation, seed,
                               np.linalg.norm(offset, axis=1))
        rel = dense[:, None, :] - roots[np.concatenate([corners, nearest[:, None]], axis=1)]
        self.weights, self.guide_of, self.corners = weights, nearest, corners
        d, g, n = self.n_dense, self.n_guides, self.n_nodes
        self._idx = _upload(np.concatenate([corners, nearest[:, None], keys[:, None]], 1), ivec5, (d,), np.int32)
        self._w = _upload(weights, vec3, (d,), self._dtype)
        self._rel = _upload(rel, vec3, (d, 4), self._dtype)
        self._local = _upload(local, vec3, (d,), self._dtype)
        self._par = _upload(par, vec5, (d,), self._dtype)
        self._normal = _upload(normals, vec3, (g,), self._dtype)
        self._u_rest = _upload(u_rest, vec3, (g,), self._dtype)
        self._t, self._u = ti.ndarray(vec3, (g, n - 1)), ti.ndarray(vec3, (g, n - 1))
        self._out = ti.ndarray(vec3, (d, n))

    def _locate(self, dense2, guide2):
        tri_of = ti.ndarray(ti.i32, (len(dense2),))
        weights = ti.ndarray(vec3, (len(dense2),))
        _locate(_upload(dense2, vec2, (len(dense2),), self._dtype),
                _upload(guide2, vec2, (len(guide2),), self._dtype),
                _upload(self.triangles, ivec3, (len(self.triangles),), np.int32), tri_of, weights)
        return tri_of.to_numpy().astype(np.int64), weights.to_numpy().astype(np.float64)

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
        rot_ti = ti.Matrix(rot.tolist())
        _guide_frames(x, self._normal, self._u_rest, rot_ti, self._t, self._u)
        _dense_nodes(x, self._t, self._u, self._idx, self._w, self._rel, self._local, self._par,
                     rot_ti, out)
        if self._ellipsoid is not None:
            c, r = self._ellipsoid
            _push_out_of_ellipsoid(out, ti.Vector((rot @ c + trans).tolist()), ti.Vector(r.tolist()),
                                   rot_ti, self._margin)

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


def _check_head(head, margin):
    if not (isinstance(margin, (int, float)) and math.isfinite(margin) and margin >= 0):
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


def _nearest(points, targets, chunk=4096):
    """Index [M] of the nearest target [T, 3] to each point [M, 3]."""
    out = np.empty(len(points), dtype=np.int64)
    t2 = (targets ** 2).sum(1)
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk]
        out[s:s + chunk] = np.argmin(t2[None, :] - 2.0 * p @ targets.T, axis=1)
    return out


def _variation(n_dense, n_nodes, mode, blend, clump_radius, frizz, length_variation,
               curl_phase_variation, seed, offset_length):
    """Per-strand parameters [D, 5] (see `_dense_nodes`) and frizz keys [D], all seeded."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    beta = np.asarray(blend, dtype=np.float64) if mode == "blend" else np.asarray(float(mode == "clump"))
    beta = np.full(n_dense, beta) if beta.ndim == 0 else beta
    if beta.shape != (n_dense,) or not np.all((beta >= 0) & (beta <= 1)):
        raise ValueError(f"blend must be a scalar or an array [{n_dense}] with values in [0, 1], got {blend!r}")
    for name, value, lo, hi, unit in (("frizz", frizz, 0.0, math.inf, "m"),
                                      ("length_variation", length_variation, 0.0, 1.0, ""),
                                      ("curl_phase_variation", curl_phase_variation, 0.0,
                                       (n_nodes - 1) / 2, "edges")):
        if not (isinstance(value, (int, float)) and lo <= value <= hi and not (hi == 1.0 and value == 1.0)):
            raise ValueError(f"{name} must be a number in [{lo:g}, {hi:g}{')' if hi == 1.0 else ']'} "
                             f"{unit}, got {value!r}".replace(" ,", ","))
    if clump_radius is not None and not (isinstance(clump_radius, (int, float)) and 0 <= clump_radius < math.inf):
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

def sample_scalp_roots(n, *, radius=0.1, centre=(0.0, 0.0, 0.0), max_polar_deg=70.0):
    """n roots [n, 3] (m) and outward normals [n, 3] spread evenly (Fibonacci spiral) over the
    cap of a sphere of `radius` [m] within `max_polar_deg` of +z. A stand-in for tests and
    benchmarks, not a scalp sampler."""
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if not 0 < max_polar_deg <= 180:
        raise ValueError(f"max_polar_deg must be in (0, 180] degrees, got {max_polar_deg!r}")
    k = np.arange(n) + 0.5
    cos_polar = 1.0 - (1.0 - math.cos(math.radians(max_polar_deg))) * k / n
    azimuth = k * math.pi * (3.0 - math.sqrt(5.0))  # golden angle
    sin_polar = np.sqrt(1.0 - cos_polar ** 2)
    normals = np.stack([sin_polar * np.cos(azimuth), sin_polar * np.sin(azimuth), cos_polar], axis=1)
    return np.asarray(centre, dtype=np.float64) + radius * normals, normals


def _curly_guides(roots, normals, n_nodes, length=0.2, curl_radius=0.01, pitch=0.02):
    """Helices [G, n_nodes, 3] (m) growing along the normals from the roots (benchmark data)."""
    rise = pitch / (2 * math.pi)
    s = (np.linspace(0.0, length, n_nodes) / math.hypot(curl_radius, rise))[None, :, None]
    side = _perpendicular(normals)[:, None]
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
    import argparse
    from .runtime import init
    parser = argparse.ArgumentParser(description="Benchmark dense hair interpolation.")
    for name, default in (("n-dense", 100_000), ("n-nodes", 32), ("n-guides", 1000), ("repeats", 5)):
        parser.add_argument(f"--{name}", type=int, default=default)
    parser.add_argument("--arch", default="cpu")
    parser.add_argument("--precision", default="float32")
    args = parser.parse_args(argv)
    init(args.arch, args.precision)
    result = bench_interpolation(args.n_dense, args.n_nodes, args.n_guides, args.repeats)
    width = max(len(k) for k in result)
    for key, value in result.items():
        print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")


if __name__ == "__main__":
    _main()
