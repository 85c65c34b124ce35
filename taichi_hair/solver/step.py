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

import functools
from dataclasses import asdict, dataclass

import taichi as ti

from ..rods.arrays import (BlockMats3, BlockVecs2, Ints1, Ints2, Points2, Scalars1, Scalars2, Scalars3, Vec3s1, Vec3s2,
                           Vec3s3, Vec4s1, Vec4s2, edge, point, step_displacement, vec3)
from .collisions import head_poses, head_rotate, strand_collide, strand_reset_friction
from ..world.forces import air_velocity, grab_force
from ..rods.frames import strand_frames, strand_material_frames
from ..rods.linalg import block_pentadiagonal_solve, thomas_solve
from .implicit import (CORRECTION_TOL, MAX_CORRECTIONS, assemble_stiffness, clear_system, length_residual,
                       record_elastic_change, strand_implicit_assemble, strand_implicit_finish,
                       strand_implicit_velocities)
from .strand_contact import (DEPTH_MAX, DONE, MAX_PENETRATION, PAIRS, RESOLVE, STEP_VALUES, ContactGridArgs,
                             contact_pass, resolve_strand_contacts)
from .pins import HELD_DAMPING, strand_carry_root_frame, strand_hold_clip_twist, strand_place_pins
from ..rods.rod import elastic_forces, strand_elastic_forces
from ..rods.modes import Integrator, Projection, Root, Strain, Twist
from ..rods.state import COUNTERS, HIST_DX, HIST_ELASTIC, HIST_V
from ..rods.twist import (CAPPED, STALLED, kmoch_forces, strand_held_twist_forces, strand_kmoch_forces,
                          strand_twist_kmoch, strand_twist_quasistatic)

TWIST_NONE, TWIST_KMOCH = Twist.NONE.code, Twist.KMOCH.code  # StageFlags.twist_mode
# StageFlags.root_mode (docs/model.md, "The clamp at the root")
ROOT_CLAMPED, ROOT_PINNED, ROOT_EDGE, ROOT_FREE = (Root[k].code for k in ("CLAMPED", "PINNED", "EDGE", "FREE"))
STALL_BELOW = 1e-3  # a stall ends the projection only this close to satisfied (the rounding floor)
LENGTHS_AFTER_CONTACT = 3  # length-only iterations after a projection with contacts ends unsatisfied
FAILED_ABOVE = 1e-2  # a residual left above this (0.5 % strain) is a failed step, not a result
# SHAKE follows the start-of-step constraint gradient while each iteration at least halves the
# residual; slower than that (a head jump, a contact push) it switches to the current gradient
SHAKE_RATE = 0.5
# ... and while every edge stays within acos(SHAKE_TURN_COS) = 8 degrees of its start-of-step
# direction: SHAKE's chord matrix G0 M^-1 G0^T misjudges C's slope along G0 by cos(turn), and an
# edge a contact turned across (a rope piling onto itself) made it overshoot without bound
SHAKE_TURN_COS = 0.99
# ... and while no node has left its prediction x_prev + h v by more than SHAKE_MOVE x its
# predicted displacement h |v| + SHAKE_MOVE_FLOOR x its edge: a strand held taut (straight
# between two held nodes) has a SHAKE solution only far off, long moves along the nearly parallel
# edges that undo a small sag. There the step starts again from the prediction with the current
# gradient, i.e. it is the fast projection's step (docs/model.md "Time step", SHAKE)
SHAKE_MOVE = 2.0
SHAKE_MOVE_FLOOR = 1e-3
# a twist solve that stalled at the rounding floor above this scaled residual is a failed step
TWIST_FAILED_ABOVE = 1e-3
PROJ_IT, PROJ_CAP, PROJ_STALL, TWIST_IT, BAD, TWIST_CAP, TWIST_STALL, TWIST_SWITCH = (
    COUNTERS[k] for k in ("projection_iterations", "projection_cap_hits", "projection_stalls",
                          "twist_iterations", "bad_step", "twist_cap_hits", "twist_stalls",
                          "twist_branch_switches"))
PROJ_IT_SUM, PROJ_COUNT = COUNTERS["projection_iterations_sum"], COUNTERS["projections"]


@dataclass(frozen=True)
class StepPlan:
    """Which stages run (fixed when the simulator is built) and the solver tolerances: the
    solver's options (world/options.py SolverOptions) with what the scene brings."""

    external_forces: bool  # gravity, air drag or wind present
    wind_field: bool  # gusts or turbulence: air velocity varies in time and space
    twist: Twist
    n_analytic: int  # analytic colliders
    mesh: bool  # a distance-grid collider
    touch: bool  # hands or grab tools
    projection_tol: float
    projection_iterations: int
    twist_tol: float
    twist_iterations: int
    root: Root = Root.CLAMPED
    integrator: Integrator = Integrator.EXPLICIT
    projection: Projection = Projection.FAST  # explicit integrator
    extensible: bool = False  # edges stretch with axial stiffness EA (explicit integrator)
    strain: Strain = Strain.DER

    @classmethod
    def of(cls, solver, facts: dict, *, external_forces: bool, projection_tol: float, twist_tol: float):
        """The plan of `solver` (a SolverOptions resolved for its groom) in a scene whose control
        facts (control.build_control) say which colliders and tools there are."""
        return cls(external_forces=external_forces, wind_field=facts["wind_field"], twist=solver.twist,
                   n_analytic=facts["n_analytic"], mesh=facts["mesh"], touch=facts["touch"],
                   projection_tol=projection_tol, projection_iterations=solver.projection_iterations,
                   twist_tol=twist_tol, twist_iterations=solver.twist_iterations, root=solver.root,
                   integrator=solver.integrator, projection=solver.projection,
                   extensible=solver.extensible, strain=solver.strain)

    @property
    def pinned_root(self) -> bool:
        return self.root == Root.PINNED

    @property
    def carried_root_frame(self) -> bool:
        """The root edge's reference frame is carried in time, not by the head (pinned, free)."""
        return self.root in (Root.PINNED, Root.FREE)

    @property
    def root_mode(self) -> int:
        return Root.parse("root", self.root).code

    @property
    def contacts(self) -> bool:
        return self.n_analytic > 0 or self.mesh or self.touch


# ---- argument bundles --------------------------------------------------------------------------
# Every step kernel takes the same five bundles (Taichi argpacks of ndarrays) instead of loose
# arrays: what never changes in a run (ModelArgs), what each step changes (StateArgs), what
# drives it (DriveArgs: head poses, loads, wind tables, tools, user forces, pins), what it
# collides with (ContactArgs), and the launch's scalars (StepScalars: passed as plain numbers,
# since building a Taichi struct in Python costs about 0.2 ms, and gathered into the struct
# inside the kernel, where it is free). A bundle is built once per simulator (StepBundles):
# building one costs about what a launch does, passing a built one costs the same as passing
# its arrays one by one (measured in docs/architecture.md).

ModelArgs = ti.types.argpack(
    node_count=Ints1, mass=Scalars2, inv_mass=Scalars2, rest_length=Scalars2, voronoi=Scalars2,
    stiffness=Vec4s1, rest_kappa=Vec4s2, rest_twist=Scalars2, root_frame=Vec3s2)
StateArgs = ti.types.argpack(
    x=Points2, v=Vec3s2, x_prev=Points2, dx=Vec3s2, force=Vec3s2, theta=Scalars2, bishop_u=Vec3s2,
    bishop_v=Vec3s2, m1=Vec3s2, m2=Vec3s2, kb=Vec3s2, root_t=Vec3s1, root_u=Vec3s1,
    diag=Scalars2, upper=Scalars2, rhs=Scalars2, counters=Ints2, residuals=Scalars2, history=Vec3s3,
    tension=Scalars2, blocks=BlockMats3, block_rhs=BlockVecs2)
DriveArgs = ti.types.argpack(
    head=Vec3s2, loads=Vec3s1, gusts=Vec3s1, modes=Vec3s2, user_force=Vec3s2, tools=Vec4s1,
    tool_points=Vec3s2, pin_mode=Ints2, pin_start=Vec3s2, pin_end=Vec3s2, clip=Vec3s3)
ContactArgs = ti.types.argpack(kinds=Ints1, geometry=Vec3s2, params=Vec4s1, sdf=Scalars3, sdf_meta=Vec3s1)
StepScalars = ti.types.struct(
    h=float, k0=float, drag=float, max_speed=float, projection_tol=float, projection_iterations=ti.i32,
    twist_tol=float, twist_iterations=ti.i32, n_analytic=ti.i32, pin_f0=float, pin_df=float)


