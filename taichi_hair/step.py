"""Kmoch's loop, one time step h: forces, integrate, project (inextensibility + contacts),
velocities, frames, twist.

Each stage is a per-strand `ti.func`. Two drivers run them:
- `advance_strands`: one kernel launch for many steps, one thread per strand running the
  stages in order; the stages a scene does not use are removed at compile time (`ti.static`
  flags), so they are neither compiled nor run. This is the default: Python's per-launch cost
  (about 12-20 us per array argument with Taichi 1.7) would otherwise dominate small scenes.
- `kmoch_step`: one kernel per stage and per step, for the per-stage timings of the benchmark
  and for hair-hair interaction, whose grid couples strands between stages.

Head poses: `head[k]` ([K+1, 4] vec3: rows of R, then t) is the head before step 0 (k = 0) and
after step k-1; a static head passes [prev, now] and uses now for every step after the first.
"""

from contextlib import nullcontext
from dataclasses import dataclass

import taichi as ti

from .arrays import Ints1, Ints2, Scalars1, Scalars2, Scalars3, Vec3s1, Vec3s2, Vec4s1, Vec4s2, vec3
from .collisions import strand_collide
from .forces import air_velocity, grab_force
from .frames import strand_frames, strand_material_frames
from .linalg import thomas_solve
from .pins import strand_carry_root_frame, strand_place_pins
from .rod import elastic_forces, strand_elastic_forces
from .state import COUNTERS
from .twist import (CAPPED, STALLED, kmoch_forces, strand_kmoch_forces, strand_twist_kmoch,
                    strand_twist_quasistatic)

TWIST_CODES = {"none": 0, "kmoch": 1, "quasistatic": 2}
# root modes (docs/model.md, "The clamp at the root"): clamped at node 0 (bending from node 0),
# pinned (a hinge at node 0), edge (the first edge held rigid, bending from node 1: the model
# before the clamp moved to the root node, kept for comparison)
ROOT_CODES = {"clamped": 0, "pinned": 1, "edge": 2}
STALL_BELOW = 1e-3  # a stall ends the projection only this close to satisfied (the rounding floor)
FAILED_ABOVE = 1e-2  # a residual left above this (0.5 % strain) is a failed step, not a result
# With pins a stretch of strand can be held at both ends; taut and straight, its projection
# system is singular (more length constraints than the free nodes can move along the line).
# Levenberg-Marquardt damping of the diagonal, (1 + HELD_DAMPING), keeps every pivot positive;
# it slows the linear convergence only by a factor HELD_DAMPING per iteration.
HELD_DAMPING = 1e-6
# a twist solve that stalled at the rounding floor above this scaled residual is a failed step
TWIST_FAILED_ABOVE = 1e-3
PROJ_IT, PROJ_CAP, PROJ_STALL, TWIST_IT, BAD, TWIST_CAP, TWIST_STALL, TWIST_SWITCH = (
    COUNTERS[k] for k in ("projection_iterations", "projection_cap_hits", "projection_stalls",
                          "twist_iterations", "bad_step", "twist_cap_hits", "twist_stalls",
                          "twist_branch_switches"))


@dataclass(frozen=True)
class StepPlan:
    """Which stages run (fixed when the simulator is built) and the solver tolerances."""

    external_forces: bool  # gravity, air drag or wind present
    wind_field: bool  # gusts or turbulence: air velocity varies in time and space
    twist: str  # "kmoch", "quasistatic" or "none"
    n_analytic: int  # analytic colliders
    mesh: bool  # a distance-grid collider
    touch: bool  # hands or grab tools
    projection_tol: float
    projection_iterations: int
    twist_tol: float
    twist_iterations: int
    root: str = "clamped"  # "clamped", "pinned" (a hinge at node 0) or "edge" (rigid first edge)

    @property
    def pinned_root(self) -> bool:
        return self.root == "pinned"

    @property
    def root_mode(self) -> int:
        return ROOT_CODES[self.root]

    @property
    def contacts(self) -> bool:
        return self.n_analytic > 0 or self.mesh or self.touch


