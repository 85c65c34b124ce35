"""Signed-distance grid of a closed triangle mesh, built once on the host in numpy.

Layout (the simulator's Taichi kernels read the same arrays):

    values[i, j, k]  (float64, metres, negative inside the mesh) is the exact signed distance at
    the grid point  origin + spacing * (i, j, k),  0 <= i < nx, 0 <= j < ny, 0 <= k < nz,
    C order: k (z) varies fastest. The field between grid points is trilinear:
    with g = (p - origin) / spacing, c = clip(floor(g), 0, n - 2) per axis, f = g - c,
    value = sum over the 8 corners (a, b, d) in {0, 1}^3 of
            values[c + (a, b, d)] * (a ? f_x : 1 - f_x) (b ? f_y : 1 - f_y) (d ? f_z : 1 - f_z).

Every value is an exact point-triangle distance, to the nearest triangle found as in
Bridson's SDFGen (makelevelset3): each grid point within one cell of a triangle's bounding box
measures that triangle (the narrow band, where hair collides: exact nearest there); then
sweeps along +-x, +-y, +-z hand each point its neighbours' nearest triangles and keep the
closest. Away from the band this is the true nearest triangle except where nearest-triangle
regions are not connected to the band (rare, concave spots), and then it is a slightly larger
distance. The sign is that of (p - nearest point) . (angle-weighted pseudonormal of the nearest
feature: face, edge or vertex; Baerentzen & Aanaes 2005), exact for a closed, consistently
oriented mesh, which `from_mesh` checks. `mesh_signed_distance` gives the exact nearest
distance for any points by culled brute force (for checks and small point sets).
"""

from dataclasses import dataclass
import math

import numpy as np

from ..diskcache import cached_arrays
from ..validation import is_real

PAIRS_PER_CHUNK = 1 << 19  # point-triangle pairs evaluated at once (~0.3 GB of temporaries)
BAND_CELLS = 1  # exact distances to every triangle within this many cells of its bounding box
MAX_SWEEP_ROUNDS = 12  # rounds of six axis sweeps; they stop when a round changes nothing


