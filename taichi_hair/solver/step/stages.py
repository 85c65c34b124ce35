"""Kmoch's loop: the per-strand stages of one time step h, in order (STAGES)."""

import taichi as ti

from ...rods.arrays import point, step_displacement, vec3
from ...rods.frames import strand_frames, strand_material_frames
from ...rods.rod import strand_elastic_forces
from ...rods.twist import CAPPED, STALLED, strand_twist_kmoch, strand_twist_quasistatic
from ...rods.twist_forces import strand_held_twist_forces, strand_kmoch_forces
from ...world.forces import air_velocity, grab_force, gusting_wind
from ..collisions import head_poses, head_rotate
from ..implicit import record_elastic_change, strand_implicit_velocities
from ..pins import strand_carry_root_frame, strand_hold_clip_twist, strand_place_pins
from .plan import (FAILED_ABOVE, ROOT_CLAMPED, ROOT_EDGE, ROOT_FREE, ROOT_PINNED, TWIST_CAP,
                   TWIST_FAILED_ABOVE, TWIST_IT, TWIST_KMOCH, TWIST_NONE, TWIST_STALL, TWIST_SWITCH)
from .projection import record_projection, strand_project


@ti.func
def strand_external_forces(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(),
                           dr: ti.template()):
    """force += m g - drag l_i (v - u_air) + grab springs; loads = (gravity [m/s^2], mean wind
    [m/s]); drag in N s/m per metre of strand; u_air varies in time and space with wind_field;
    grabs at the tools' positions at the start of step k."""
    t = (sc.k0 + k) * sc.h  # from the step's index, not a running sum: the same whatever the launches
    if ti.static(fl.strides):
        t = (sc.k0 + k) * (sc.h / sc.stride)  # in launch steps: the strand's step spans sc.stride
    wind = dr.loads[1]
    if ti.static(fl.wind_field):
        wind = gusting_wind(dr.loads[1], dr.gusts, t)
    for i in range(md.node_count[s]):
        air = wind
        if ti.static(fl.wind_field):
            air = air_velocity(wind, dr.modes, t, point(st.x, s, i))
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
                                                    md, st, sc.twist_tol, sc.twist_iterations, fl.clips, dr.clip)
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
            st.counters[s, TWIST_SWITCH] += strand_twist_kmoch(s, clamp, md, st, st.diag)
        strand_material_frames(s, md.node_count, st.theta, st.bishop_u, st.bishop_v, st.m1, st.m2)
    return failed


@ti.func
def stage_forces(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(), dr: ti.template(),
                 co: ti.template()):
    """force = elastic (with Kmoch's rule's total-derivative term) + gravity, drag, wind, grabs
    + user forces."""
    clamp = ti.static(fl.root_mode == ROOT_CLAMPED)
    strand_elastic_forces(s, clamp, fl.rotation, md, st)
    if ti.static(fl.twist_mode == TWIST_KMOCH):
        strand_kmoch_forces(s, clamp, md, st)
    if ti.static(fl.clips):
        strand_held_twist_forces(s, clamp, fl.rotation, md, st, dr.clip)
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
    now, _ = head_poses(k, fl, sc.stride)
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
        now, _ = head_poses(k, fl, sc.stride)
        strand_hold_clip_twist(s, pin_fraction(k, sc), md.node_count, dr.pin_mode, dr.clip, dr.head, now,
                               st.bishop_u, st.bishop_v, st.theta)
    if strand_twist(s, fl, sc, md, st, dr):
        bad = 1
    return bad


STAGES = (("forces", stage_forces), ("integration", stage_integrate), ("projection", stage_project),
          ("frames + twist", stage_frames_twist))


STAGE_NAMES = tuple(name for name, _ in STAGES)


STAGE_FUNCS = tuple(func for _, func in STAGES)


PROJECTION = STAGE_NAMES.index("projection")


INTEGRATION = STAGE_NAMES.index("integration")
