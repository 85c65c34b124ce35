"""Kernel argument types and allocation helpers for the simulator's Taichi arrays.

All simulator state lives in Taichi ndarrays indexed [strand, node] or [strand, edge]
(structure of arrays). Kernels take them as `ti.types.ndarray` arguments, so each kernel
compiles once per process and is reused by every strand, scene and simulator; a kernel taking
`ti.field`s as templates would recompile for every newly allocated field (measured ~0.2 s per
kernel on this CPU). Element type `float` follows the precision chosen by `taichi_hair.init`.
"""

import numpy as np
import taichi as ti

from ..runtime import ensure_init

vec2 = ti.math.vec2
vec3 = ti.math.vec3
vec4 = ti.math.vec4

Scalars1 = ti.types.ndarray(dtype=float, ndim=1)  # [S]
Scalars2 = ti.types.ndarray(dtype=float, ndim=2)  # [S, N] or [S, N - 1]
Scalars3 = ti.types.ndarray(dtype=float, ndim=3)  # grids [nx, ny, nz]
Ints1 = ti.types.ndarray(dtype=ti.i32, ndim=1)  # [S]
Ints2 = ti.types.ndarray(dtype=ti.i32, ndim=2)  # [S, k]
Vec3s1 = ti.types.ndarray(dtype=vec3, ndim=1)  # [S]
Vec3s2 = ti.types.ndarray(dtype=vec3, ndim=2)  # [S, N] or [S, N - 1]
Vec3s3 = ti.types.ndarray(dtype=vec3, ndim=3)  # [S, N, k]
Vec4s1 = ti.types.ndarray(dtype=vec4, ndim=1)
Vec4s2 = ti.types.ndarray(dtype=vec4, ndim=2)
# node positions are stored in float64 in both precisions: in float32 each update rounded a
# position to eps |x| (3e-8 m at 0.3 m, whatever the segment), and stiff fine hair turned that
# rounding into energy at every substep; edges are formed in float64 and rounded once,
# relative to their own length (`edge`). docs/model.md, "Positions and velocities in float32"
vec3d = ti.types.vector(3, ti.f64)
Points2 = ti.types.ndarray(dtype=vec3d, ndim=2)  # [S, N] positions [m]
# the implicit step's banded systems are factored in float64 in both precisions (a hair node's
# mass and its bending stiffness over a large step differ by up to 1e7: float32 loses them);
# node i's unknowns: velocity (3), the multiplier of edge i-1, the angle of edge i-1
BLOCK = 5
mat_block = ti.types.matrix(BLOCK, BLOCK, ti.f64)
vec_block = ti.types.vector(BLOCK, ti.f64)
BlockMats3 = ti.types.ndarray(dtype=mat_block, ndim=3)  # [S, N, k]: k 5x5 blocks per node
BlockVecs2 = ti.types.ndarray(dtype=vec_block, ndim=2)

# The rods' arrays as two bundles (Taichi argpacks of ndarrays): the model (state.RodModel) and
# the state (state.RodState, with its three edge scratch rows diag, upper, rhs). The step's
# kernels and the energy and force kernels of rod.py and twist_forces.py take them whole; a
# ti.func reads the members it needs (solver/step/bundles.StepBundles builds them once).
ModelArgs = ti.types.argpack(
    node_count=Ints1, mass=Scalars2, inv_mass=Scalars2, rest_length=Scalars2, voronoi=Scalars2,
    stiffness=Vec4s1, rest_kappa=Vec4s2, rest_twist=Scalars2, root_frame=Vec3s2)


StateArgs = ti.types.argpack(
    x=Points2, v=Vec3s2, x_prev=Points2, dx=Vec3s2, force=Vec3s2, theta=Scalars2, bishop_u=Vec3s2,
    bishop_v=Vec3s2, m1=Vec3s2, m2=Vec3s2, kb=Vec3s2, root_t=Vec3s1, root_u=Vec3s1,
    diag=Scalars2, upper=Scalars2, rhs=Scalars2, counters=Ints2, residuals=Scalars2, history=Vec3s3,
    tension=Scalars2, blocks=BlockMats3, block_rhs=BlockVecs2)


def scalars(shape, value=None):
    """A float ndarray of `shape`, zero or filled from `value` (numpy-broadcastable)."""
    ensure_init()
    a = ti.ndarray(float, shape)
    a.from_numpy(np.broadcast_to(np.asarray(0.0 if value is None else value, dtype=np_float()), shape).copy())
    return a


def ints(shape, value):
    ensure_init()
    a = ti.ndarray(ti.i32, shape)
    a.from_numpy(np.ascontiguousarray(np.broadcast_to(np.asarray(value, dtype=np.int32), shape)))
    return a


@ti.func
def edge(x: ti.template(), s, i, j):
    """x[s, j] - x[s, i] in the process's float (formed in the positions' float64) [m]."""
    return ti.cast(x[s, j] - x[s, i], float)


@ti.func
def step_displacement(x: ti.template(), x_prev: ti.template(), s, i):
    """x[s, i] - x_prev[s, i] in the process's float [m]."""
    return ti.cast(x[s, i] - x_prev[s, i], float)


@ti.func
def point(x: ti.template(), s, i):
    """x[s, i] in the process's float [m]."""
    return ti.cast(x[s, i], float)


def vectors(n, shape, value=None, dtype=float):
    """An ndarray of n-vectors (element type `dtype`, default the process's float) with index
    `shape`, zero or filled from `value` [*shape, n]."""
    ensure_init()
    a = ti.Vector.ndarray(n, dtype, shape)
    full = tuple(shape) + (n,)
    np_dtype = np.float64 if dtype is ti.f64 else np_float()
    a.from_numpy(np.broadcast_to(np.asarray(0.0 if value is None else value, dtype=np_dtype), full).copy())
    return a


def matrices(n, shape, dtype=float):
    """An ndarray of n x n matrices (element type `dtype`) with index `shape`, zero."""
    ensure_init()
    a = ti.Matrix.ndarray(n, n, dtype, shape)
    a.fill(0.0)
    return a


def np_float():
    """numpy dtype of the process's Taichi float."""
    from ..runtime import precision
    return np.float64 if precision() == "float64" else np.float32


def like(a):
    """A new ndarray with the same element type and shape as ndarray `a` (contents undefined)."""
    ensure_init()
    if a.element_shape:
        return ti.Vector.ndarray(a.element_shape[0], a.dtype, a.shape)
    return ti.ndarray(a.dtype, a.shape)