@dataclass(frozen=True)
class StageFlags:
    """The compile-time switches of the step kernels (passed as ti.template, so each distinct
    value compiles its own kernel once per process): a stage whose flag is off is neither
    compiled nor run. twist_mode: a Twist's code; root_mode: a Root's code; user: user forces;
    moving_head: one head pose per step (else [prev, now]); pins: pins or clips are held; clips:
    a clip holds twist or slides (pins.py); implicit: the implicit step (implicit.py) instead of
    symplectic Euler; shake: the projection's constraint forces along the start-of-step edges
    (strand_project); stretch: the edges are compliant constraints with axial stiffness EA
    (assemble_projection); rotation: the rotation strain measure (rods/rod.py)."""

    external: bool
    wind_field: bool
    twist_mode: int
    user: bool
    moving_head: bool
    contacts: bool
    mesh: bool
    touch: bool
    pins: bool
    root_mode: int
    implicit: bool = False
    clips: bool = False
    shake: bool = False
    stretch: bool = False
    rotation: bool = False


@functools.lru_cache(maxsize=256)
def stage_flags(plan: StepPlan, *, user: bool = False, moving_head: bool = False, pins: bool = False,
                clips: bool = False, **overrides) -> StageFlags:
    """The flags of `plan` for one launch."""
    flags = dict(external=plan.external_forces, wind_field=plan.wind_field, twist_mode=Twist.parse("twist", plan.twist).code,
                 user=user, moving_head=moving_head, contacts=plan.contacts, mesh=plan.mesh,
                 touch=plan.touch, pins=pins, root_mode=plan.root_mode,
                 implicit=plan.integrator == "implicit", clips=clips, shake=plan.projection == "shake",
                 stretch=plan.extensible, rotation=plan.strain == "rotation")
    flags.update(overrides)
    return StageFlags(**flags)


class StepBundles:
    """One simulator's kernel bundles, built once: model and state from the rods, contacts and
    drive from the control once `bind` gives it; the drive bundle is rebuilt only when user
    forces or pins first get their arrays."""

    def __init__(self, model, state):
        md, st = model, state
        self.model = ModelArgs(node_count=md.node_count, mass=md.mass, inv_mass=md.inv_mass,
                               rest_length=md.rest_length, voronoi=md.voronoi, stiffness=md.stiffness,
                               rest_kappa=md.rest_kappa, rest_twist=md.rest_twist, root_frame=md.root_frame)
        diag, upper, rhs = st.scratch_edge
        self.state = StateArgs(x=st.x, v=st.v, x_prev=st.x_prev, dx=st.dx, force=st.force, theta=st.theta,
                               bishop_u=st.bishop_u, bishop_v=st.bishop_v, m1=st.m1, m2=st.m2, kb=st.kb,
                               root_t=st.root_t, root_u=st.root_u, diag=diag, upper=upper, rhs=rhs,
                               counters=st.counters, residuals=st.residuals, history=st.history,
                               tension=st.tension, blocks=st.blocks, block_rhs=st.block_rhs)
        self._state, self._model, self._control, self.contacts = st, md, None, None
        self._drive_key, self._drive = None, None

    def bind(self, control) -> None:
        """Take the control arrays (control.Control) that drive the steps."""
        c = control
        self._control = c
        self.contacts = ContactArgs(kinds=c.kinds, geometry=c.geometry, params=c.params, sdf=c.sdf,
                                    sdf_meta=c.sdf_meta)
        self._drive_key = None

    def drive(self, pins=None):
        """The drive bundle; pins: None or the (mode, start, end, clip) arrays of the pin table
        (an unused flag's arrays are placeholders of the right type)."""
        st, c = self._state, self._control
        key = (id(c.user_force), None if pins is None else tuple(id(a) for a in pins))
        if key != self._drive_key:
            mode, start, end, clip = pins if pins is not None else (st.counters, st.dx, st.dx, st.history)
            self._drive = DriveArgs(head=c.head, loads=c.loads, gusts=c.gusts, modes=c.modes,
                                    user_force=c.user_force if c.user_force is not None else st.force,
                                    tools=c.tools, tool_points=c.tool_points, pin_mode=mode,
                                    pin_start=start, pin_end=end, clip=clip)
            self._drive_key = key
        return self._drive

    @property
    def rods(self):
        """(RodModel, RodState): the arrays the bundles hold."""
        return self._model, self._state

    def twist_drive(self, pins=None):
        """The drive bundle for the twist stage alone: `drive(pins)` once a control is bound,
        else placeholders of the right types (a RodSystem without a simulator has no clips)."""
        if self._control is not None:
            return self.drive(pins)
        st, md = self._state, self._model
        return DriveArgs(head=st.dx, loads=st.root_t, gusts=st.root_t, modes=st.dx, user_force=st.force,
                         tools=md.stiffness, tool_points=st.dx, pin_mode=st.counters, pin_start=st.dx,
                         pin_end=st.dx, clip=st.history)


def step_scalars(plan: StepPlan, control, h: float, pin_fraction=(0.0, 0.0)) -> tuple:
    """The launch's scalars, in StepScalars' field order: step h [s], the launch's first step index
    control.first_step (k0: time k0 h; a whole number, exact in float32 up to 2^24 steps); pins
    pin_fraction = (f0, df)."""
    return (h, float(control.first_step), control.drag, control.max_speed, plan.projection_tol,
            plan.projection_iterations, plan.twist_tol, plan.twist_iterations, plan.n_analytic,
            pin_fraction[0], pin_fraction[1])


# ---- per-strand helpers ------------------------------------------------------------------------


@ti.func
def strand_external_forces(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(),
                           dr: ti.template()):
    """force += m g - drag l_i (v - u_air) + grab springs; loads = (gravity [m/s^2], mean wind
    [m/s]); drag in N s/m per metre of strand; u_air varies in time and space with wind_field;
    grabs at the tools' positions at the start of step k."""
    t = (sc.k0 + k) * sc.h  # from the step's index, not a running sum: the same whatever the launches
    for i in range(md.node_count[s]):
        air = dr.loads[1]
        if ti.static(fl.wind_field):
            air = air_velocity(dr.loads[1], dr.gusts, dr.modes, t, point(st.x, s, i))
        f = md.mass[s, i] * dr.loads[0] - sc.drag * md.voronoi[s, i] * (st.v[s, i] - air)
        if ti.static(fl.touch):
            f += grab_force(dr.tools, dr.tool_points, k, point(st.x, s, i))
        st.force[s, i] += f


@ti.func
def strand_symplectic_euler(s, h, fl: ti.template(), md: ti.template(), st: ti.template(), dr: ti.template()):
    """v += h F / m, x_prev = x, x += h v for the free nodes (inv_mass > 0); dx = the step's
    displacement so far (h v, 0 on held nodes), which the projection and contacts add to. A
    slider's two nodes (the strand's last edge, pins.py) move together along its axis under the
    sum of their forces. An extensible strand's edge tensions start the step at zero
    (assemble_projection)."""
    n = md.node_count[s]
    if ti.static(fl.stretch):
        for j in range(n - 1):
            st.tension[s, j] = 0.0
    for i in range(n):
        st.x_prev[s, i] = st.x[s, i]
        st.dx[s, i] = vec3(0.0)
        if md.inv_mass[s, i] > 0.0:
            st.v[s, i] += h * md.inv_mass[s, i] * st.force[s, i]
            st.dx[s, i] = h * st.v[s, i]
            st.x[s, i] += st.dx[s, i]
    if ti.static(fl.clips):
        b = dr.clip[s, n - 2, 2]  # a / sqrt(pair mass), zero unless the last edge slides
        if b.dot(b) > 0.0:
            # v_a = v.a + h (F_c + F_c+1).a / m_pair, written in b = a / sqrt(m_pair): v_a a = speed b
            speed = st.v[s, n - 1].dot(b) / b.dot(b) + h * b.dot(st.force[s, n - 2] + st.force[s, n - 1])
            for i in ti.static(range(2)):
                st.dx[s, n - 2 + i] = h * speed * b
                st.x[s, n - 2 + i] += h * speed * b


@ti.func
def strand_place_root(s, head: ti.template(), k, root_frame: ti.template(), x: ti.template(),
                      root_t: ti.template(), root_u: ti.template(), root_mode: ti.template()):
    """The root node rides on head pose k: x_0 = R xbar_0 + t. A clamped root's frame (t, u), the
    clamp that node 0 bends and twists against and from which the Bishop frames start, turns
    with R; a pinned root's reference is carried in time instead (pins.strand_carry_root_frame)."""
    if ti.static(root_mode != ROOT_FREE):  # a free root rides on nothing
        for node in ti.static(range(2 if root_mode == ROOT_EDGE else 1)):  # "edge": the first edge rides too
            x[s, node] = head_rotate(head, k, root_frame[s, node]) + head[k, 3]
    if ti.static(root_mode != ROOT_PINNED and root_mode != ROOT_FREE):
        root_t[s] = head_rotate(head, k, root_frame[s, 2])
        root_u[s] = head_rotate(head, k, root_frame[s, 3])


