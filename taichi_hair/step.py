"""Kmoch's loop, one time step h: forces, integrate, project, velocities, frames, twist.

Each stage is a per-strand `ti.func` below. Two drivers run them:
- `advance_strands`: one kernel launch for many steps, one thread per strand running the
  stages in order; the stages a scene does not use are removed at compile time (`ti.static`
  flags), so they are neither compiled nor run. This is the default: Python's per-launch cost
  (about 12 us per array argument with Taichi 1.7) would otherwise dominate small scenes.
- `kmoch_step`: one kernel per stage and per step, for the per-stage timings of the benchmark
  and for scenes whose stages couple strands (hair-hair interaction).
"""

from contextlib import nullcontext
from dataclasses import dataclass

import taichi as ti

from .arrays import Ints1, Scalars1, Scalars2, Vec3s1, Vec3s2, Vec4s1, Vec4s2, vec3
from .frames import strand_frames, strand_material_frames, update_frames, update_material_frames
from .linalg import thomas_solve
from .rod import elastic_forces, strand_elastic_forces
from .twist import (kmoch_twist_angles, solve_twist_quasistatic, strand_twist_kmoch,
                    strand_twist_quasistatic)

TWIST_CODES = {"none": 0, "kmoch": 1, "quasistatic": 2}


@dataclass(frozen=True)
class StepPlan:
    """Which stages run, fixed when the simulator is built, and the solver tolerances."""

    external_forces: bool  # gravity, air drag or wind present
    twist: str  # "kmoch", "quasistatic" or "none"
    projection_tol: float
    projection_iterations: int
    twist_tol: float
    twist_iterations: int


# ---- stages, one strand each ----------------------------------------------------------------

@ti.func
def strand_external_forces(s, node_count: ti.template(), mass: ti.template(), voronoi: ti.template(),
                           v: ti.template(), loads: ti.template(), drag, force: ti.template()):
    """force += m g - drag l_i (v - wind), loads = (gravity [m/s^2], wind [m/s]), drag in N s/m
    per metre of strand."""
    for i in range(node_count[s]):
        force[s, i] += mass[s, i] * loads[0] - drag * voronoi[s, i] * (v[s, i] - loads[1])


@ti.func
def strand_add_forces(s, node_count: ti.template(), extra: ti.template(), force: ti.template()):
    for i in range(node_count[s]):
        force[s, i] += extra[s, i]


@ti.func
def strand_symplectic_euler(s, h, node_count: ti.template(), inv_mass: ti.template(),
                            force: ti.template(), v: ti.template(), x: ti.template(),
                            x_prev: ti.template()):
    """v += h F / m, x_prev = x, x += h v for the free nodes (inv_mass > 0)."""
    for i in range(node_count[s]):
        x_prev[s, i] = x[s, i]
        if inv_mass[s, i] > 0.0:
            v[s, i] += h * inv_mass[s, i] * force[s, i]
            x[s, i] += h * v[s, i]


@ti.func
def rigid_transform(head: ti.template(), k, p):
    """R p + t for the head pose k, head[k, 0..2] the rows of R and head[k, 3] = t."""
    return vec3(head[k, 0].dot(p), head[k, 1].dot(p), head[k, 2].dot(p)) + head[k, 3]


@ti.func
def strand_place_root(s, head: ti.template(), k, root_rest: ti.template(), root_tangent: ti.template(),
                      root_reference: ti.template(), x: ti.template(), root_t: ti.template(),
                      root_u: ti.template()):
    """The clamped root edge rides on head pose k: its two nodes x = R xbar + t, and the
    reference (t, u) from which the Bishop frames start turns with R."""
    for node in ti.static(range(2)):
        x[s, node] = rigid_transform(head, k, root_rest[s, node])
    root_t[s] = rigid_transform(head, k, root_tangent[s]) - head[k, 3]
    root_u[s] = rigid_transform(head, k, root_reference[s]) - head[k, 3]