# ---- stages, one strand each ----------------------------------------------------------------

@ti.func
def strand_external_forces(s, t, drag, wind_field: ti.template(), touch: ti.template(),
                           node_count: ti.template(), mass: ti.template(), voronoi: ti.template(),
                           x: ti.template(), v: ti.template(), loads: ti.template(),
                           gusts: ti.template(), modes: ti.template(), tools: ti.template(),
                           tool_points: ti.template(), now, force: ti.template()):
    """force += m g - drag l_i (v - u_air) + grab springs; loads = (gravity [m/s^2], mean wind
    [m/s]); drag in N s/m per metre of strand; u_air varies in time and space with wind_field."""
    for i in range(node_count[s]):
        air = loads[1]
        if ti.static(wind_field):
            air = air_velocity(loads[1], gusts, modes, t, x[s, i])
        f = mass[s, i] * loads[0] - drag * voronoi[s, i] * (v[s, i] - air)
        if ti.static(touch):
            f += grab_force(tools, tool_points, now, x[s, i])
        force[s, i] += f


@ti.func
def strand_add_forces(s, node_count: ti.template(), extra: ti.template(), force: ti.template()):
    for i in range(node_count[s]):
        force[s, i] += extra[s, i]


@ti.func
def strand_symplectic_euler(s, h, node_count: ti.template(), inv_mass: ti.template(),
                            force: ti.template(), v: ti.template(), x: ti.template(),
                            x_prev: ti.template(), dx: ti.template()):
    """v += h F / m, x_prev = x, x += h v for the free nodes (inv_mass > 0); dx = the step's
    displacement so far (h v, 0 on held nodes), which the projection and contacts add to."""
    for i in range(node_count[s]):
        x_prev[s, i] = x[s, i]
        dx[s, i] = vec3(0.0)
        if inv_mass[s, i] > 0.0:
            v[s, i] += h * inv_mass[s, i] * force[s, i]
            dx[s, i] = h * v[s, i]
            x[s, i] += dx[s, i]


@ti.func
def rotate(head: ti.template(), k, p):
    return vec3(head[k, 0].dot(p), head[k, 1].dot(p), head[k, 2].dot(p))


@ti.func
def strand_place_root(s, head: ti.template(), k, root_frame: ti.template(), x: ti.template(),
                      root_t: ti.template(), root_u: ti.template(), root_mode: ti.template()):
    """The root node rides on head pose k: x_0 = R xbar_0 + t. A clamped root's frame (t, u), the
    clamp that node 0 bends and twists against and from which the Bishop frames start, turns
    with R; a pinned root's reference is carried in time instead (pins.strand_carry_root_frame)."""
    for node in ti.static(range(2 if root_mode == 2 else 1)):  # "edge": the first edge rides too
        x[s, node] = rotate(head, k, root_frame[s, node]) + head[k, 3]
    if ti.static(root_mode != 1):
        root_t[s] = rotate(head, k, root_frame[s, 2])
        root_u[s] = rotate(head, k, root_frame[s, 3])


@ti.func
def solve_inextensibility(s, n, inv_mass: ti.template(), x: ti.template(), dx: ti.template(),
                          diag: ti.template(), upper: ti.template(), rhs: ti.template()):
    """One fast-projection iteration: (grad C M^-1 grad C^T) lambda = C (tridiagonal, assembled
    in diag/upper/rhs by the residual pass), x -= M^-1 grad C^T lambda; the correction is added
    to the step's displacement dx too (see strand_velocities)."""
    thomas_solve(s, 0, n - 2, diag, upper, rhs)
    # node i moves by 2 w_i (lambda_i e^i - lambda_{i-1} e^{i-1}), the edges taken before the
    # move: e^i still reads the old x_i and x_{i+1}, e^{i-1} is kept from the last pass
    e_before = vec3(0.0)
    for i in range(n):
        move = vec3(0.0)
        e = vec3(0.0)
        if i + 1 < n:
            e = x[s, i + 1] - x[s, i]
            move += rhs[s, i] * e
        if i > 0:
            move -= rhs[s, i - 1] * e_before
        move *= 2.0 * inv_mass[s, i]
        x[s, i] += move
        dx[s, i] += move
        e_before = e