@ti.func
def slider_vector(s, n, fl: ti.template(), dr: ti.template()):
    """b = a / sqrt(m_pair) of strand s's slider (its last edge), zero without one: the pair's
    inverse mass is b b^T (pins.py)."""
    b = vec3(0.0)
    if ti.static(fl.clips):
        b = dr.clip[s, n - 2, 2]
    return b


@ti.func
def constraint_edge(s, j, e, shake, fl: ti.template(), st: ti.template()):
    """Edge j's direction in the constraint gradient G, given its current vector e: its
    start-of-step vector under SHAKE while that converges (fl.shake and shake = 1), else e (the
    fast projection)."""
    g = e
    if ti.static(fl.shake):
        if shake:
            g = edge(st.x_prev, s, j, j + 1)
    return g


@ti.func
def solve_inextensibility(s, n, shake, h, fl: ti.template(), md: ti.template(), st: ti.template(),
                          dr: ti.template()):
    """One projection iteration: (G M^-1 G^T) dlambda = C(x) (tridiagonal, assembled in
    diag/upper/rhs by assemble_projection), x -= M^-1 G^T dlambda, G along constraint_edge;
    the correction is added to the step's displacement dx too (see strand_velocities). A
    slider's pair moves by -2 dlambda b (b . e) through the edge before it, along its axis only.
    An extensible edge's tension grows by the force 2 |e| dlambda / h^2 of this iteration."""
    thomas_solve(s, 0, n - 2, st.diag, st.upper, st.rhs)
    if ti.static(fl.stretch):
        for j in range(n - 1):
            st.tension[s, j] += 2.0 * edge(st.x, s, j, j + 1).norm() * st.rhs[s, j] / (h * h)
    slide = vec3(0.0)
    if ti.static(fl.clips):
        b = slider_vector(s, n, fl, dr)
        if b.dot(b) > 0.0 and n >= 3:
            slide = -2.0 * st.rhs[s, n - 3] * b * b.dot(
                constraint_edge(s, n - 3, edge(st.x, s, n - 3, n - 2), shake, fl, st))
    # node i moves by 2 w_i (lambda_i e^i - lambda_{i-1} e^{i-1}), the edges taken before the
    # move: e^i still reads the old x_i and x_{i+1}, e^{i-1} is kept from the last pass
    e_before = vec3(0.0)
    for i in range(n):
        move = vec3(0.0)
        e = vec3(0.0)
        if i + 1 < n:
            e = constraint_edge(s, i, edge(st.x, s, i, i + 1), shake, fl, st)
            move += st.rhs[s, i] * e
        if i > 0:
            move -= st.rhs[s, i - 1] * e_before
        move *= 2.0 * md.inv_mass[s, i]
        st.x[s, i] += move
        st.dx[s, i] += move
        e_before = e
    if ti.static(fl.clips):
        for i in ti.static(range(2)):
            st.x[s, n - 2 + i] += slide
            st.dx[s, n - 2 + i] += slide


@ti.func
def assemble_projection(s, n, shake, h, fl: ti.template(), md: ti.template(), st: ti.template(),
                        dr: ti.template(), restart=0):
    """The projection's tridiagonal system G M^-1 G^T (diag, upper) and right-hand side C(x)
    (rhs), G along constraint_edge. An edge with both nodes held (a clip) is prescribed: its row
    is the identity with a zero right-hand side, outside the residual; with pins the diagonal is
    damped (HELD_DAMPING). An extensible strand (fl.stretch) makes each edge a compliant
    constraint (XPBD): diag + alpha_j / h^2 and C_j - alpha_j / h^2 Lambda_j, with Lambda_j =
    h^2 T_j / (2 |e|) the multiplier of the tension T_j [N] the step has applied so far
    (st.tension) and alpha_j = 2 |ebar| |e| (|e| + |ebar|) / EA, so that at convergence
    T_j = EA (|e| - |ebar|) / |ebar| exactly (docs/model.md, "Extensible strands"). Returns
    (max_j of that residual / |ebar^j|^2 over the free edges, 1 if an edge has turned past
    SHAKE_TURN_COS from its G direction, 2 if (under SHAKE, with restart) a node has left its
    prediction by more than SHAKE_MOVE, else 0)."""
    res = 0.0
    turned = 0
    b = slider_vector(s, n, fl, dr)
    for j in range(n - 1):
        e = edge(st.x, s, j, j + 1)
        g = constraint_edge(s, j, e, shake, fl, st)
        w = md.inv_mass[s, j] + md.inv_mass[s, j + 1]
        slide = 0.0  # the slider's share (b . g)^2 of the edge before it
        if ti.static(fl.clips):
            if j == n - 3:
                slide = b.dot(g) * b.dot(g)
        st.rhs[s, j] = 0.0
        st.diag[s, j] = 1.0
        if w > 0.0 or slide > 0.0:
            l2 = md.rest_length[s, j] * md.rest_length[s, j]
            c = e.dot(e) - l2
            st.diag[s, j] = 4.0 * (g.dot(g) * w + slide)
            if ti.static(fl.stretch):
                length = ti.sqrt(e.dot(e))
                rest = md.rest_length[s, j]
                stretch = rest * (length + rest) / md.stiffness[s].w  # alpha / (2 |e|) [m^2/N]
                c -= stretch * st.tension[s, j]
                st.diag[s, j] += 2.0 * length * stretch / (h * h)
            scaled = ti.abs(c) / l2
            if not scaled <= res:  # so that a NaN residual stays NaN and fails the tolerance
                res = scaled
            st.rhs[s, j] = c
            if ti.static(fl.shake):
                if e.dot(g) < SHAKE_TURN_COS * ti.sqrt(e.dot(e) * g.dot(g)):
                    turned = ti.max(turned, 1)
                if restart and md.inv_mass[s, j + 1] > 0.0:
                    predicted = h * st.v[s, j + 1]
                    moved = (st.dx[s, j + 1] - predicted).norm()
                    if not moved <= SHAKE_MOVE * predicted.norm() + SHAKE_MOVE_FLOOR * md.rest_length[s, j]:
                        turned = 2
            if ti.static(fl.pins):
                st.diag[s, j] *= 1.0 + HELD_DAMPING
        if j + 1 < n - 1:
            g_next = constraint_edge(s, j + 1, edge(st.x, s, j + 1, j + 2), shake, fl, st)
            st.upper[s, j] = -4.0 * md.inv_mass[s, j + 1] * g.dot(g_next)
    return res, turned


@ti.func
def untouched_prediction(s, n, h, md: ti.template(), st: ti.template()):
    """1 if every free node still sits at the step's prediction (dx = h v exactly, as
    strand_symplectic_euler left it), i.e. nothing has moved it since: this is the step's
    first projection (SHAKE may start again from there) and no collider has pushed it yet; 0
    after a strand contact pass or a collider has moved nodes."""
    untouched = 1
    for i in range(n):
        if md.inv_mass[s, i] > 0.0:
            if (st.dx[s, i] - h * st.v[s, i]).norm() > 0.0:
                untouched = 0
    return untouched


@ti.func
def restart_from_prediction(s, n, h, md: ti.template(), st: ti.template()):
    """Free nodes back at the step's prediction x_prev + h v (strand_symplectic_euler) with
    their displacement dx = h v: SHAKE's moves so far are undone."""
    for i in range(n):
        if md.inv_mass[s, i] > 0.0:
            st.dx[s, i] = h * st.v[s, i]
            st.x[s, i] = st.x_prev[s, i] + st.dx[s, i]