@ti.func
def strand_project(s, node_count: ti.template(), inv_mass: ti.template(), rest_length: ti.template(),
                   tol, max_iterations, x: ti.template(), dx: ti.template(), diag: ti.template(),
                   upper: ti.template(), rhs: ti.template()):
    """Fast projection (Goldenthal et al. 2007) of C_j = |e^j|^2 - |ebar^j|^2 = 0 on every free
    edge: each iteration solves (grad C M^-1 grad C^T) lambda = C (tridiagonal) and moves
    x -= M^-1 grad C^T lambda, until max_j |C_j| / |ebar^j|^2 < tol, max_iterations, or a stall
    (an iteration that removes less than 10 % of the residual: the precision's rounding floor).
    The root edge's nodes have infinite mass. Returns (iterations, final residual)."""
    n = node_count[s]
    it = 0
    res = 0.0
    previous = 0.0
    while True:
        previous = res
        res = 0.0
        for j in range(1, n - 1):
            e = x[s, j + 1] - x[s, j]
            l2 = rest_length[s, j] * rest_length[s, j]
            c = e.dot(e) - l2
            res = ti.max(res, ti.abs(c) / l2)
            rhs[s, j] = c
            diag[s, j] = 4.0 * e.dot(e) * (inv_mass[s, j] + inv_mass[s, j + 1])
            if j + 1 < n - 1:
                upper[s, j] = -4.0 * inv_mass[s, j + 1] * e.dot(x[s, j + 2] - x[s, j + 1])
        if res < tol or it >= max_iterations or (it >= 1 and res > 0.9 * previous):
            break
        thomas_solve(s, 1, n - 2, diag, upper, rhs)
        for i in range(n):
            dx[s, i] = vec3(0.0)
        for j in range(1, n - 1):
            e = x[s, j + 1] - x[s, j]
            dx[s, j] += 2.0 * inv_mass[s, j] * rhs[s, j] * e
            dx[s, j + 1] -= 2.0 * inv_mass[s, j + 1] * rhs[s, j] * e
        for i in range(n):
            x[s, i] += dx[s, i]
        it += 1
    return it, res


@ti.func
def strand_velocities(s, inv_h, max_speed, node_count: ti.template(), x: ti.template(),
                      x_prev: ti.template(), v: ti.template()):
    """v = (x - x_prev) / h. Returns 1 if a node is non-finite or faster than max_speed, else 0."""
    bad = 0
    for i in range(node_count[s]):
        vel = (x[s, i] - x_prev[s, i]) * inv_h
        v[s, i] = vel
        # written so that NaN, which fails every comparison, counts as bad
        if not (vel.dot(vel) <= max_speed * max_speed):
            bad = 1
    return bad


@ti.func
def record(s, counter: ti.template(), residual: ti.template(), it, res):
    counter[s] = ti.max(counter[s], it)
    residual[s] = ti.max(residual[s], res)


@ti.func
def record_projection(s, counter: ti.template(), residual: ti.template(), cap_hits: ti.template(),
                      stalls: ti.template(), it, res, tol, max_iterations):
    """Running maxima of iterations and final residual; counts of steps that ended above tol
    at the iteration cap, or stalled at the rounding floor."""
    record(s, counter, residual, it, res)
    if res >= tol:
        if it >= max_iterations:
            cap_hits[s] += 1
        else:
            stalls[s] += 1


# ---- the fused driver -------------------------------------------------------------------------

@ti.kernel
def advance_strands(
        n_steps: int, h: float, drag: float, max_speed: float, projection_tol: float,
        projection_iterations: int, twist_tol: float, twist_iterations: int,
        external: ti.template(), twist_mode: ti.template(), user: ti.template(), moving_head: ti.template(),
        node_count: Ints1, mass: Scalars2, inv_mass: Scalars2, rest_length: Scalars2, voronoi: Scalars2,
        stiffness: Vec4s1, rest_kappa: Vec4s2, rest_twist: Scalars2, root_rest: Vec3s2,
        root_tangent: Vec3s1, root_reference: Vec3s1, head: Vec3s2, loads: Vec3s1, user_force: Vec3s2,
        x: Vec3s2, v: Vec3s2, x_prev: Vec3s2, dx: Vec3s2, force: Vec3s2, theta: Scalars2,
        bishop_u: Vec3s2, bishop_v: Vec3s2, m1: Vec3s2, m2: Vec3s2, kb: Vec3s2, root_t: Vec3s1,
        root_u: Vec3s1, scratch_a: Scalars2, scratch_b: Scalars2, scratch_c: Scalars2,
        projection_count: Ints1, projection_residual: Scalars1, cap_hits: Ints1, stalls: Ints1,
        twist_count: Ints1, twist_residual: Scalars1, bad_step: Ints1):
    """n_steps steps of h [s] for every strand; head[k] is the head pose at the end of step k
    (only head[0] when not moving_head). bad_step[s] = first step where strand s went non-finite
    or too fast (that strand stops there), -1 if none. One thread per strand."""
    for s in range(x.shape[0]):
        bad_step[s] = -1
        for k in range(n_steps):
            strand_elastic_forces(s, x, node_count, kb, m1, m2, rest_kappa, voronoi, stiffness, force)
            if ti.static(external):
                strand_external_forces(s, node_count, mass, voronoi, v, loads, drag, force)
            if ti.static(user):
                strand_add_forces(s, node_count, user_force, force)
            strand_symplectic_euler(s, h, node_count, inv_mass, force, v, x, x_prev)
            pose = 0
            if ti.static(moving_head):
                pose = k
            strand_place_root(s, head, pose, root_rest, root_tangent, root_reference, x, root_t, root_u)
            it, res = strand_project(s, node_count, inv_mass, rest_length, projection_tol,
                                     projection_iterations, x, dx, scratch_a, scratch_b, scratch_c)
            record_projection(s, projection_count, projection_residual, cap_hits, stalls, it, res,
                              projection_tol, projection_iterations)
            bad = strand_velocities(s, 1.0 / h, max_speed, node_count, x, x_prev, v)
            strand_frames(s, x, node_count, root_t, root_u, theta, bishop_u, bishop_v, m1, m2, kb)
            if ti.static(twist_mode == 1):
                strand_twist_kmoch(s, node_count, bishop_u, bishop_v, kb, theta, rest_kappa,
                                   rest_twist, voronoi, stiffness, scratch_a)
            if ti.static(twist_mode == 2):
                it, res = strand_twist_quasistatic(s, node_count, bishop_u, bishop_v, kb, theta,
                                                   rest_kappa, rest_twist, voronoi, stiffness,
                                                   twist_tol, twist_iterations, scratch_a,
                                                   scratch_b, scratch_c)
                record(s, twist_count, twist_residual, it, res)
            if ti.static(twist_mode != 0):
                strand_material_frames(s, node_count, theta, bishop_u, bishop_v, m1, m2)
            if bad:
                bad_step[s] = k
                break


