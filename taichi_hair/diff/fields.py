"""The differentiable problem's Taichi fields: inputs, what the rest shape gives, and the slot
arrays of one checkpoint segment (frames.py's module docstring lists them), allocated once per
problem. Fields whose values a gradient flows through carry a gradient field."""

import taichi as ti

def slot_bytes(n_strands: int, n_nodes: int, projection_iterations: int, twist_iterations: int) -> int:
    """Bytes of one slot of the segment arrays (values and gradients, the process precision)."""
    per_node = 3 * 7 + 2 + 6 * projection_iterations + 6 * projection_iterations + \
        (twist_iterations + 1) + 6 * twist_iterations
    return 2 * per_node * n_strands * n_nodes * (8 if ti.lang.impl.get_runtime().default_fp == ti.f64 else 4)


def allocate(holder, n_strands: int, n_nodes: int, n_keys: int, slots: int, checkpoints: int,
             projection_iterations: int, twist_iterations: int) -> None:
    """Allocate every field as an attribute of `holder` (the problem)."""
    S, N, K, P, W = n_strands, n_nodes, slots, projection_iterations, twist_iterations

    def scalar(shape, grad=True):
        return ti.field(float, shape=shape, needs_grad=grad)

    def vector(shape, width=3, grad=True):
        return ti.Vector.field(width, float, shape=shape, needs_grad=grad)

    holder.node_count = ti.field(ti.i32, shape=S)
    # inputs
    holder.youngs_modulus, holder.shear_modulus, holder.density = scalar(S), scalar(S), scalar(S)
    holder.radius, holder.ellipticity = scalar(S), scalar(S, False)
    holder.drag = scalar(())
    holder.rest_x = vector((S, N))
    holder.initial_v = vector((S, N))
    holder.start_x = vector((S, N), grad=False)
    holder.keys = vector(n_keys, 6)
    holder.rest_theta, holder.rest_twist = scalar((S, N - 1), False), scalar((S, N), False)
    holder.root_u_head = vector(S, grad=False)
    holder.gravity, holder.pivot = vector((), grad=False), vector((), grad=False)
    holder.sphere_centre, holder.sphere_radius = vector((), grad=False), scalar((), False)
    # the rest shape and material
    holder.stiffness = vector(S)
    holder.rest_length, holder.voronoi, holder.mass = scalar((S, N - 1)), scalar((S, N)), scalar((S, N))
    holder.root_t_head = vector(S)
    holder.rest_u, holder.rest_kb = vector((S, N - 1)), vector((S, N))
    holder.rest_kappa = vector((S, N), 4)
    # one segment's slots
    holder.pose_r = ti.Matrix.field(3, 3, float, shape=K + 1, needs_grad=True)
    holder.pose_t = vector(K + 1)
    holder.x, holder.v = vector((K + 1, S, N)), vector((K + 1, S, N))
    holder.ang = scalar((K + 1, W + 1, S, N - 1))
    holder.u, holder.kb = vector((K + 1, S, N - 1)), vector((K + 1, S, N))
    holder.f, holder.bend, holder.hol = vector((K, S, N)), scalar((K, S, N - 1)), scalar((K, S, N))
    holder.xp, holder.xc = vector((K, P + 1, S, N)), vector((K, P, S, N))
    for name in ("pdiag", "pup", "pres", "pc", "pd", "lam"):
        setattr(holder, name, scalar((K, P, S, N - 1)))
    for name in ("tdiag", "tup", "tres", "tc", "td", "tstep"):
        setattr(holder, name, scalar((K, W, S, N - 1)))
    # the tridiagonal adjoint's scratch (tridiagonal.py)
    for name in ("mu_c", "mu_d", "mu"):
        setattr(holder, name, scalar((S, N - 1), False))
    # checkpoints (segment starts) and the gradient carried from one segment to the one before
    holder.ck_x, holder.ck_v = vector((checkpoints, S, N), grad=False), vector((checkpoints, S, N), grad=False)
    holder.ck_ang = scalar((checkpoints, S, N - 1), False)
    holder.carry_x, holder.carry_v = vector((S, N), grad=False), vector((S, N), grad=False)
    holder.carry_ang = scalar((S, N - 1), False)


SLOT_FIELDS = ("pose_r", "pose_t", "x", "v", "ang", "u", "kb", "f", "bend", "hol", "xp", "xc", "pdiag", "pup",
               "pres", "pc", "pd", "lam", "tdiag", "tup", "tres", "tc", "td", "tstep")
DERIVED_FIELDS = ("stiffness", "rest_length", "voronoi", "mass", "root_t_head", "rest_u", "rest_kb", "rest_kappa")
INPUT_FIELDS = ("youngs_modulus", "shear_modulus", "density", "radius", "drag", "rest_x", "initial_v", "keys")
