"""Colliders: shapes hair must stay outside of, enforced inside the fast projection.

Analytic shapes (sphere, ellipsoid, capsule, plane) and a triangle mesh through a signed-distance
grid. Each rides on the head (`attached="head"`: given in head coordinates, moving with the
head's rigid transform) or stays in the world (`attached="world"`). A node closer than `margin`
[m] (the hair layer's thickness) to the surface is pushed out to the margin along the surface
normal, and its motion along the surface, relative to the collider, is reduced by Coulomb
friction `friction` (position-based: over one step's projection iterations the friction shift
given to a node stays within friction x the sum of its pushes; docs/model.md, "Collisions").
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from ..rods.arrays import vec3
from ..rods.linalg import corner_factors, corner_signs, grid_cell
from ..validation import choice, real, vector3

SPHERE, ELLIPSOID, CAPSULE, PLANE = 0, 1, 2, 3
ATTACHMENTS = ("head", "world")


@dataclass(frozen=True, kw_only=True)
class _Collider:
    margin: float = 0.002
    friction: float = 0.3
    attached: str = "head"

    def _check_common(self):
        real("margin", self.margin, "m", low=0.0)
        real("friction", self.friction, "(Coulomb coefficient)", low=0.0)
        choice("attached", self.attached, ATTACHMENTS)


@dataclass(frozen=True, kw_only=True)
class Sphere(_Collider):
    """Sphere of `radius` [m] about `centre` [m]."""

    centre: tuple = (0.0, 0.0, 0.0)
    radius: float = 0.1

    def __post_init__(self):
        self._check_common()
        vector3("centre", self.centre)
        real("radius", self.radius, "m", low=0.0, low_open=True)

    def packed(self):
        return SPHERE, self.centre, (0.0, 0.0, 0.0), self.radius


@dataclass(frozen=True, kw_only=True)
class Ellipsoid(_Collider):
    """Axis-aligned ellipsoid (in its frame) with semi-axes `radii` [m] about `centre` [m].
    Its distance is Quilez's first-order estimate, exact on the surface and for spheres."""

    centre: tuple = (0.0, 0.0, 0.0)
    radii: tuple = (0.08, 0.1, 0.115)

    def __post_init__(self):
        self._check_common()
        vector3("centre", self.centre)
        vector3("radii", self.radii, positive=True)

    def packed(self):
        return ELLIPSOID, self.centre, self.radii, 0.0


@dataclass(frozen=True, kw_only=True)
class Capsule(_Collider):
    """Segment p0-p1 [m] swept by a sphere of `radius` [m] (neck, shoulders, arms, a finger)."""

    p0: tuple = (0.0, 0.0, -0.1)
    p1: tuple = (0.0, 0.0, -0.2)
    radius: float = 0.05

    def __post_init__(self):
        self._check_common()
        vector3("p0", self.p0)
        vector3("p1", self.p1)
        real("radius", self.radius, "m", low=0.0, low_open=True)

    def packed(self):
        return CAPSULE, self.p0, self.p1, self.radius


@dataclass(frozen=True, kw_only=True)
class Plane(_Collider):
    """Half-space above the plane through `point` [m] with unit `normal` (a floor, a wall)."""

    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 0.0, 1.0)
    attached: str = "world"

    def __post_init__(self):
        self._check_common()
        vector3("point", self.point)
        n = vector3("normal", self.normal)
        if np.linalg.norm(n) < 1e-9:
            raise ValueError(f"normal must be non-zero, got {self.normal!r}")

    def packed(self):
        n = np.asarray(self.normal, dtype=np.float64)
        return PLANE, self.point, n / np.linalg.norm(n), 0.0


@dataclass(frozen=True, kw_only=True)
class MeshCollider(_Collider):
    """A closed triangle mesh through its signed-distance grid, built once at load:
    `grid` has values [nx, ny, nz] (metres, negative inside) sampled at origin + spacing (i, j, k)
    (see taichi_hair.world.sdf.SignedDistanceGrid)."""

    grid: object = None

    def __post_init__(self):
        self._check_common()
        values = getattr(self.grid, "values", None)
        if values is None or np.asarray(values).ndim != 3 or min(np.asarray(values).shape) < 2:
            raise ValueError("grid must be a signed-distance grid with values [nx, ny, nz] (nx, ny, nz >= 2), "
                             f"origin [3] and spacing; got {type(self.grid).__name__}")
        real("grid.spacing", float(self.grid.spacing), "m", low=0.0, low_open=True)
        vector3("grid.origin", self.grid.origin)


# ---- distance functions, in the collider's own frame ------------------------------------------

@ti.func
def analytic_distance(kind, a, b, radius, p):
    """(signed distance [m], outward unit normal) of point p from analytic collider (kind, a, b, r)."""
    d = 0.0
    n = vec3(0.0, 0.0, 1.0)
    if kind == SPHERE:
        d, n = sphere_distance(p - a, radius)
    elif kind == ELLIPSOID:
        q = p - a
        k0 = (q / b).norm()
        k1 = (q / (b * b)).norm()
        d = k0 * (k0 - 1.0) / ti.max(k1, 1e-12)
        n = safe_normal(q / (b * b), n)
    elif kind == CAPSULE:
        ab = b - a
        t = ti.math.clamp((p - a).dot(ab) / ti.max(ab.dot(ab), 1e-12), 0.0, 1.0)
        q = p - (a + t * ab)
        d = q.norm() - radius
        n = safe_normal(q, n)
    else:  # PLANE: a point on it, b its unit normal
        d = (p - a).dot(b)
        n = b
    return d, n