def advance(model, state, control, plan: StepPlan, h: float, n_steps: int, moving_head: bool) -> None:
    """Run n_steps steps of h in one launch; state.strand_bad holds each strand's first bad step."""
    md, st = model, state
    user = control.user_force is not None
    advance_strands(
        n_steps, h, control.drag, control.max_speed, plan.projection_tol, plan.projection_iterations,
        plan.twist_tol, plan.twist_iterations, plan.external_forces, TWIST_CODES[plan.twist], user,
        moving_head, md.node_count, md.mass, md.inv_mass, md.rest_length, md.voronoi, md.stiffness,
        md.rest_kappa, md.rest_twist, md.root_rest, md.root_tangent, md.root_reference,
        control.head_poses if moving_head else control.head,
        control.loads, control.user_force if user else st.force, st.x, st.v, st.x_prev, st.dx,
        st.force, st.theta, st.bishop_u, st.bishop_v, st.m1, st.m2, st.kb, st.root_t, st.root_u,
        *st.scratch_edge, st.projection_iterations, st.projection_residual, st.projection_cap_hits,
        st.projection_stalls, st.twist_iterations, st.twist_residual, st.strand_bad)


# ---- one kernel per stage (benchmark breakdown; strand-coupling scenes) ---------------------

@ti.kernel
def external_and_user_forces(external: ti.template(), user: ti.template(), node_count: Ints1,
                             mass: Scalars2, voronoi: Scalars2, v: Vec3s2, loads: Vec3s1, drag: float,
                             user_force: Vec3s2, force: Vec3s2):
    for s in range(force.shape[0]):
        if ti.static(external):
            strand_external_forces(s, node_count, mass, voronoi, v, loads, drag, force)
        if ti.static(user):
            strand_add_forces(s, node_count, user_force, force)


@ti.kernel
def integrate(h: float, node_count: Ints1, inv_mass: Scalars2, force: Vec3s2, head: Vec3s2,
              root_rest: Vec3s2, root_tangent: Vec3s1, root_reference: Vec3s1, v: Vec3s2, x: Vec3s2,
              x_prev: Vec3s2, root_t: Vec3s1, root_u: Vec3s1):
    for s in range(x.shape[0]):
        strand_symplectic_euler(s, h, node_count, inv_mass, force, v, x, x_prev)
        strand_place_root(s, head, 0, root_rest, root_tangent, root_reference, x, root_t, root_u)


@ti.kernel
def project_inextensibility(node_count: Ints1, inv_mass: Scalars2, rest_length: Scalars2,
                            tol: float, max_iterations: int, x: Vec3s2, dx: Vec3s2,
                            diag: Scalars2, upper: Scalars2, rhs: Scalars2,
                            iterations: Ints1, residual: Scalars1, cap_hits: Ints1, stalls: Ints1):
    """strand_project for every strand, recorded as in record_projection. One thread per strand."""
    for s in range(x.shape[0]):
        it, res = strand_project(s, node_count, inv_mass, rest_length, tol, max_iterations, x, dx,
                                 diag, upper, rhs)
        record_projection(s, iterations, residual, cap_hits, stalls, it, res, tol, max_iterations)