@ti.func
def strand_project(s, tol, max_iterations, pins: ti.template(), node_count: ti.template(),
                   inv_mass: ti.template(), rest_length: ti.template(), x: ti.template(),
                   dx: ti.template(), diag: ti.template(), upper: ti.template(), rhs: ti.template(),
                   contacts: ti.template(),
                   x_prev: ti.template(), head: ti.template(), now, prev, n_analytic,
                   kinds: ti.template(), geometry: ti.template(), params: ti.template(),
                   use_mesh: ti.template(), sdf: ti.template(), sdf_meta: ti.template(),
                   use_touch: ti.template(), tools: ti.template(), tool_points: ti.template(),
                   tool_now, tool_prev):
    """Fast projection (Goldenthal et al. 2007) of C_j = |e^j|^2 - |ebar^j|^2 = 0 on every free
    edge, alternating with the contact pushes (Gauss-Seidel), until max_j |C_j| / |ebar^j|^2 <
    tol after contacts, max_iterations, or a stall (an iteration removing less than 10 % of a
    residual already below STALL_BELOW: the precision's rounding floor; far from satisfied, slow
    progress is the nonlinear start of Gauss-Newton and it keeps going). Held nodes (the root,
    pins) have infinite mass (inv_mass 0); an edge with both nodes held (a
    clip) is prescribed: its row is the identity with a zero right-hand side, outside the
    residual; with pins the diagonal is damped (HELD_DAMPING). Returns (iterations, final
    residual)."""
    n = node_count[s]
    it = 0
    res = 0.0
    previous = 0.0
    while True:
        if ti.static(contacts):
            strand_collide(s, node_count, inv_mass, x, x_prev, dx, head, now, prev, n_analytic, kinds,
                           geometry, params, use_mesh, sdf, sdf_meta, use_touch, tools, tool_points,
                           tool_now, tool_prev)
        previous = res
        res = 0.0
        for j in range(n - 1):
            e = x[s, j + 1] - x[s, j]
            w = inv_mass[s, j] + inv_mass[s, j + 1]
            rhs[s, j] = 0.0
            diag[s, j] = 1.0
            if w > 0.0:
                l2 = rest_length[s, j] * rest_length[s, j]
                c = e.dot(e) - l2
                res = ti.max(res, ti.abs(c) / l2)
                rhs[s, j] = c
                diag[s, j] = 4.0 * e.dot(e) * w
                if ti.static(pins):
                    diag[s, j] *= 1.0 + HELD_DAMPING
            if j + 1 < n - 1:
                upper[s, j] = -4.0 * inv_mass[s, j + 1] * e.dot(x[s, j + 2] - x[s, j + 1])
        if res < tol or it >= max_iterations or (it >= 1 and res < STALL_BELOW and res > 0.9 * previous):
            break
        solve_inextensibility(s, n, inv_mass, x, dx, diag, upper, rhs)
        it += 1
    return it, res


@ti.func
def strand_velocities(s, inv_h, max_speed, node_count: ti.template(), inv_mass: ti.template(),
                      x: ti.template(), x_prev: ti.template(), dx: ti.template(), v: ti.template()):
    """v = (x - x_prev) / h, read for free nodes from the step's accumulated displacement dx:
    x itself is rounded to its coordinates' precision at every update, and in float32 with small
    substeps (eps |x| / h ~ mm/s at 1 mm segments) that rounding, read back as velocity, would
    heat the hair (docs/model.md, "Velocities"). Held nodes take the difference of positions.
    Returns 1 if a node is non-finite or faster than max_speed, else 0."""
    bad = 0
    for i in range(node_count[s]):
        vel = dx[s, i] * inv_h
        if inv_mass[s, i] == 0.0:
            vel = (x[s, i] - x_prev[s, i]) * inv_h
        v[s, i] = vel
        # written so that NaN, which fails every comparison, counts as bad
        if not (vel.dot(vel) <= max_speed * max_speed):
            bad = 1
    return bad


