"""The scalp as a 2D domain: chart, Delaunay triangulation of the guide roots, point location.

Setup-time tools of `taichi_hair.hair.interpolate` (numpy, plus one Taichi kernel for locating many
points): the guide roots are mapped to a 2D chart of the scalp (azimuthal equidistant about the
roots' mean direction seen from the head centre) and triangulated (Bowyer-Watson Delaunay);
each dense root gets its containing triangle and barycentric weights (the nearest point of the
nearest triangle when it lies outside).

Positions are metres; chart coordinates are metres along the scalp (spherical chart) or in the
tangent plane (planar chart).
"""

from collections import Counter
from dataclasses import dataclass
import math

import numpy as np
import taichi as ti

from ..runtime import ensure_init, precision

MAX_POLAR_DEG = 170.0  # the scalp chart folds up at the antipode of the roots' mean direction

vec2 = ti.math.vec2
vec3 = ti.math.vec3
ivec3 = ti.types.vector(3, ti.i32)  # integer element types do not depend on the float precision

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
        e1 = perpendicular(axis[None])[0]
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


def perpendicular(n):
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


def locate(points, vertices, triangles):
    """Triangle index [M] (int64) and barycentric weights [M, 3] (float64) of the point of
    triangles [T, 3] (indices into vertices [V, 2], m) nearest to each chart point [M, 2] (m):
    the point itself when it lies inside. Runs `_locate` in this process's precision."""
    ensure_init()
    dtype = np.float32 if precision() == "float32" else np.float64
    m = len(points)
    tri_of, weights = ti.ndarray(ti.i32, (m,)), ti.ndarray(vec3, (m,))
    _locate(_upload(points, vec2, dtype), _upload(vertices, vec2, dtype),
            _upload(triangles, ivec3, np.int32), tri_of, weights)
    return tri_of.to_numpy().astype(np.int64), weights.to_numpy().astype(np.float64)


def _upload(array, dtype, np_dtype):
    array = np.ascontiguousarray(array, dtype=np_dtype)
    nd = ti.ndarray(dtype, (len(array),))
    nd.from_numpy(array)
    return nd


@ti.kernel
def _nearest(points: ti.types.ndarray(dtype=vec3, ndim=1), targets: ti.types.ndarray(dtype=vec3, ndim=1),
             out: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """out[p] = index of the target nearest to point p (the first of equals). One thread per
    point, all targets scanned."""
    for p in points:
        best, best_k = (points[p] - targets[0]).norm_sqr(), 0
        for k in range(1, targets.shape[0]):
            d = (points[p] - targets[k]).norm_sqr()
            if d < best:
                best, best_k = d, k
        out[p] = best_k


def nearest(points, targets):
    """Index [M] (int64) of the nearest target [T, 3] (m) to each point [M, 3] (m), the first
    of equally near ones; distances in this process's precision."""
    ensure_init()
    dtype = np.float32 if precision() == "float32" else np.float64
    out = ti.ndarray(ti.i32, (len(points),))
    _nearest(_upload(points, vec3, dtype), _upload(targets, vec3, dtype), out)
    return out.to_numpy().astype(np.int64)


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