@ti.func
def sphere_distance(q, radius):
    """(signed distance [m], outward unit normal) of offset q [m] from a sphere's centre."""
    return q.norm() - radius, safe_normal(q, vec3(0.0, 0.0, 1.0))


@ti.func
def safe_normal(q, fallback):
    result = fallback
    length = q.norm()
    if length > 1e-12:
        result = q / length
    return result


# sdf_meta rows per distance grid (pack_grids): origin [m]; (spacing [m], margin [m], friction);
# (attached to head 1/0, first z index in the packed values, 0); (nx, ny, nz)
GRID_META_ROWS = 4


@ti.func
def grid_distance(values: ti.template(), meta: ti.template(), g, p):
    """Trilinear signed distance [m] and unit gradient of distance grid g of the packed grids
    (values, meta: pack_grids) at p (clamped to the grid's box: outside it, the box's boundary
    values, which are positive by construction)."""
    row = GRID_META_ROWS * g
    origin, spacing = meta[row], meta[row + 1][0]
    offset = ti.cast(meta[row + 2][1], ti.i32)
    top = ti.cast(meta[row + 3], ti.i32) - 1  # the largest index along each axis
    base, f = grid_cell((p - origin) / spacing)
    d = 0.0
    grad = vec3(0.0)
    for c in ti.static(ti.grouped(ti.ndrange(2, 2, 2))):
        w = corner_factors(c, f)
        value = values[ti.math.clamp(base[0] + c[0], 0, top[0]), ti.math.clamp(base[1] + c[1], 0, top[1]),
                       offset + ti.math.clamp(base[2] + c[2], 0, top[2])]
        d += w[0] * w[1] * w[2] * value
        grad += value * corner_signs(c) * vec3(w[1] * w[2], w[0] * w[2], w[0] * w[1])
    return d, safe_normal(grad, vec3(0.0, 0.0, 1.0))


def pack_grids(meshes):
    """Kernel arrays for the mesh colliders' distance grids: values [NX, NY, NZ] m, the grids side
    by side along z (grid g from its meta's z offset), and meta [GRID_META_ROWS x G] vec3
    (GRID_META_ROWS). No grid: a 2 x 2 x 2 placeholder and empty meta."""
    if not meshes:
        return np.ones((2, 2, 2)), np.zeros((0, 3))
    shapes = np.array([np.asarray(m.grid.values).shape for m in meshes])
    values = np.ones((shapes[:, 0].max(), shapes[:, 1].max(), shapes[:, 2].sum()))
    meta = np.zeros((GRID_META_ROWS * len(meshes), 3))
    offset = 0
    for g, (m, shape) in enumerate(zip(meshes, shapes)):
        values[: shape[0], : shape[1], offset: offset + shape[2]] = m.grid.values
        meta[GRID_META_ROWS * g: GRID_META_ROWS * (g + 1)] = [
            m.grid.origin, [m.grid.spacing, m.margin, m.friction],
            [1.0 if m.attached == "head" else 0.0, offset, 0.0], shape]
        offset += shape[2]
    return values, meta


def pack_colliders(colliders):
    """Kernel arrays for the analytic colliders: kinds [C] int, geometry [C, 2] vec3 (a, b),
    params [C] vec4 (radius, margin, friction, attached to head 1/0). Mesh colliders go apart."""
    analytic = [c for c in colliders if not isinstance(c, MeshCollider)]
    kinds = np.array([c.packed()[0] for c in analytic] or [0], dtype=np.int32)
    geometry = np.zeros((max(len(analytic), 1), 2, 3))
    params = np.zeros((max(len(analytic), 1), 4))
    for k, c in enumerate(analytic):
        _, a, b, radius = c.packed()
        geometry[k] = [a, b]
        params[k] = [radius, c.margin, c.friction, 1.0 if c.attached == "head" else 0.0]
    return len(analytic), kinds, geometry, params


def host_distance(c, p):
    """Signed distance [m], shape [M], of points p [M, 3] m from one collider `c`, on the host (the
    kernels' formulas)."""
    if isinstance(c, MeshCollider):
        return c.grid.sample(p)
    kind, a, b, radius = c.packed()
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if isinstance(c, Sphere):
        return np.linalg.norm(p - a, axis=1) - radius
    if isinstance(c, Ellipsoid):
        q = p - a
        k0 = np.linalg.norm(q / b, axis=1)
        return k0 * (k0 - 1.0) / np.maximum(np.linalg.norm(q / b**2, axis=1), 1e-12)
    if isinstance(c, Capsule):
        ab = b - a
        t = np.clip((p - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
        return np.linalg.norm(p - (a + t[:, None] * ab), axis=1) - radius
    return (p - a) @ b