@ti.kernel
def update_velocities(node_count: Ints1, x: Vec3s2, x_prev: Vec3s2, inv_h: float,
                      max_speed: float, v: Vec3s2, bad_step: Ints1):
    for s in range(x.shape[0]):
        bad_step[s] = -1
        if strand_velocities(s, inv_h, max_speed, node_count, x, x_prev, v):
            bad_step[s] = 0


@ti.kernel
def place_roots(head: Vec3s2, root_rest: Vec3s2, root_tangent: Vec3s1, root_reference: Vec3s1,
                x: Vec3s2, root_t: Vec3s1, root_u: Vec3s1):
    """Root nodes and root reference frames at head pose 0. One thread per strand."""
    for s in range(x.shape[0]):
        strand_place_root(s, head, 0, root_rest, root_tangent, root_reference, x, root_t, root_u)


def kmoch_step(model, state, control, plan: StepPlan, h: float, timers=None) -> None:
    """One step of h with one kernel per stage; `timers(name)` gives a context manager timing
    each stage (it must synchronise). state.strand_bad marks strands that went bad."""
    md, st = model, state
    stage = timers if timers is not None else (lambda name: nullcontext())
    user = control.user_force is not None
    with stage("forces"):
        elastic_forces(st.x, md.node_count, st.kb, st.m1, st.m2, md.rest_kappa, md.voronoi,
                       md.stiffness, st.force)
        if plan.external_forces or user:
            external_and_user_forces(plan.external_forces, user, md.node_count, md.mass, md.voronoi,
                                     st.v, control.loads, control.drag,
                                     control.user_force if user else st.force, st.force)
    with stage("integration"):
        integrate(h, md.node_count, md.inv_mass, st.force, control.head, md.root_rest,
                  md.root_tangent, md.root_reference, st.v, st.x, st.x_prev, st.root_t, st.root_u)
    with stage("projection"):
        project_inextensibility(md.node_count, md.inv_mass, md.rest_length, plan.projection_tol,
                                plan.projection_iterations, st.x, st.dx, *st.scratch_edge,
                                st.projection_iterations, st.projection_residual,
                                st.projection_cap_hits, st.projection_stalls)
    with stage("integration"):
        update_velocities(md.node_count, st.x, st.x_prev, 1.0 / h, control.max_speed, st.v, st.strand_bad)
    with stage("frames + twist"):
        update_frames(st.x, md.node_count, st.root_t, st.root_u, st.theta, st.bishop_u,
                      st.bishop_v, st.m1, st.m2, st.kb)
        run_twist_update(model, state, plan)


def run_twist_update(model, state, plan: StepPlan):
    """The twist stage (no-op for "none"); material frames follow the new angles."""
    md, st = model, state
    if plan.twist == "none":
        return
    if plan.twist == "quasistatic":
        grad, diag, upper = st.scratch_edge
        solve_twist_quasistatic(md.node_count, st.bishop_u, st.bishop_v, st.kb, st.theta,
                                md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness,
                                plan.twist_tol, plan.twist_iterations, grad, diag, upper,
                                st.twist_iterations, st.twist_residual)
    else:
        kmoch_twist_angles(md.node_count, st.bishop_u, st.bishop_v, st.kb, st.theta,
                           md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness, st.scratch_edge[0])
    update_material_frames(md.node_count, st.theta, st.bishop_u, st.bishop_v, st.m1, st.m2)


@ti.kernel
def strand_mechanical_energy(node_count: Ints1, mass: Scalars2, inv_mass: Scalars2, x: Vec3s2,
                             v: Vec3s2, loads: Vec3s1, kinetic: Scalars1, potential: Scalars1):
    """kinetic[s] = sum 1/2 m |v|^2, potential[s] = -sum m g . x [J] over the free nodes (the root
    edge is driven by the head, not by forces). One thread per strand."""
    for s in range(x.shape[0]):
        k = 0.0
        p = 0.0
        for i in range(node_count[s]):
            if inv_mass[s, i] > 0.0:
                k += 0.5 * mass[s, i] * v[s, i].dot(v[s, i])
                p -= mass[s, i] * loads[0].dot(x[s, i])
        kinetic[s] = k
        potential[s] = p