@ti.func
def record_projection(s, counters: ti.template(), residuals: ti.template(), it, res, tol, max_iterations):
    """Running maxima of iterations and final residual; counts of steps that ended above tol
    at the iteration cap, or stalled at the rounding floor."""
    counters[s, PROJ_IT] = ti.max(counters[s, PROJ_IT], it)
    residuals[s, 0] = ti.max(residuals[s, 0], res)
    if res >= tol:
        if it >= max_iterations:
            counters[s, PROJ_CAP] += 1
        else:
            counters[s, PROJ_STALL] += 1


@ti.func
def strand_twist(s, twist_mode: ti.template(), clamp: ti.template(), tol, max_iterations,
                 node_count: ti.template(), bishop_u: ti.template(), bishop_v: ti.template(),
                 kb: ti.template(), theta: ti.template(), rest_kappa: ti.template(),
                 rest_twist: ti.template(), voronoi: ti.template(), stiffness: ti.template(),
                 m1: ti.template(), m2: ti.template(), a: ti.template(), b: ti.template(),
                 c: ti.template(), counters: ti.template(), residuals: ti.template()):
    """The twist update of strand s (kmoch or quasistatic); material frames follow. Kmoch's rule
    needs an elliptic section: round strands solve their twist exactly. Returns 1 if the solve
    failed (iteration cap, or stalled far from equilibrium), else 0."""
    failed = 0
    if ti.static(twist_mode != 0):
        exact = 1
        if ti.static(twist_mode == 1):
            if stiffness[s].x != stiffness[s].y:
                exact = 0
        if exact:
            it, res, how = strand_twist_quasistatic(s, clamp, node_count, bishop_u, bishop_v, kb,
                                                    theta, rest_kappa, rest_twist, voronoi,
                                                    stiffness, tol, max_iterations, a, b, c)
            counters[s, TWIST_IT] = ti.max(counters[s, TWIST_IT], it)
            residuals[s, 1] = ti.max(residuals[s, 1], res)
            if how == CAPPED:
                counters[s, TWIST_CAP] += 1
                failed = 1
            if how == STALLED:
                counters[s, TWIST_STALL] += 1
                if res > TWIST_FAILED_ABOVE:
                    failed = 1
        elif ti.static(twist_mode == 1):
            counters[s, TWIST_SWITCH] += strand_twist_kmoch(s, clamp, node_count, bishop_u, bishop_v,
                                                            kb, theta, rest_kappa, rest_twist,
                                                            voronoi, stiffness, a)
        strand_material_frames(s, node_count, theta, bishop_u, bishop_v, m1, m2)
    return failed


# ---- the fused driver -------------------------------------------------------------------------