@ti.func
def strand_project(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(),
                   dr: ti.template(), co: ti.template()):
    """Projection of C_j = |e^j|^2 - |ebar^j|^2 = 0 on every free edge, alternating with the
    contact pushes (Gauss-Seidel): Gauss-Newton steps along the current gradient (the fast
    projection of Goldenthal et al. 2007), or with fl.shake along the start-of-step gradient
    (SHAKE) while each iteration at least halves the residual (SHAKE_RATE) and no edge has turned
    past SHAKE_TURN_COS from its start (else, a head jump or a contact, it switches to the
    current gradient), and while no node has left its prediction by more than SHAKE_MOVE (a
    taut stretch: the step then starts again from the prediction with the current gradient;
    only in a step's first projection of a scene without colliders, untouched_prediction);
    a strand that a collider pushes at the start of its step's first projection takes the fast
    projection for that step.
    Ends when max_j |C_j| / |ebar^j|^2 < projection_tol after contacts, at
    projection_iterations, or at a stall (an iteration removing less than 10 % of a residual
    already below STALL_BELOW: the precision's rounding floor; far from satisfied, slow progress
    is the nonlinear start of Gauss-Newton and it keeps going). Held nodes (the root, pins) have
    infinite mass (inv_mass 0). Returns (iterations, final residual)."""
    n = md.node_count[s]
    now, prev = head_poses(k, fl)
    it = 0
    res = 0.0
    previous = 0.0
    shake = 0
    restart = 0
    first = 0  # still at the prediction: the step's first projection
    if ti.static(fl.shake):
        shake = 1
        first = untouched_prediction(s, n, sc.h, md, st)
        if ti.static(not fl.contacts):
            restart = first
    if ti.static(fl.contacts):
        strand_reset_friction(s, st)  # friction's cone holds on the step's totals
    while True:
        if ti.static(fl.contacts):
            strand_collide(s, now, prev, k + 1, k, sc.n_analytic, fl, md, st, dr, co)
            if ti.static(fl.shake):
                if first:
                    # a collider pushed the strand at the step's start: this step is the fast
                    # projection's (SHAKE with the pushes gained energy on curls resting on a
                    # head)
                    if not untouched_prediction(s, n, sc.h, md, st):
                        shake = 0
                    first = 0
        previous = res
        res, turned = assemble_projection(s, n, shake, sc.h, fl, md, st, dr, restart * shake)
        switched = 0
        if ti.static(fl.shake):
            if shake and (turned or (it >= 1 and not res <= SHAKE_RATE * previous)):  # NaN too
                # slow progress here is SHAKE's, not the rounding floor: no stall
                shake = 0
                switched = 1
                if turned == 2:
                    restart_from_prediction(s, n, sc.h, md, st)
                res, _ = assemble_projection(s, n, shake, sc.h, fl, md, st, dr)
        if (res < sc.projection_tol or it >= sc.projection_iterations
                or (it >= 1 and not switched and res < STALL_BELOW and res > 0.9 * previous)):
            break
        solve_inextensibility(s, n, shake, sc.h, fl, md, st, dr)
        it += 1
    if ti.static(fl.contacts):
        # friction that holds puts its nodes back in every iteration, so the alternation can
        # stall with edges up to STALL_BELOW off; a few iterations of the lengths alone finish
        # them, moving held nodes by about that residual x their edge (docs/model.md,
        # "Collisions"). Not further off: that would pull nodes into the colliders.
        extra = 0
        while res >= sc.projection_tol and res < STALL_BELOW and extra < LENGTHS_AFTER_CONTACT:
            solve_inextensibility(s, n, shake, sc.h, fl, md, st, dr)
            res, _ = assemble_projection(s, n, shake, sc.h, fl, md, st, dr)
            extra += 1
            it += 1
    return it, res


@ti.func
def strand_velocities(s, sc, md: ti.template(), st: ti.template()):
    """v = (x - x_prev) / h, read for free nodes from the step's accumulated displacement dx (a
    difference kept in the precision's float, exact to the displacement's own precision; see
    docs/model.md, "Positions and velocities in float32"). Held nodes take the difference of
    positions (float64).
    Returns 1 if a node is non-finite or faster than max_speed, else 0."""
    bad = 0
    inv_h = 1.0 / sc.h
    for i in range(md.node_count[s]):
        vel = st.dx[s, i] * inv_h
        if md.inv_mass[s, i] == 0.0:
            vel = step_displacement(st.x, st.x_prev, s, i) * inv_h
        st.v[s, i] = vel
        # written so that NaN, which fails every comparison, counts as bad
        if not (vel.dot(vel) <= sc.max_speed * sc.max_speed):
            bad = 1
    return bad


@ti.func
def record_projection(s, st: ti.template(), it, res, tol, max_iterations):
    """Running maxima of iterations and final residual, the iterations' sum and the number of
    projections (their mean); counts of steps that ended above tol at the iteration cap, or
    stalled at the rounding floor."""
    st.counters[s, PROJ_IT] = ti.max(st.counters[s, PROJ_IT], it)
    st.counters[s, PROJ_IT_SUM] += it
    st.counters[s, PROJ_COUNT] += 1
    st.residuals[s, 0] = ti.max(st.residuals[s, 0], res)
    if res >= tol:
        if it >= max_iterations:
            st.counters[s, PROJ_CAP] += 1
        else:
            st.counters[s, PROJ_STALL] += 1


@ti.func
def strand_twist(s, fl: ti.template(), sc, md: ti.template(), st: ti.template(), dr: ti.template()):
    """The twist update of strand s (kmoch or quasistatic); material frames follow. Kmoch's rule
    needs an elliptic section: round strands solve their twist exactly. Edges held by
    twist-holding clips keep their angles (set by strand_hold_clip_twist; clips need the
    quasistatic mode). Returns 1 if the solve failed (iteration cap, or stalled far from
    equilibrium), else 0."""
    failed = 0
    clamp = ti.static(fl.root_mode == ROOT_CLAMPED)
    if ti.static(fl.twist_mode != TWIST_NONE):
        exact = 1
        if ti.static(fl.twist_mode == TWIST_KMOCH):
            if md.stiffness[s].x != md.stiffness[s].y:
                exact = 0
        if exact:
            it, res, how = strand_twist_quasistatic(s, clamp, ti.static(fl.root_mode == ROOT_FREE), fl.rotation,
                                                    md.node_count,
                                                    st.bishop_u, st.bishop_v, st.kb, st.theta,
                                                    md.rest_kappa, md.rest_twist, md.voronoi,
                                                    md.stiffness, sc.twist_tol, sc.twist_iterations,
                                                    st.diag, st.upper, st.rhs, fl.clips, dr.clip)
            st.counters[s, TWIST_IT] = ti.max(st.counters[s, TWIST_IT], it)
            st.residuals[s, 1] = ti.max(st.residuals[s, 1], res)
            if how == CAPPED:
                st.counters[s, TWIST_CAP] += 1
                failed = 1
            if how == STALLED:
                st.counters[s, TWIST_STALL] += 1
                if res > TWIST_FAILED_ABOVE:
                    failed = 1
        elif ti.static(fl.twist_mode == TWIST_KMOCH):
            st.counters[s, TWIST_SWITCH] += strand_twist_kmoch(s, clamp, md.node_count, st.bishop_u,
                                                               st.bishop_v, st.kb, st.theta, md.rest_kappa,
                                                               md.rest_twist, md.voronoi, md.stiffness, st.diag)
        strand_material_frames(s, md.node_count, st.theta, st.bishop_u, st.bishop_v, st.m1, st.m2)
    return failed


# ---- the stages of Kmoch's loop, in order ------------------------------------------------------
# Each takes (strand, step k of the launch, flags, scalars, model, state, drive, contacts) and
# returns 1 if the strand's step failed there. Both drivers run this one list.

@ti.func
def stage_forces(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(), dr: ti.template(),
                 co: ti.template()):
    """force = elastic (with Kmoch's rule's total-derivative term) + gravity, drag, wind, grabs
    + user forces."""
    clamp = ti.static(fl.root_mode == ROOT_CLAMPED)
    strand_elastic_forces(s, clamp, fl.rotation, st.x, md.node_count, st.kb, st.m1, st.m2, st.theta,
                          st.root_t, st.root_u, md.rest_kappa, md.voronoi, md.stiffness, st.force)
    if ti.static(fl.twist_mode == TWIST_KMOCH):
        strand_kmoch_forces(s, clamp, st.x, md.node_count, st.bishop_u, st.bishop_v, st.kb, st.theta,
                            st.root_t, md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness, st.force)
    if ti.static(fl.clips):
        strand_held_twist_forces(s, clamp, fl.rotation, st.x, md.node_count, st.bishop_u, st.bishop_v, st.kb, st.theta,
                                 st.root_t, md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness, dr.clip,
                                 st.force)
    if ti.static(fl.implicit):
        record_elastic_change(s, md, st)
    if ti.static(fl.external or fl.touch):
        strand_external_forces(s, k, fl, sc, md, st, dr)
    if ti.static(fl.user):
        for i in range(md.node_count[s]):
            st.force[s, i] += dr.user_force[s, i]
    return 0