@dataclass(frozen=True, kw_only=True, eq=False)
class SignedDistanceGrid:
    """Signed distance [m] sampled on a regular grid (layout in the module docstring).

    values: float64 [nx, ny, nz], m, negative inside. origin: float64 [3], m, the position of
    values[0, 0, 0]. spacing: grid step [m], the same on all three axes.
    """

    values: np.ndarray
    origin: np.ndarray
    spacing: float

    def __post_init__(self):
        values = np.array(self.values, dtype=np.float64)
        origin = np.array(self.origin, dtype=np.float64)
        if values.ndim != 3 or min(values.shape) < 2 or not np.all(np.isfinite(values)):
            raise ValueError(f"values must be a finite [nx, ny, nz] array with every n >= 2, got shape {values.shape}")
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"origin must be a finite 3-vector [m], got {self.origin!r}")
        if not (is_real(self.spacing) and math.isfinite(self.spacing) and self.spacing > 0):
            raise ValueError(f"spacing must be a finite number > 0 m, got {self.spacing!r}")
        values.setflags(write=False)
        origin.setflags(write=False)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "spacing", float(self.spacing))

    @property
    def shape(self) -> tuple:
        """(nx, ny, nz) grid points."""
        return self.values.shape

    @property
    def upper(self) -> np.ndarray:
        """Position [3] m of the last grid point values[-1, -1, -1]."""
        return self.origin + self.spacing * (np.array(self.shape) - 1)

    @classmethod
    def from_mesh(cls, vertices, faces, *, spacing: float = 0.004, padding: float = 0.02) -> "SignedDistanceGrid":
        """Grid over the mesh's bounding box grown by `padding` [m] on every side, step
        `spacing` [m]. vertices [V, 3] m; faces [F, 3] int, closed and outward oriented
        (counter-clockwise seen from outside), else ValueError."""
        if not (is_real(spacing) and math.isfinite(spacing) and spacing > 0):
            raise ValueError(f"spacing must be a finite number > 0 m, got {spacing!r}")
        if not (is_real(padding) and math.isfinite(padding) and padding >= 0):
            raise ValueError(f"padding must be a finite number >= 0 m, got {padding!r}")
        mesh = _Mesh(vertices, faces)
        lo = mesh.v.min(axis=0) - padding
        counts = np.ceil((mesh.v.max(axis=0) + padding - lo) / spacing).astype(int) + 1
        if np.prod(counts) > 50_000_000:
            raise ValueError(f"spacing {spacing!r} m gives {np.prod(counts):,} grid points (max 50,000,000); "
                             "use a larger spacing")

        def build():
            dist, tri, sign = _band(mesh, lo, float(spacing), counts)
            stamp = np.zeros(dist.shape, dtype=np.int64)  # round in which a point last changed
            for round_ in range(1, MAX_SWEEP_ROUNDS + 1):
                updates = sum(_sweep(mesh, lo, float(spacing), (dist, tri, sign, stamp), round_, axis, direction)
                              for axis in range(3) for direction in (1, -1))
                if updates == 0:
                    break
            return {"values": sign * np.sqrt(dist)}
        values = cached_arrays("sdf", (mesh.v, mesh.f, float(spacing), float(padding)), build)["values"]
        return cls(values=values, origin=lo, spacing=float(spacing))

    # ---- sampling on the host ----------------------------------------------------------------
    def _cells(self, points):
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points must have shape [M, 3], got {p.shape}")
        q = np.clip(p, self.origin, self.upper)  # outside the box: continue from its surface
        g = (q - self.origin) / self.spacing
        c = np.clip(np.floor(g).astype(np.int64), 0, np.array(self.shape) - 2)
        return p, q, c, g - c

    def _corners(self, c):
        v = self.values
        return {(a, b, d): v[c[:, 0] + a, c[:, 1] + b, c[:, 2] + d] for a in (0, 1) for b in (0, 1) for d in (0, 1)}

    def sample(self, points) -> np.ndarray:
        """Trilinear signed distance [M] m at points [M, 3] m. Outside the grid's box the value
        is the one at the nearest box point plus the distance to it (an upper bound)."""
        p, q, c, f = self._cells(points)
        corner = self._corners(c)
        wt = (1.0 - f, f)
        out = np.zeros(len(p))
        for (a, b, d), val in corner.items():
            out += val * wt[a][:, 0] * wt[b][:, 1] * wt[d][:, 2]
        return out + np.linalg.norm(p - q, axis=1)

    def gradient(self, points) -> np.ndarray:
        """Gradient [M, 3] of `sample`: the exact derivative of the trilinear field inside a cell
        (piecewise; ~unit length away from the medial axis), and outward unit growth beyond
        the box along the clamped axes."""
        p, q, c, f = self._cells(points)
        corner = self._corners(c)
        wt = (1.0 - f, f)
        sign = (-1.0, 1.0)
        grad = np.zeros_like(p)
        for (a, b, d), val in corner.items():
            grad[:, 0] += val * sign[a] * wt[b][:, 1] * wt[d][:, 2]
            grad[:, 1] += val * wt[a][:, 0] * sign[b] * wt[d][:, 2]
            grad[:, 2] += val * wt[a][:, 0] * wt[b][:, 1] * sign[d]
        grad /= self.spacing
        out = p - q
        dist = np.linalg.norm(out, axis=1, keepdims=True)
        clamped = out != 0.0
        return np.where(clamped, out / np.maximum(dist, 1e-300), grad)