@ti.kernel
def advance_strands(
        n_steps: int, h: float, t0: float, drag: float, max_speed: float, projection_tol: float,
        projection_iterations: int, twist_tol: float, twist_iterations: int, n_analytic: int,
        external: ti.template(), wind_field: ti.template(), twist_mode: ti.template(),
        user: ti.template(), moving_head: ti.template(), contacts: ti.template(),
        use_mesh: ti.template(), touch: ti.template(), pins: ti.template(), root_mode: ti.template(),
        pin_f0: float, pin_df: float, pin_mode: Ints2, pin_start: Vec3s2, pin_end: Vec3s2,
        node_count: Ints1, mass: Scalars2, inv_mass: Scalars2, rest_length: Scalars2,
        voronoi: Scalars2, stiffness: Vec4s1, rest_kappa: Vec4s2, rest_twist: Scalars2,
        root_frame: Vec3s2, head: Vec3s2, loads: Vec3s1, gusts: Vec3s1, modes: Vec3s2,
        user_force: Vec3s2, kinds: Ints1, geometry: Vec3s2, params: Vec4s1, sdf: Scalars3,
        sdf_meta: Vec3s1, tools: Vec4s1, tool_points: Vec3s2,
        x: Vec3s2, v: Vec3s2, x_prev: Vec3s2, dx: Vec3s2, force: Vec3s2, theta: Scalars2,
        bishop_u: Vec3s2, bishop_v: Vec3s2, m1: Vec3s2, m2: Vec3s2, kb: Vec3s2, root_t: Vec3s1,
        root_u: Vec3s1, scratch_a: Scalars2, scratch_b: Scalars2, scratch_c: Scalars2,
        counters: Ints2, residuals: Scalars2):
    """n_steps steps of h [s] from time t0 for every strand (head poses as in the module doc;
    tool_points[k] are the tools at the start of step k, always per step; pinned nodes at
    pin_f0 + (k + 1) pin_df of the way from pin_start to pin_end after step k). counters[s, BAD] =
    the first step where strand s went non-finite or too fast (that strand stops there), -1 if
    none. One thread per strand."""
    for s in range(x.shape[0]):
        counters[s, BAD] = -1
        for k in range(n_steps):
            now = 1
            prev = 0
            if ti.static(moving_head):
                now = k + 1
                prev = k
            elif k > 0:
                prev = 1
            strand_elastic_forces(s, ti.static(root_mode == 0), x, node_count, kb, m1, m2, root_t, root_u,
                                  rest_kappa, voronoi, stiffness, force)
            if ti.static(twist_mode == 1):
                strand_kmoch_forces(s, ti.static(root_mode == 0), x, node_count, bishop_u, bishop_v, kb,
                                    theta, root_t, rest_kappa, rest_twist, voronoi, stiffness, force)
            if ti.static(external or touch):
                strand_external_forces(s, t0 + k * h, drag, wind_field, touch, node_count, mass,
                                       voronoi, x, v, loads, gusts, modes, tools, tool_points, k, force)
            if ti.static(user):
                strand_add_forces(s, node_count, user_force, force)
            strand_symplectic_euler(s, h, node_count, inv_mass, force, v, x, x_prev, dx)
            strand_place_root(s, head, now, root_frame, x, root_t, root_u, root_mode)
            if ti.static(pins):
                strand_place_pins(s, ti.min(1.0, pin_f0 + (k + 1) * pin_df), node_count, pin_mode,
                                  pin_start, pin_end, head, now, x)
            it, res = strand_project(s, projection_tol, projection_iterations, pins, node_count,
                                     inv_mass, rest_length, x, dx, scratch_a, scratch_b, scratch_c, contacts,
                                     x_prev, head, now, prev, n_analytic, kinds, geometry, params,
                                     use_mesh, sdf, sdf_meta, touch, tools, tool_points, k + 1, k)
            record_projection(s, counters, residuals, it, res, projection_tol, projection_iterations)
            bad = strand_velocities(s, 1.0 / h, max_speed, node_count, inv_mass, x, x_prev, dx, v)
            if not (res <= FAILED_ABOVE):
                bad = 1
            strand_frames(s, ti.static(root_mode == 0), x, node_count, root_t, root_u, theta, bishop_u,
                          bishop_v, m1, m2, kb)
            if ti.static(root_mode == 1):
                strand_carry_root_frame(s, x, root_t, root_u)
            if strand_twist(s, twist_mode, ti.static(root_mode == 0), twist_tol, twist_iterations, node_count,
                            bishop_u, bishop_v, kb, theta, rest_kappa, rest_twist, voronoi,
                            stiffness, m1, m2, scratch_a, scratch_b, scratch_c, counters, residuals):
                bad = 1
            if bad:
                counters[s, BAD] = k
                break


def compiled_variants() -> list[dict]:
    """The stage flags of every compiled instance of the fused kernel in this process: a stage
    whose flag is False in every instance was never compiled (nor run). Reads Taichi's
    template-instance table."""
    mapper = advance_strands._primal.mapper
    names = [a.name for a in mapper.arguments]
    flags = ("external", "wind_field", "twist_mode", "user", "moving_head", "contacts", "use_mesh", "touch",
             "pins", "root_mode")
    return [{f: key[names.index(f)] for f in flags} for key in mapper.mapping]