@ti.func
def stage_integrate(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(), dr: ti.template(),
                    co: ti.template()):
    """Symplectic Euler (the explicit step);
    the root onto the head pose ending the step; pinned nodes min(1, pin_f0 + (k + 1) pin_df) of
    the way to their targets."""
    # the implicit step's integration runs in launches of its own (implicit_integrate)
    ti.static_assert(not fl.implicit, "the implicit step integrates in implicit_integrate")
    now, _ = head_poses(k, fl)
    strand_symplectic_euler(s, sc.h, fl, md, st, dr)
    place_root_and_pins(s, k, now, fl, sc, md, st, dr)
    return 0


@ti.func
def pin_fraction(k, sc):
    """How far through the step call the pins are after step k of the launch (pins.py)."""
    return ti.min(1.0, sc.pin_f0 + (k + 1) * sc.pin_df)


@ti.func
def place_root_and_pins(s, k, now, fl: ti.template(), sc, md: ti.template(), st: ti.template(), dr: ti.template()):
    """The root onto head pose `now`; pins min(1, pin_f0 + (k + 1) pin_df) of the way to their targets."""
    strand_place_root(s, dr.head, now, md.root_frame, st.x, st.root_t, st.root_u, fl.root_mode)
    if ti.static(fl.pins):
        strand_place_pins(s, pin_fraction(k, sc), fl.clips, md.node_count, dr.pin_mode, dr.pin_start,
                          dr.pin_end, dr.clip, dr.head, now, st.x)


@ti.func
def stage_project(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(), dr: ti.template(),
                  co: ti.template()):
    """Inextensibility and contacts (strand_project), recorded; fails above FAILED_ABOVE."""
    it, res = strand_project(s, k, fl, sc, md, st, dr, co)
    record_projection(s, st, it, res, sc.projection_tol, sc.projection_iterations)
    bad = 0
    if not (res <= FAILED_ABOVE):
        bad = 1
    return bad


@ti.func
def stage_frames_twist(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(), dr: ti.template(),
                       co: ti.template()):
    """Velocities (with the blow-up check), Bishop frames (a pinned root's reference carried in
    time), the twist update and the material frames."""
    bad = 0
    if ti.static(fl.implicit):
        bad = strand_implicit_velocities(s, sc, md, st)
    else:
        bad = strand_velocities(s, sc, md, st)
    strand_frames(s, ti.static(fl.root_mode == ROOT_CLAMPED), st.x, md.node_count, st.root_t, st.root_u, st.theta,
                  st.bishop_u, st.bishop_v, st.m1, st.m2, st.kb)
    if ti.static(fl.root_mode == ROOT_PINNED or fl.root_mode == ROOT_FREE):
        strand_carry_root_frame(s, st.x, st.root_t, st.root_u)
    if ti.static(fl.clips):
        now, _ = head_poses(k, fl)
        strand_hold_clip_twist(s, pin_fraction(k, sc), md.node_count, dr.pin_mode, dr.clip, dr.head, now,
                               st.bishop_u, st.bishop_v, st.theta)
    if strand_twist(s, fl, sc, md, st, dr):
        bad = 1
    return bad


STAGES = (("forces", stage_forces), ("integration", stage_integrate), ("projection", stage_project),
          ("frames + twist", stage_frames_twist))
STAGE_NAMES = tuple(name for name, _ in STAGES)
_STAGE_FUNCS = tuple(func for _, func in STAGES)
PROJECTION = STAGE_NAMES.index("projection")
INTEGRATION = STAGE_NAMES.index("integration")


# ---- the fused driver: many steps in one launch -------------------------------------------------

@ti.kernel
def advance_strands(n_steps: int, fl: ti.template(), h: float, k0: float, drag: float, max_speed: float,
                    projection_tol: float, projection_iterations: ti.i32, twist_tol: float,
                    twist_iterations: ti.i32, n_analytic: ti.i32, pin_f0: float, pin_df: float,
                    md: ModelArgs, st: StateArgs, dr: DriveArgs, co: ContactArgs):
    """n_steps steps of sc.h [s] from step index sc.k0 (time k0 h) for every strand (head poses as in the module
    doc; tool_points[k] are the tools at the start of step k). counters[s, BAD] = the first
    step where strand s failed (that strand stops there), -1 if none. One thread per strand."""
    sc = StepScalars(h=h, k0=k0, drag=drag, max_speed=max_speed, projection_tol=projection_tol,
                     projection_iterations=projection_iterations, twist_tol=twist_tol,
                     twist_iterations=twist_iterations, n_analytic=n_analytic, pin_f0=pin_f0, pin_df=pin_df)
    for s in range(st.x.shape[0]):
        st.counters[s, BAD] = -1
        for k in range(n_steps):
            bad = 0
            for stage in ti.static(_STAGE_FUNCS):
                bad += stage(s, k, fl, sc, md, st, dr, co)
            if bad:
                st.counters[s, BAD] = k
                break


def compiled_variants() -> list[dict]:
    """The stage flags of every compiled instance of the fused kernel in this process: a stage
    whose flag is False in every instance was never compiled (nor run). Reads Taichi's
    template-instance table."""
    keys = advance_strands._primal.mapper.mapping
    return [asdict(next(part for part in key if isinstance(part, StageFlags))) for key in keys]


def launch_flags(plan: StepPlan, control, pins, moving_head: bool = False):
    """(flags, pin arrays or None, (f0, df)) of a launch; pins: None, or (pin_mode, pin_start,
    pin_end, clip, f0, df, clips) as `advance` takes them."""
    arrays_, fraction, clips = (None, (0.0, 0.0), False) if pins is None else (pins[:4], pins[4:6], pins[6])
    flags = stage_flags(plan, user=control.user_force is not None, moving_head=moving_head,
                        pins=pins is not None, clips=clips)
    return flags, arrays_, fraction


def advance(bundles: StepBundles, plan: StepPlan, control, h: float, n_steps: int, moving_head: bool,
            pins=None) -> None:
    """Run n_steps steps of h in one launch; counters[:, BAD] holds each strand's first bad step.
    pins: None, or (pin_mode, pin_start, pin_end, clip, f0, df, clips): after step k pinned
    nodes are min(1, f0 + (k + 1) df) of the way from start to end (see pins.py); clips: a clip
    holds twist or slides."""
    flags, arrays_, fraction = launch_flags(plan, control, pins, moving_head)
    args = (flags, *step_scalars(plan, control, h, fraction), bundles.model, bundles.state,
            bundles.drive(arrays_), bundles.contacts)
    if flags.implicit:
        advance_implicit(bundles, args, n_steps)
        return
    advance_strands(n_steps, *args)


# ---- the implicit step's driver: its integration in launches of its own -------------------------
# A kernel's compile time grows faster than its size, and the implicit step's predictor and each
# of its length corrections hold a block assembly and a solve: one kernel holding them (and the
# other stages) compiled for minutes (docs/architecture.md, "Compile time"). So each round of
# the integration (the predictor, then up to MAX_CORRECTIONS corrections) is three launches:
# assemble, solve (implicit_solve: one kernel for every round, taking only the arrays it reads,
# since a launch costs ~15 us per array) and take the solution; a correction round runs only
# while some strand needs it.
ASSEMBLE, FINISH = range(2)


@ti.func
def implicit_round(s, k, j, node_count: ti.template(), inv_mass: ti.template(), rest_length: ti.template(),
                   x: ti.template(), counters: ti.template()):
    """1 if strand s takes round j of step k's implicit solves, else 0: it has not failed in an
    earlier step of the launch group, and round j is the predictor (0), the first correction (1)
    or a later one while an edge is off by more than CORRECTION_TOL (x is the same in a round's
    three launches: only the last moves it)."""
    bad = counters[s, BAD]
    take = 0
    if bad < 0 or bad == k:
        take = 1
        if j >= 2:
            if length_residual(s, node_count, inv_mass, rest_length, x) <= CORRECTION_TOL:
                take = 0
    return take