def mesh_signed_distance(points, vertices, faces) -> np.ndarray:
    """Exact signed distance [M] m from points [M, 3] m to a closed, outward-oriented triangle
    mesh (negative inside); the same routine the grid is built with."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise ValueError(f"points must be a finite [M, 3] array of metres, got shape {p.shape}")
    return _Mesh(vertices, faces).signed_distance(p)


class _Mesh:
    """Per-triangle data and the pseudonormals of a validated closed mesh."""

    def __init__(self, vertices, faces):
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError(f"vertices must be a finite [V, 3] array of metres, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4 or not np.issubdtype(f.dtype, np.integer) \
                or f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"faces must be an integer [F >= 4, 3] array indexing the {len(v)} vertices, "
                             f"got shape {f.shape}")
        self.v, self.f = v, f.astype(np.int64)
        self.a, self.b, self.c = (v[f[:, k]] for k in range(3))
        cross = np.cross(self.b - self.a, self.c - self.a)
        area2 = np.linalg.norm(cross, axis=1)
        if np.any(area2 <= 1e-300):
            raise ValueError(f"faces: triangle {int(np.argmin(area2))} is degenerate (zero area)")
        self.normal = cross / area2[:, None]
        self.edge_id = self._edge_ids()
        self.edge_normal = np.zeros((self.edge_id.max() + 1, 3))
        np.add.at(self.edge_normal, self.edge_id.reshape(-1), np.repeat(self.normal, 3, axis=0))
        self.vertex_normal = self._vertex_pseudonormals()
        self.ab, self.ac, self.bc = self.b - self.a, self.c - self.a, self.c - self.b
        self.d00, self.d01, self.d11, self.d22 = ((x * y).sum(1) for x, y in
                                                  ((self.ab, self.ab), (self.ab, self.ac), (self.ac, self.ac),
                                                   (self.bc, self.bc)))
        self.centre = (self.a + self.b + self.c) / 3.0
        self.radius = np.max([np.linalg.norm(x - self.centre, axis=1) for x in (self.a, self.b, self.c)], axis=0)

    def _edge_ids(self):
        """Undirected edge id [F, 3] of edges (a b), (b c), (c a); ValueError unless every edge
        is shared by exactly two faces that traverse it in opposite directions."""
        f = self.f
        directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        und = np.sort(directed, axis=1)
        unique, inverse, counts = np.unique(und, axis=0, return_inverse=True, return_counts=True)
        if np.any(counts != 2):
            e = unique[np.flatnonzero(counts != 2)[0]]
            raise ValueError(f"faces: the mesh must be closed (watertight); edge ({e[0]}, {e[1]}) is shared by "
                             f"{counts[counts != 2][0]} faces instead of 2")
        forward = (directed[:, 0] < directed[:, 1]).astype(np.int64)
        per_edge = np.zeros(len(unique), dtype=np.int64)
        np.add.at(per_edge, inverse.reshape(-1), forward)
        if np.any(per_edge != 1):
            e = unique[np.flatnonzero(per_edge != 1)[0]]
            raise ValueError(f"faces: inconsistent orientation; both faces at edge ({e[0]}, {e[1]}) traverse it "
                             "the same way (every face must be counter-clockwise seen from outside)")
        return inverse.reshape(3, len(f)).T

    def _vertex_pseudonormals(self):
        """Angle-weighted sums [V, 3] of the incident face normals."""
        n = np.zeros_like(self.v)
        corners = (self.a, self.b, self.c)
        for k in range(3):
            e1 = corners[(k + 1) % 3] - corners[k]
            e2 = corners[(k + 2) % 3] - corners[k]
            cosang = np.einsum("ij,ij->i", e1, e2) / (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1))
            np.add.at(n, self.f[:, k], np.arccos(np.clip(cosang, -1.0, 1.0))[:, None] * self.normal)
        return n

    def signed_distance(self, points):
        """Exact signed distance [M] from points [M, 3]: triangles whose bounding sphere is
        nearer than the nearest vertex are candidates; of those, the ones whose bounding sphere
        is nearer than the nearest candidate vertex get the exact distance."""
        out = np.empty(len(points))
        step = max(1, 2_000_000 // max(len(self.v), len(self.f)))
        for s in range(0, len(points), step):
            p = points[s: s + step]
            nearest_vertex = np.sqrt(_sq_dist(p, self.v).min(axis=1)) + 1e-7  # slack for rounding
            lower = np.sqrt(_sq_dist(p, self.centre)) - self.radius
            g, t = np.nonzero(lower <= nearest_vertex[:, None])
            d2, side = self._exact(p[g], t)
            best = np.full(len(p), np.inf)
            np.minimum.at(best, g, d2)
            sign = np.ones(len(p))
            win = d2 <= best[g]  # ties share a feature, so their signs agree
            sign[g[win]] = side[win]
            out[s: s + step] = sign * np.sqrt(best)
        return out

    def _exact(self, p, t):
        """Squared distance [K] and sign (+-1) [K] from points p [K, 3] to triangles t [K]:
        the sign of (p - nearest) . pseudonormal(nearest feature: face, edge or vertex)."""
        def dot(x, y):
            return x[:, 0] * y[:, 0] + x[:, 1] * y[:, 1] + x[:, 2] * y[:, 2]
        a, ab, ac, bc = self.a[t], self.ab[t], self.ac[t], self.bc[t]
        w = p - a
        d00, d01, d11 = self.d00[t], self.d01[t], self.d11[t]
        d20, d21 = dot(w, ab), dot(w, ac)
        denom = d00 * d11 - d01 * d01
        bv = (d11 * d20 - d01 * d21) / denom
        bw = (d00 * d21 - d01 * d20) / denom
        inside = (bv >= 0) & (bw >= 0) & (bv + bw <= 1)
        plane = dot(w, self.normal[t])
        best_d2 = np.full(len(p), np.inf)
        side = np.zeros(len(p))
        # edges as segments (start vertex, end vertex, edge slot): (a, b, 0), (b, c, 1), (a, c, 2)
        for i0, i1, slot, ww, e, ee in ((0, 1, 0, w, ab, d00), (1, 2, 1, p - self.b[t], bc, self.d22[t]),
                                        (0, 2, 2, w, ac, d11)):
            u = np.clip(dot(ww, e) / ee, 0.0, 1.0)
            r = ww - u[:, None] * e  # p - nearest point of the edge
            d2 = dot(r, r)
            vid = np.where(u <= 0.0, self.f[t, i0], self.f[t, i1])
            n = np.where(((u > 0.0) & (u < 1.0))[:, None], self.edge_normal[self.edge_id[t, slot]],
                         self.vertex_normal[vid])
            closer = d2 < best_d2
            best_d2 = np.where(closer, d2, best_d2)
            side = np.where(closer, dot(r, n), side)
        d2 = np.where(inside, plane * plane, best_d2)
        side = np.where(inside, plane, side)
        return d2, np.where(side < 0, -1.0, 1.0)


def _grid_points(lo, spacing, i, j, k):
    return lo + spacing * np.stack([i, j, k], axis=1)


def _band(mesh, lo, spacing, counts):
    """Squared distance, nearest triangle and sign [nx, ny, nz] from every triangle to the grid
    points within BAND_CELLS cells of its bounding box (inf / -1 / +1 elsewhere)."""
    tri_lo = np.clip(np.floor((np.minimum(np.minimum(mesh.a, mesh.b), mesh.c) - lo) / spacing).astype(np.int64)
                     - BAND_CELLS, 0, counts - 1)
    tri_hi = np.clip(np.ceil((np.maximum(np.maximum(mesh.a, mesh.b), mesh.c) - lo) / spacing).astype(np.int64)
                     + BAND_CELLS, 0, counts - 1)
    ext = tri_hi - tri_lo + 1
    per_tri = ext.prod(axis=1)
    dist = np.full(int(np.prod(counts)), np.inf)
    tri = np.full(dist.shape, -1, dtype=np.int64)
    sign = np.ones(dist.shape)
    ends = np.cumsum(per_tri)
    t0 = 0
    while t0 < len(per_tri):  # chunks of whole triangles, ~PAIRS_PER_CHUNK pairs each
        t1 = max(t0 + 1, int(np.searchsorted(ends, ends[t0] - per_tri[t0] + PAIRS_PER_CHUNK, "right")))
        n = per_tri[t0:t1]
        t = np.repeat(np.arange(t0, t1), n)
        local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)  # ragged arange per triangle
        ey, ez = ext[t, 1], ext[t, 2]
        i, j, k = tri_lo[t, 0] + local // (ey * ez), tri_lo[t, 1] + (local // ez) % ey, tri_lo[t, 2] + local % ez
        d2, side = mesh._exact(_grid_points(lo, spacing, i, j, k), t)
        flat = (i * counts[1] + j) * counts[2] + k
        order = np.lexsort((d2, flat))  # nearest first within each grid point
        first = order[np.r_[True, flat[order][1:] != flat[order][:-1]]]
        better = d2[first] < dist[flat[first]]
        pick = first[better]
        dist[flat[pick]], tri[flat[pick]], sign[flat[pick]] = d2[pick], t[pick], side[pick]
        t0 = t1
    shape = tuple(counts)
    return dist.reshape(shape), tri.reshape(shape), sign.reshape(shape)


def _sweep(mesh, lo, spacing, fields, round_, axis, direction):
    """One pass along `axis` in `direction` (+1 / -1): each grid point tries the nearest
    triangle of its neighbour in the slice before and keeps it if closer (fields updated in
    place). Neighbours unchanged since this sweep last ran were tried then and are skipped.
    Returns the number of points that changed."""
    dist, tri, sign, stamp = fields
    n = dist.shape[axis]
    order = range(1, n) if direction > 0 else range(n - 2, -1, -1)
    other = [a for a in range(3) if a != axis]
    grids = np.meshgrid(np.arange(dist.shape[other[0]]), np.arange(dist.shape[other[1]]), indexing="ij")
    changed = 0
    for s in order:
        prev = np.take(tri, s - direction, axis=axis)
        todo = (np.take(stamp, s - direction, axis=axis) >= round_ - 1) & (prev >= 0) \
            & (prev != np.take(tri, s, axis=axis))
        if not todo.any():
            continue
        idx = [None, None, None]
        idx[axis] = np.full(int(todo.sum()), s)
        idx[other[0]], idx[other[1]] = grids[0][todo], grids[1][todo]
        cand = prev[todo]
        d2, side = mesh._exact(_grid_points(lo, spacing, *idx), cand)
        better = d2 < dist[tuple(idx)]
        sel = tuple(x[better] for x in idx)
        dist[sel], tri[sel], sign[sel], stamp[sel] = d2[better], cand[better], side[better], round_
        changed += int(better.sum())
    return changed


def _sq_dist(a, b):
    """Squared distances [A, B] between point sets a [A, 3] and b [B, 3]."""
    return np.maximum((a * a).sum(1)[:, None] - 2.0 * a @ b.T + (b * b).sum(1)[None], 0.0)