def _common_args(model, state, control, plan: StepPlan):
    md = model
    return (md.node_count, md.mass, md.inv_mass, md.rest_length, md.voronoi, md.stiffness,
            md.rest_kappa, md.rest_twist, md.root_frame)


def _pin_args(state, pins):
    """(pins flag, f0, df, mode, start, end): the pin arrays of `pins` = (mode, start, end, f0,
    df), or unused placeholders when no pin is held."""
    if pins is None:
        return (False, 0.0, 0.0, state.counters, state.dx, state.dx)
    mode, start, end, f0, df = pins
    return (True, f0, df, mode, start, end)


def advance(model, state, control, plan: StepPlan, h: float, n_steps: int, moving_head: bool,
            pins=None) -> None:
    """Run n_steps steps of h in one launch; counters[:, BAD] holds each strand's first bad step.
    pins: None, or (pin_mode, pin_start, pin_end, f0, df): after step k pinned nodes are
    min(1, f0 + (k + 1) df) of the way from start to end (see pins.py)."""
    st, c = state, control
    user = c.user_force is not None
    use_pins, f0, df, *pin_arrays = _pin_args(state, pins)
    advance_strands(
        n_steps, h, c.time, c.drag, c.max_speed, plan.projection_tol, plan.projection_iterations,
        plan.twist_tol, plan.twist_iterations, plan.n_analytic,
        plan.external_forces, plan.wind_field, TWIST_CODES[plan.twist], user, moving_head,
        plan.contacts, plan.mesh, plan.touch, use_pins, plan.root_mode, f0, df, *pin_arrays,
        *_common_args(model, state, control, plan), c.head, c.loads, c.gusts, c.modes,
        c.user_force if user else st.force, c.kinds, c.geometry, c.params, c.sdf, c.sdf_meta,
        c.tools, c.tool_points, st.x, st.v, st.x_prev, st.dx, st.force, st.theta, st.bishop_u,
        st.bishop_v, st.m1, st.m2, st.kb, st.root_t, st.root_u, *st.scratch_edge, st.counters,
        st.residuals)


# ---- one kernel per stage (benchmark breakdown; hair-hair interaction) ----------------------

@ti.kernel
def external_and_user_forces(t: float, drag: float, external: ti.template(), wind_field: ti.template(),
                             touch: ti.template(), user: ti.template(), node_count: Ints1,
                             mass: Scalars2, voronoi: Scalars2, x: Vec3s2, v: Vec3s2, loads: Vec3s1,
                             gusts: Vec3s1, modes: Vec3s2, tools: Vec4s1, tool_points: Vec3s2,
                             user_force: Vec3s2, force: Vec3s2):
    for s in range(force.shape[0]):
        if ti.static(external or touch):
            strand_external_forces(s, t, drag, wind_field, touch, node_count, mass, voronoi, x, v,
                                   loads, gusts, modes, tools, tool_points, 0, force)
        if ti.static(user):
            strand_add_forces(s, node_count, user_force, force)


@ti.kernel
def integrate(h: float, pins: ti.template(), root_mode: ti.template(), pin_f0: float, pin_df: float,
              pin_mode: Ints2, pin_start: Vec3s2, pin_end: Vec3s2, node_count: Ints1,
              inv_mass: Scalars2, force: Vec3s2, head: Vec3s2, root_frame: Vec3s2, v: Vec3s2, x: Vec3s2,
              x_prev: Vec3s2, dx: Vec3s2, root_t: Vec3s1, root_u: Vec3s1):
    """Symplectic Euler, then the root nodes onto head pose 1 and pinned nodes pin_f0 + pin_df
    of the way to their end targets. One thread per strand."""
    for s in range(x.shape[0]):
        strand_symplectic_euler(s, h, node_count, inv_mass, force, v, x, x_prev, dx)
        strand_place_root(s, head, 1, root_frame, x, root_t, root_u, root_mode)
        if ti.static(pins):
            strand_place_pins(s, ti.min(1.0, pin_f0 + pin_df), node_count, pin_mode, pin_start,
                              pin_end, head, 1, x)