@ti.kernel
def implicit_part(part: ti.template(), correction: ti.template(), forces: ti.template(), k: ti.i32, j: ti.i32,
                  fl: ti.template(), h: float, k0: float, drag: float, max_speed: float, projection_tol: float,
                  projection_iterations: ti.i32, twist_tol: float, twist_iterations: ti.i32, n_analytic: ti.i32,
                  pin_f0: float, pin_df: float, md: ModelArgs, st: StateArgs, dr: DriveArgs, co: ContactArgs,
                  more: ti.template()):
    """The assembly (ASSEMBLE) or the solution's update (FINISH) of round j of step k's implicit
    integration (k as advance_strands' k) for every strand that takes it (implicit_round);
    correction: 0 the predictor (round 0), 1 a length correction (implicit.py); forces: the
    forces stage first (the predictor's ASSEMBLE of a fused step, where it also resets
    counters[s, BAD] at k = 0). The predictor's FINISH places the root and the pins; a
    correction's sets more[None] = 1 (a 0-d int field: Taichi caps a kernel's arguments at 64
    numbers and arrays) where an edge is still off by more than CORRECTION_TOL.
    One thread per strand."""
    sc = StepScalars(h=h, k0=k0, drag=drag, max_speed=max_speed, projection_tol=projection_tol,
                     projection_iterations=projection_iterations, twist_tol=twist_tol,
                     twist_iterations=twist_iterations, n_analytic=n_analytic, pin_f0=pin_f0, pin_df=pin_df)
    for s in range(st.x.shape[0]):
        if ti.static(forces):
            if k == 0:
                st.counters[s, BAD] = -1
        if implicit_round(s, k, j, md.node_count, md.inv_mass, md.rest_length, st.x, st.counters):
            if ti.static(part == ASSEMBLE):
                bad = 0
                if ti.static(forces):
                    bad += stage_forces(s, k, fl, sc, md, st, dr, co)
                strand_implicit_assemble(s, k, correction, sc.h, sc.drag,
                                         ti.static(fl.twist_mode != TWIST_NONE), fl, sc, md, st, dr, co)
                if bad:
                    st.counters[s, BAD] = k
            if ti.static(part == FINISH):
                strand_implicit_finish(s, correction, sc.h, md, st)
                if ti.static(correction == 0):
                    now, _ = head_poses(k, fl)
                    place_root_and_pins(s, k, now, fl, sc, md, st, dr)
                else:
                    if length_residual(s, md.node_count, md.inv_mass, md.rest_length, st.x) > CORRECTION_TOL:
                        more[None] = 1


@ti.kernel
def implicit_solve(k: ti.i32, j: ti.i32, node_count: Ints1, inv_mass: Scalars2, rest_length: Scalars2, x: Points2,
                   counters: Ints2, blocks: BlockMats3, block_rhs: BlockVecs2):
    """Solve the systems of round j of step k (implicit_part's ASSEMBLE) in place
    (linalg.block_pentadiagonal_solve); counters[s, BAD] = k where a factorisation failed (a
    non-finite state). One thread per strand."""
    for s in range(x.shape[0]):
        if implicit_round(s, k, j, node_count, inv_mass, rest_length, x, counters):
            if block_pentadiagonal_solve(s, node_count[s], blocks, block_rhs):
                counters[s, BAD] = k


@ti.kernel
def implicit_stages(first: ti.template(), last: ti.template(), k: ti.i32, fl: ti.template(), h: float, k0: float,
                    drag: float, max_speed: float, projection_tol: float, projection_iterations: ti.i32,
                    twist_tol: float, twist_iterations: ti.i32, n_analytic: ti.i32, pin_f0: float, pin_df: float,
                    md: ModelArgs, st: StateArgs, dr: DriveArgs, co: ContactArgs):
    """STAGES first..last-1 of step k (after the implicit integration) for every strand that has
    not failed in an earlier step; counters[s, BAD] = k where one fails. One thread per strand."""
    sc = StepScalars(h=h, k0=k0, drag=drag, max_speed=max_speed, projection_tol=projection_tol,
                     projection_iterations=projection_iterations, twist_tol=twist_tol,
                     twist_iterations=twist_iterations, n_analytic=n_analytic, pin_f0=pin_f0, pin_df=pin_df)
    for s in range(st.x.shape[0]):
        if st.counters[s, BAD] < 0 or st.counters[s, BAD] == k:
            bad = 0
            for stage in ti.static(_STAGE_FUNCS[first:last]):
                bad += stage(s, k, fl, sc, md, st, dr, co)
            if bad:
                st.counters[s, BAD] = k


_CORRECTION_FLAG = []


def correction_flag():
    """The 0-d int field implicit_part's FINISH raises when a strand needs another correction
    (made on first use: a field needs Taichi initialised)."""
    if not _CORRECTION_FLAG:
        _CORRECTION_FLAG.append(ti.field(ti.i32, shape=()))
    return _CORRECTION_FLAG[0]


def implicit_integrate(bundles: StepBundles, args: tuple, k: int, forces: bool) -> None:
    """Step k's implicit integration (with `forces`, the forces stage first): the predictor,
    then rounds of length corrections while a strand needs one (implicit_round), at most
    MAX_CORRECTIONS; args: implicit_part's from fl on."""
    model, state = bundles.rods
    arrays_ = (model.node_count, model.inv_mass, model.rest_length, state.x, state.counters, state.blocks,
               state.block_rhs)
    more = correction_flag()
    for j in range(MAX_CORRECTIONS + 1):
        if j >= 2 and not more[None]:
            break
        more[None] = 0
        correction = min(j, 1)
        implicit_part(ASSEMBLE, correction, forces and j == 0, k, j, *args, more)
        implicit_solve(k, j, *arrays_)
        implicit_part(FINISH, correction, False, k, j, *args, more)


def advance_implicit(bundles: StepBundles, args: tuple, n_steps: int) -> None:
    """n_steps implicit steps in launches (as advance_strands' steps); args: implicit_part's
    from fl on."""
    for k in range(n_steps):
        implicit_integrate(bundles, args, k, True)
        implicit_stages(INTEGRATION + 1, len(STAGES), k, *args)


def run_stage_range(bundles: StepBundles, first: int, last: int, args: tuple) -> None:
    """run_stages(first, last, *args), with the implicit step's integration (args[0].implicit)
    in launches of its own (implicit_integrate)."""
    if not (args[0].implicit and first <= INTEGRATION < last):
        run_stages(first, last, *args)
        return
    if first < INTEGRATION:
        run_stages(first, INTEGRATION, *args)
    implicit_integrate(bundles, args, 0, False)
    if INTEGRATION + 1 < last:
        run_stages(INTEGRATION + 1, last, *args)


def implicit_steps_with_strand_contact(bundles: StepBundles, plan: StepPlan, control, h: float, n_steps: int,
                                       grid, settings, moving_head: bool, pins=None) -> float:
    """n_steps implicit steps with strand contact, in launches: per step the forces, the
    integration and the projection, the contact passes (strand_contact.resolve_strand_contacts,
    each followed by the projection stage again), then velocities, frames and twist, as
    steps_with_strand_contact does in one launch. Returns the deepest depth [m] a step's last
    pass found (0 if none)."""
    flags, arrays_, fraction = launch_flags(plan, control, pins, moving_head)
    args = (flags, *step_scalars(plan, control, h, fraction), bundles.model, bundles.state,
            bundles.drive(arrays_), bundles.contacts)
    model, state = bundles.rods
    deepest = 0.0
    for k in range(n_steps):
        implicit_integrate(bundles, args, k, True)
        implicit_stages(PROJECTION, PROJECTION + 1, k, *args)
        depth = resolve_strand_contacts(grid, settings, model, state,
                                        lambda: implicit_stages(PROJECTION, PROJECTION + 1, k, *args))  # noqa: B023
        deepest = max(deepest, depth)
        implicit_stages(PROJECTION + 1, len(STAGES), k, *args)
    return deepest


# ---- the staged driver: stages in separate launches (per-stage timings; hair-hair interaction) --

@ti.kernel
def run_stages(first: ti.template(), last: ti.template(), fl: ti.template(), h: float, k0: float,
               drag: float, max_speed: float, projection_tol: float, projection_iterations: ti.i32,
               twist_tol: float, twist_iterations: ti.i32, n_analytic: ti.i32, pin_f0: float,
               pin_df: float, md: ModelArgs, st: StateArgs, dr: DriveArgs, co: ContactArgs):
    """Stages first..last-1 of STAGES for one step of every strand; counters[s, BAD] is reset
    by the launch that runs the first stage and set to 0 where a stage failed. One thread per
    strand."""
    sc = StepScalars(h=h, k0=k0, drag=drag, max_speed=max_speed, projection_tol=projection_tol,
                     projection_iterations=projection_iterations, twist_tol=twist_tol,
                     twist_iterations=twist_iterations, n_analytic=n_analytic, pin_f0=pin_f0, pin_df=pin_df)
    for s in range(st.x.shape[0]):
        if ti.static(first == 0):
            st.counters[s, BAD] = -1
        for stage in ti.static(_STAGE_FUNCS[first:last]):
            if stage(s, 0, fl, sc, md, st, dr, co):
                st.counters[s, BAD] = 0


@ti.kernel
def place_roots(head: Vec3s2, root_frame: Vec3s2, x: ti.types.ndarray(ndim=2), root_t: Vec3s1, root_u: Vec3s1):
    """Root nodes and root reference frames at head pose 1. One thread per strand."""
    for s in range(x.shape[0]):
        strand_place_root(s, head, 1, root_frame, x, root_t, root_u, 0)


def kmoch_step(bundles: StepBundles, plan: StepPlan, model, state, control, h: float, timers=None,
               interaction=None, pins=None, strand_contact=None) -> None:
    """One step of h (head poses [prev, now] in control.head; pins as in `advance`, for this one
    step), with `interaction(model, state, control, h)` adding hair-hair forces and velocity
    smoothing after the forces: two launches around it; and `strand_contact(project)` resolving
    strand-strand contacts after the projection, calling project() to run the projection stage
    again between its passes. With `timers(name)` (a context manager timing each stage; it must
    synchronise) every stage runs in a launch of its own."""
    flags, arrays_, fraction = launch_flags(plan, control, pins)
    args = (flags, *step_scalars(plan, control, h, fraction), bundles.model, bundles.state,
            bundles.drive(arrays_), bundles.contacts)
    if timers is None:
        first = 0
        if interaction is not None:
            run_stage_range(bundles, 0, 1, args)
            interaction(model, state, control, h)
            first = 1
        if strand_contact is None:
            run_stage_range(bundles, first, len(STAGES), args)
            return
        run_stage_range(bundles, first, PROJECTION + 1, args)
        strand_contact(lambda: run_stages(PROJECTION, PROJECTION + 1, *args))
        run_stage_range(bundles, PROJECTION + 1, len(STAGES), args)
        return
    for k, (name, _) in enumerate(STAGES):
        with timers(name):
            run_stage_range(bundles, k, k + 1, args)
        if k == 0 and interaction is not None:
            with timers("hair-hair"):
                interaction(model, state, control, h)
        if k == PROJECTION and strand_contact is not None:
            with timers("strand contact"):
                strand_contact(lambda: run_stages(PROJECTION, PROJECTION + 1, *args))


@ti.func
def read_step_values(params: ti.template()):
    """(StepScalars, self_contact, hash mask, friction, allowed depth [m], contact passes, steps)
    from params[STEP_VALUES:], as write_step_values put them."""
    v = ti.static(STEP_VALUES)
    sc = StepScalars(h=params[v + 0], k0=params[v + 1], drag=params[v + 2], max_speed=params[v + 3],
                     projection_tol=params[v + 4], projection_iterations=ti.cast(params[v + 5], ti.i32),
                     twist_tol=params[v + 6], twist_iterations=ti.cast(params[v + 7], ti.i32),
                     n_analytic=ti.cast(params[v + 8], ti.i32), pin_f0=params[v + 9], pin_df=params[v + 10])
    return (sc, ti.cast(params[v + 11], ti.i32), ti.cast(params[v + 12], ti.i32), params[v + 13], params[v + 14],
            ti.cast(params[v + 15], ti.i32), ti.cast(params[v + 16], ti.i32))


@ti.kernel
def advance_with_strand_contact(fl: ti.template(), with_friction: ti.template(), md: ModelArgs, st: StateArgs,
                                dr: DriveArgs, co: ContactArgs, cg: ContactGridArgs):
    """One step of h with strand-strand contact, in one launch when one contact pass is enough
    (head poses [prev, now]): the stages up to the projection per strand, a contact pass
    (strand_contact.contact_pass) and, if it found contacts, the projection stage again; if
    that pass found none, or all within the allowed depth, the step is done (grid_params[DONE])
    and velocities, frames and twist follow here; otherwise the caller runs further passes and
    the last stage (step_with_strand_contact). One pass, not a loop of them: every pass unrolled
    into the kernel multiplies its compile time. grid_params[DEPTH_MAX] keeps the deepest
    overlap a step's last pass found. counters[s, BAD] = 0 where a stage failed, else -1. Every
    loop is a top-level loop of the kernel (parallel), so the pass sees every strand's
    corrections. The scalars come in grid_params[STEP_VALUES:] (write_step_values): Taichi's cap
    of 64 arguments leaves no room for them."""
    sc, self_contact, mask, friction, allowed, _, _ = read_step_values(cg.grid_params)
    for s in range(st.x.shape[0]):
        st.counters[s, BAD] = -1
        for stage in ti.static(_STAGE_FUNCS[:PROJECTION + 1]):
            if stage(s, 0, fl, sc, md, st, dr, co):
                st.counters[s, BAD] = 0
    contact_pass(RESOLVE, with_friction, cg, md.node_count, st.x, st.x_prev, md.inv_mass, st.dx, self_contact,
                 mask, friction)
    cg.grid_params[DONE] = 1.0
    project = 0
    if cg.grid_counters[PAIRS] > 0:
        project = 1
        cg.grid_params[DEPTH_MAX] = ti.max(cg.grid_params[DEPTH_MAX], cg.grid_params[MAX_PENETRATION])
        if cg.grid_params[MAX_PENETRATION] > allowed:
            cg.grid_params[DONE] = 0.0
    for s in range(st.x.shape[0] * project):
        if stage_project(s, 0, fl, sc, md, st, dr, co):
            st.counters[s, BAD] = 0
    done = ti.cast(cg.grid_params[DONE], ti.i32)
    for s in range(st.x.shape[0] * done):
        if stage_frames_twist(s, 0, fl, sc, md, st, dr, co):
            st.counters[s, BAD] = 0


@ti.kernel
def advance_small_with_strand_contact(fl: ti.template(), with_friction: ti.template(), md: ModelArgs,
                                      st: StateArgs, dr: DriveArgs, co: ContactArgs, cg: ContactGridArgs):
    """n_steps steps of h with strand-strand contact in one launch, on one thread: for scenes
    small enough (SMALL_CONTACT_SCENE nodes) that the launches of a step per launch, not the
    work, would set the cost. Each step: the stages up to the projection for every strand, then
    up to `iterations` contact passes each followed by the projection stage, stopping after a
    pass that found nothing or nothing deeper than allowed, then velocities, frames and twist.
    Head poses and pins as in advance_strands (fl.moving_head: one pose per step). counters[s,
    BAD] = the step where a strand failed (the launch stops there), -1 if none. Scalars in
    grid_params[STEP_VALUES:] (write_step_values)."""
    sc, self_contact, mask, friction, allowed, iterations, n_steps = read_step_values(cg.grid_params)
    for s in range(st.x.shape[0]):
        st.counters[s, BAD] = -1
    ti.loop_config(serialize=True)
    for k in range(n_steps):
        failed = 0
        for s in range(st.x.shape[0]):
            for stage in ti.static(_STAGE_FUNCS[:PROJECTION + 1]):
                if stage(s, k, fl, sc, md, st, dr, co):
                    st.counters[s, BAD] = k
                    failed = 1
        depth = 0.0
        for _ in range(iterations):
            contact_pass(RESOLVE, with_friction, cg, md.node_count, st.x, st.x_prev, md.inv_mass, st.dx,
                         self_contact, mask, friction)
            if cg.grid_counters[PAIRS] == 0:
                break
            depth = cg.grid_params[MAX_PENETRATION]
            for s in range(st.x.shape[0]):
                if stage_project(s, k, fl, sc, md, st, dr, co):
                    st.counters[s, BAD] = k
                    failed = 1
            if depth <= allowed:
                break
        cg.grid_params[DEPTH_MAX] = ti.max(cg.grid_params[DEPTH_MAX], depth)
        for s in range(st.x.shape[0]):
            if stage_frames_twist(s, k, fl, sc, md, st, dr, co):
                st.counters[s, BAD] = k
                failed = 1
        if failed:
            break


@ti.kernel
def write_step_values(params: Scalars1, h: float, k0: float, drag: float, max_speed: float,
                      projection_tol: float, projection_iterations: ti.i32, twist_tol: float,
                      twist_iterations: ti.i32, n_analytic: ti.i32, pin_f0: float, pin_df: float,
                      self_contact: ti.i32, mask: ti.i32, friction: float, allowed: float, iterations: ti.i32,
                      n_steps: ti.i32):
    """params[STEP_VALUES:] = StepScalars' fields in order, then self_contact, the hash mask,
    friction, the allowed depth [m], the contact passes per step and the steps of the launch
    (the fused kernels read them)."""
    values = ti.Vector([h, k0, drag, max_speed, projection_tol, projection_iterations, twist_tol,
                        twist_iterations, n_analytic, pin_f0, pin_df, self_contact, mask, friction, allowed,
                        iterations, n_steps], dt=float)
    for i in ti.static(range(17)):
        params[STEP_VALUES + i] = values[i]