@ti.kernel
def project_constraints(tol: float, max_iterations: int, n_analytic: int, contacts: ti.template(),
                        pins: ti.template(), use_mesh: ti.template(), touch: ti.template(), node_count: Ints1,
                        inv_mass: Scalars2, rest_length: Scalars2, head: Vec3s2, kinds: Ints1,
                        geometry: Vec3s2, params: Vec4s1, sdf: Scalars3, sdf_meta: Vec3s1,
                        tools: Vec4s1, tool_points: Vec3s2, x: Vec3s2, x_prev: Vec3s2, dx: Vec3s2,
                        diag: Scalars2, upper: Scalars2, rhs: Scalars2, counters: Ints2,
                        residuals: Scalars2):
    """strand_project for every strand (head pose 0 -> 1), recorded; counters[s, BAD] = 0 where
    the projection failed (residual above FAILED_ABOVE), else -1. One thread per strand."""
    for s in range(x.shape[0]):
        it, res = strand_project(s, tol, max_iterations, pins, node_count, inv_mass, rest_length, x, dx,
                                 diag, upper, rhs, contacts, x_prev, head, 1, 0, n_analytic, kinds,
                                 geometry, params, use_mesh, sdf, sdf_meta, touch, tools, tool_points, 1, 0)
        record_projection(s, counters, residuals, it, res, tol, max_iterations)
        counters[s, BAD] = -1
        if not (res <= FAILED_ABOVE):
            counters[s, BAD] = 0


@ti.kernel
def velocities_frames_twist(inv_h: float, max_speed: float, twist_tol: float, twist_iterations: int,
                            twist_mode: ti.template(), root_mode: ti.template(), node_count: Ints1,
                            inv_mass: Scalars2, x: Vec3s2, x_prev: Vec3s2, dx: Vec3s2,
                            v: Vec3s2, root_t: Vec3s1, root_u: Vec3s1, theta: Scalars2,
                            bishop_u: Vec3s2, bishop_v: Vec3s2, m1: Vec3s2, m2: Vec3s2, kb: Vec3s2,
                            rest_kappa: Vec4s2, rest_twist: Scalars2, voronoi: Scalars2,
                            stiffness: Vec4s1, a: Scalars2, b: Scalars2, c: Scalars2,
                            counters: Ints2, residuals: Scalars2):
    """Velocities from positions (with the blow-up check), frames and the twist update."""
    for s in range(x.shape[0]):
        if strand_velocities(s, inv_h, max_speed, node_count, inv_mass, x, x_prev, dx, v):
            counters[s, BAD] = 0
        strand_frames(s, ti.static(root_mode == 0), x, node_count, root_t, root_u, theta, bishop_u, bishop_v,
                      m1, m2, kb)
        if ti.static(root_mode == 1):
            strand_carry_root_frame(s, x, root_t, root_u)
        if strand_twist(s, twist_mode, ti.static(root_mode == 0), twist_tol, twist_iterations, node_count,
                        bishop_u, bishop_v, kb, theta, rest_kappa, rest_twist, voronoi, stiffness,
                        m1, m2, a, b, c, counters, residuals):
            counters[s, BAD] = 0


@ti.kernel
def place_roots(head: Vec3s2, root_frame: Vec3s2, x: Vec3s2, root_t: Vec3s1, root_u: Vec3s1):
    """Root nodes and root reference frames at head pose 1. One thread per strand."""
    for s in range(x.shape[0]):
        strand_place_root(s, head, 1, root_frame, x, root_t, root_u, 0)