SMALL_CONTACT_SCENE = 4096  # nodes: up to here a launch runs many contact steps on one thread


def steps_with_strand_contact(bundles: StepBundles, plan: StepPlan, control, h: float, n_steps: int, grid,
                              settings, moving_head: bool, pins=None) -> None:
    """n_steps steps of h with strand contact in one launch on one thread
    (`advance_small_with_strand_contact`; a small scene: SMALL_CONTACT_SCENE); head poses and
    pins as in `advance`."""
    if plan.integrator == "implicit":
        depth = implicit_steps_with_strand_contact(bundles, plan, control, h, n_steps, grid, settings, moving_head,
                                                   pins)
        params = grid.params.to_numpy()
        params[DEPTH_MAX] = max(params[DEPTH_MAX], depth)
        grid.params.from_numpy(params)
        return
    flags, arrays_, fraction = launch_flags(plan, control, pins, moving_head)
    write_step_values(grid.params, *step_scalars(plan, control, h, fraction), int(settings.self_contact),
                      grid.T - 1, settings.friction, grid.allowed_depth(settings.tolerance), settings.iterations,
                      n_steps)
    advance_small_with_strand_contact(flags, settings.friction > 0.0, bundles.model, bundles.state,
                                      bundles.drive(arrays_), bundles.contacts, grid.args())


def step_with_strand_contact(bundles: StepBundles, plan: StepPlan, control, h: float, grid, settings,
                             pins=None) -> float:
    """One step of h with strand contact: `advance_with_strand_contact`, then, if its pass left
    contacts deeper than allowed, up to settings.iterations - 1 more passes (each with the
    projection stage) and the last stage, in launches of their own. grid a
    strand_contact.ContactGrid, settings its StrandContact; pins as in `advance`. Returns the
    depth [m] the last of those further passes found (0 if none ran)."""
    if plan.integrator == "implicit":
        return implicit_steps_with_strand_contact(bundles, plan, control, h, 1, grid, settings, False, pins)
    flags, arrays_, fraction = launch_flags(plan, control, pins)
    scalars = step_scalars(plan, control, h, fraction)
    write_step_values(grid.params, *scalars, int(settings.self_contact), grid.T - 1, settings.friction,
                      grid.allowed_depth(settings.tolerance), settings.iterations, 1)
    drive = bundles.drive(arrays_)
    advance_with_strand_contact(flags, settings.friction > 0.0, bundles.model, bundles.state, drive,
                                bundles.contacts, grid.args())
    if grid.params.to_numpy()[DONE] > 0.5:
        return 0.0
    args = (flags, *scalars, bundles.model, bundles.state, drive, bundles.contacts)
    model, state = bundles.rods
    depth = resolve_strand_contacts(grid, settings, model, state,
                                    lambda: run_stages(PROJECTION, PROJECTION + 1, *args),
                                    passes=settings.iterations - 1)
    run_stages(PROJECTION + 1, len(STAGES), *args)
    return depth


@ti.kernel
def clear_bad(counters: Ints2):
    for s in range(counters.shape[0]):
        counters[s, BAD] = -1


def project_once(bundles: StepBundles, plan: StepPlan, control, h: float = 1.0) -> None:
    """The projection stage alone, contacts on and pins off (head pose 0 -> 1): the initial
    contact solve."""
    flags = stage_flags(plan, contacts=True, pins=False, shake=False)
    clear_bad(bundles.state.counters)
    run_stages(PROJECTION, PROJECTION + 1, flags, *step_scalars(plan, control, h), bundles.model, bundles.state,
               bundles.drive(), bundles.contacts)


@ti.kernel
def update_twist_kernel(fl: ti.template(), twist_tol: float, twist_iterations: ti.i32, md: ModelArgs,
                        st: StateArgs, dr: DriveArgs):
    """The twist stage alone (twist-holding clips at their latest angles, head pose 1);
    counters[s, BAD] = 0 where it failed, else -1."""
    sc = StepScalars(h=1.0, k0=0.0, drag=0.0, max_speed=0.0, projection_tol=0.0, projection_iterations=0,
                     twist_tol=twist_tol, twist_iterations=twist_iterations, n_analytic=0, pin_f0=1.0,
                     pin_df=0.0)
    for s in range(st.theta.shape[0]):
        st.counters[s, BAD] = -1
        if ti.static(fl.clips):
            strand_hold_clip_twist(s, 1.0, md.node_count, dr.pin_mode, dr.clip, dr.head, 1, st.bishop_u,
                                   st.bishop_v, st.theta)
        if strand_twist(s, fl, sc, md, st, dr):
            st.counters[s, BAD] = 0


def total_elastic_forces(model, state, twist: str, rest_kappa=None) -> None:
    """state.force = the elastic force [S, N] N: minus the gradient at fixed angles, plus, under
    Kmoch's rule, the term from the angles' dependence on the centreline (elliptic strands).
    rest_kappa: rest curvatures to use instead of the model's (None: the model's)."""
    md, st = model, state
    kappa = md.rest_kappa if rest_kappa is None else rest_kappa
    elastic_forces(md.clamp, md.rotation, st.x, md.node_count, st.kb, st.m1, st.m2, st.theta, st.root_t,
                   st.root_u, kappa, md.voronoi, md.stiffness, st.force)
    if twist == "kmoch":
        kmoch_forces(md.clamp, st.x, md.node_count, st.bishop_u, st.bishop_v, st.kb, st.theta,
                     st.root_t, kappa, md.rest_twist, md.voronoi, md.stiffness, st.force)


def run_twist_update(bundles: StepBundles, twist: str, root: str, twist_tol: float, twist_iterations: int,
                     clip_arrays=None):
    """The twist stage alone (no-op for "none"); material frames follow the new angles.
    clip_arrays: the pin table's (mode, start, end, clip) when clips hold twist (else None)."""
    if twist == "none":
        return
    flags = StageFlags(external=False, wind_field=False, twist_mode=Twist.parse("twist", twist).code, user=False,
                       moving_head=False, contacts=False, mesh=False, touch=False,
                       pins=clip_arrays is not None, root_mode=Root.parse("root", root).code, clips=clip_arrays is not None,
                       rotation=bundles.rods[0].rotation)
    update_twist_kernel(flags, twist_tol, twist_iterations, bundles.model, bundles.state,
                        bundles.twist_drive(clip_arrays))


@ti.kernel
def strand_mechanical_energy(node_count: Ints1, mass: Scalars2, inv_mass: Scalars2, x: Points2,
                             v: Vec3s2, loads: Vec3s1, kinetic: Scalars1, potential: Scalars1):
    """kinetic[s] = sum 1/2 m |v|^2, potential[s] = -sum m g . x [J] over the free nodes (the root
    edge is driven by the head, not by forces). One thread per strand."""
    for s in range(x.shape[0]):
        k = 0.0
        p = 0.0
        for i in range(node_count[s]):
            if inv_mass[s, i] > 0.0:
                k += 0.5 * mass[s, i] * v[s, i].dot(v[s, i])
                p -= mass[s, i] * loads[0].dot(point(x, s, i))
        kinetic[s] = k
        potential[s] = p


@ti.kernel
def seed_history(h: float, node_count: Ints1, v: Vec3s2, history: Vec3s3, tension: Scalars2):
    """Start the implicit step's history as if each node had moved at its present velocity for
    one step of h [s]: v_prev = v, dx_prev = h v (BDF2's first step is then second order); no
    tension or earlier elastic force known yet (NaN)."""
    for s, i in ti.ndrange(v.shape[0], v.shape[1]):
        if i < node_count[s]:
            history[s, i, HIST_V] = v[s, i]
            history[s, i, HIST_DX] = h * v[s, i]
            history[s, i, HIST_ELASTIC] = vec3(ti.math.nan)
            if i < tension.shape[1]:
                tension[s, i] = 0.0


@ti.kernel
def stiffness_blocks(clamp: ti.template(), twist_free: ti.template(), rotation: ti.template(), md: ModelArgs,
                     st: StateArgs):
    """st.blocks = the implicit step's Gauss-Newton stiffness of every strand over the free
    nodes' positions [N/m] and the free edges' angles (implicit.assemble_stiffness; blocks as
    in linalg.block_pentadiagonal_solve) at the current frames. One thread per strand."""
    for s in range(st.x.shape[0]):
        clear_system(s, md.node_count[s], True, st)
        assemble_stiffness(s, clamp, twist_free, rotation, 1.0, md, st, 0)