def kmoch_step(model, state, control, plan: StepPlan, h: float, timers=None, interaction=None,
               pins=None) -> None:
    """One step of h with one kernel per stage (head poses [prev, now] in control.head; pins as
    in `advance`, for this one step).
    `timers(name)` gives a context manager timing each stage (it must synchronise);
    `interaction(model, state, control, h)` adds hair-hair forces and velocity smoothing."""
    md, st, c = model, state, control
    stage = timers if timers is not None else (lambda name: nullcontext())
    user = c.user_force is not None
    with stage("forces"):
        total_elastic_forces(model, state, plan.twist)
        if plan.external_forces or plan.touch or user:
            external_and_user_forces(c.time, c.drag, plan.external_forces, plan.wind_field, plan.touch,
                                     user, md.node_count, md.mass, md.voronoi, st.x, st.v, c.loads,
                                     c.gusts, c.modes, c.tools, c.tool_points,
                                     c.user_force if user else st.force, st.force)
    if interaction is not None:
        with stage("hair-hair"):
            interaction(model, state, control, h)
    with stage("integration"):
        use_pins, f0, df, *pin_arrays = _pin_args(st, pins)
        integrate(h, use_pins, plan.root_mode, f0, df, *pin_arrays, md.node_count, md.inv_mass,
                  st.force, c.head, md.root_frame, st.v, st.x, st.x_prev, st.dx, st.root_t, st.root_u)
    with stage("projection"):
        project_constraints(plan.projection_tol, plan.projection_iterations, plan.n_analytic,
                            plan.contacts, use_pins, plan.mesh, plan.touch, md.node_count, md.inv_mass,
                            md.rest_length, c.head, c.kinds, c.geometry, c.params, c.sdf, c.sdf_meta,
                            c.tools, c.tool_points, st.x, st.x_prev, st.dx, *st.scratch_edge,
                            st.counters, st.residuals)
    with stage("frames + twist"):
        velocities_frames_twist(1.0 / h, c.max_speed, plan.twist_tol, plan.twist_iterations,
                                TWIST_CODES[plan.twist], plan.root_mode, md.node_count, md.inv_mass, st.x,
                                st.x_prev, st.dx, st.v, st.root_t, st.root_u, st.theta, st.bishop_u,
                                st.bishop_v, st.m1, st.m2, st.kb, md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness,
                                *st.scratch_edge, st.counters, st.residuals)


@ti.kernel
def update_twist_kernel(twist_tol: float, twist_iterations: int, twist_mode: ti.template(),
                        clamp: ti.template(), node_count: Ints1, theta: Scalars2, bishop_u: Vec3s2, bishop_v: Vec3s2,
                        m1: Vec3s2, m2: Vec3s2, kb: Vec3s2, rest_kappa: Vec4s2, rest_twist: Scalars2,
                        voronoi: Scalars2, stiffness: Vec4s1, a: Scalars2, b: Scalars2, c: Scalars2,
                        counters: Ints2, residuals: Scalars2):
    """The twist stage alone; counters[s, BAD] = 0 where it failed, else -1."""
    for s in range(theta.shape[0]):
        counters[s, BAD] = -1
        if strand_twist(s, twist_mode, clamp, twist_tol, twist_iterations, node_count, bishop_u,
                        bishop_v, kb, theta, rest_kappa, rest_twist, voronoi, stiffness, m1, m2, a,
                        b, c, counters, residuals):
            counters[s, BAD] = 0


def total_elastic_forces(model, state, twist: str) -> None:
    """state.force = the elastic force [S, N] N: minus the gradient at fixed angles, plus, under
    Kmoch's rule, the term from the angles' dependence on the centreline (elliptic strands)."""
    md, st = model, state
    elastic_forces(md.clamp, st.x, md.node_count, st.kb, st.m1, st.m2, st.root_t, st.root_u,
                   md.rest_kappa, md.voronoi, md.stiffness, st.force)
    if twist == "kmoch":
        kmoch_forces(md.clamp, st.x, md.node_count, st.bishop_u, st.bishop_v, st.kb, st.theta,
                     st.root_t, md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness, st.force)


def run_twist_update(model, state, plan: StepPlan):
    """The twist stage alone (no-op for "none"); material frames follow the new angles."""
    md, st = model, state
    if plan.twist != "none":
        update_twist_kernel(plan.twist_tol, plan.twist_iterations, TWIST_CODES[plan.twist],
                            md.clamp, md.node_count, st.theta, st.bishop_u, st.bishop_v, st.m1, st.m2, st.kb,
                            md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness, *st.scratch_edge,
                            st.counters, st.residuals)


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
