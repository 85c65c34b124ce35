"""Launches of steps with strand-strand contact: the stages and a contact pass in one kernel."""

import taichi as ti

from ...rods.arrays import Scalars1
from ..strand_contact import (contact_pass, ContactGridArgs, DEPTH_MAX, DONE, MAX_PENETRATION, PAIRS,
                              RESOLVE, resolve_strand_contacts, STEP_VALUES, CONTACT_GRID_VALUES)
from .bundles import (ContactArgs, DriveArgs, launch_flags, ModelArgs, SCALAR_NAMES, ScalarArgs, StateArgs,
                      StepBundles, StepScalars)
from .fused import run_stages
from .plan import BAD, StepPlan
from ...rods.spread import spread_factor
from .stages import PROJECTION, stage_frames_twist, STAGE_FUNCS, stage_project, STAGES


# params[STEP_VALUES:] of a contact grid: the launch's scalars (bundles.SCALAR_NAMES), then the
# contact step's own values, each in the slot its name gives (write_step_values, read_step_values)
CONTACT_VALUES = ("self_contact", "mask", "friction", "allowed", "passes", "n_steps")
SLOT = {name: STEP_VALUES + k for k, name in enumerate(SCALAR_NAMES + CONTACT_VALUES)}
assert len(SLOT) == CONTACT_GRID_VALUES, "strand_contact.CONTACT_GRID_VALUES sizes the grid's params"


@ti.func
def read_step_values(params: ti.template()):
    """(StepScalars, self_contact, hash mask, friction, allowed depth [m], contact passes, steps)
    from params[STEP_VALUES:], each from its named slot (SLOT), as write_step_values put them."""
    sc = StepScalars(h=params[SLOT["h"]], k0=params[SLOT["k0"]], drag=params[SLOT["drag"]],
                     max_speed=params[SLOT["max_speed"]], projection_tol=params[SLOT["projection_tol"]],
                     projection_iterations=ti.cast(params[SLOT["projection_iterations"]], ti.i32),
                     twist_tol=params[SLOT["twist_tol"]],
                     twist_iterations=ti.cast(params[SLOT["twist_iterations"]], ti.i32),
                     n_analytic=ti.cast(params[SLOT["n_analytic"]], ti.i32), pin_f0=params[SLOT["pin_f0"]],
                     pin_df=params[SLOT["pin_df"]], stride=1)
    return (sc, ti.cast(params[SLOT["self_contact"]], ti.i32), ti.cast(params[SLOT["mask"]], ti.i32),
            params[SLOT["friction"]], params[SLOT["allowed"]], ti.cast(params[SLOT["passes"]], ti.i32),
            ti.cast(params[SLOT["n_steps"]], ti.i32))


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
    factor = spread_factor(st.x.shape[0])
    for t in range(st.x.shape[0] * factor):
        if t % factor == 0:
            s = t // factor
            st.counters[s, BAD] = -1
            for stage in ti.static(STAGE_FUNCS[:PROJECTION + 1]):
                if stage(s, 0, fl, sc, md, st, dr, co):
                    st.counters[s, BAD] = 0
    contact_pass(RESOLVE, with_friction, cg, md.node_count, st.x, st.x_prev, md.inv_mass, st.dx, self_contact,
                 mask, friction, cg.hits)  # (the record array: unused when resolving)
    cg.grid_params[DONE] = 1.0
    project = 0
    if cg.grid_counters[PAIRS] > 0:
        project = 1
        cg.grid_params[DEPTH_MAX] = ti.max(cg.grid_params[DEPTH_MAX], cg.grid_params[MAX_PENETRATION])
        if cg.grid_params[MAX_PENETRATION] > allowed:
            cg.grid_params[DONE] = 0.0
    for t in range(st.x.shape[0] * factor * project):
        if t % factor == 0:
            s = t // factor
            if stage_project(s, 0, fl, sc, md, st, dr, co):
                st.counters[s, BAD] = 0
    done = ti.cast(cg.grid_params[DONE], ti.i32)
    for t in range(st.x.shape[0] * factor * done):
        if t % factor == 0:
            s = t // factor
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
            for stage in ti.static(STAGE_FUNCS[:PROJECTION]):
                if stage(s, k, fl, sc, md, st, dr, co):
                    st.counters[s, BAD] = k
                    failed = 1
        # the projection, then up to `iterations` contact passes each followed by the
        # projection again, until a pass finds nothing (no projection after it) or nothing
        # deeper than allowed: written as one loop so that the projection is inlined once
        # (this kernel is one serial task, one LLVM function, whose compile time grows
        # faster than its length)
        depth, passes = 0.0, 0
        while True:
            for s in range(st.x.shape[0]):
                if stage_project(s, k, fl, sc, md, st, dr, co):
                    st.counters[s, BAD] = k
                    failed = 1
            if passes == iterations or (passes > 0 and depth <= allowed):
                break
            contact_pass(RESOLVE, with_friction, cg, md.node_count, st.x, st.x_prev, md.inv_mass, st.dx,
                         self_contact, mask, friction, cg.hits)
            passes += 1
            if cg.grid_counters[PAIRS] == 0:
                break
            depth = cg.grid_params[MAX_PENETRATION]
        cg.grid_params[DEPTH_MAX] = ti.max(cg.grid_params[DEPTH_MAX], depth)
        for s in range(st.x.shape[0]):
            if stage_frames_twist(s, k, fl, sc, md, st, dr, co):
                st.counters[s, BAD] = k
                failed = 1
        if failed:
            break


@ti.kernel
def write_step_values(params: Scalars1, sa: ScalarArgs, self_contact: ti.i32, mask: ti.i32, friction: float,
                      allowed: float, iterations: ti.i32, n_steps: ti.i32):
    """Each value into its named slot of params (SLOT): the launch's scalars (sa), then
    self_contact, the hash mask, friction, the allowed depth [m], the contact passes per step
    and the steps of the launch (the fused contact kernels read them, read_step_values)."""
    params[SLOT["h"]] = sa.h
    params[SLOT["k0"]] = sa.k0
    params[SLOT["drag"]] = sa.drag
    params[SLOT["max_speed"]] = sa.max_speed
    params[SLOT["projection_tol"]] = sa.projection_tol
    params[SLOT["projection_iterations"]] = sa.projection_iterations
    params[SLOT["twist_tol"]] = sa.twist_tol
    params[SLOT["twist_iterations"]] = sa.twist_iterations
    params[SLOT["n_analytic"]] = sa.n_analytic
    params[SLOT["pin_f0"]] = sa.pin_f0
    params[SLOT["pin_df"]] = sa.pin_df
    params[SLOT["self_contact"]] = self_contact
    params[SLOT["mask"]] = mask
    params[SLOT["friction"]] = friction
    params[SLOT["allowed"]] = allowed
    params[SLOT["passes"]] = iterations
    params[SLOT["n_steps"]] = n_steps


SMALL_CONTACT_SCENE = 4096  # nodes: up to here a launch runs many contact steps on one thread


def steps_with_strand_contact(bundles: StepBundles, plan: StepPlan, control, h: float, n_steps: int, grid,
                              settings, moving_head: bool, pins=None) -> None:
    """n_steps steps of h with strand contact in one launch on one thread
    (`advance_small_with_strand_contact`; a small scene: SMALL_CONTACT_SCENE); head poses and
    pins as in `advance`."""
    flags, arrays_, fraction = launch_flags(plan, control, pins, moving_head)
    write_step_values(grid.params, bundles.scalars(plan, control, h, fraction), int(settings.self_contact),
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
    flags, arrays_, fraction = launch_flags(plan, control, pins)
    scalars = bundles.scalars(plan, control, h, fraction)
    write_step_values(grid.params, scalars, int(settings.self_contact), grid.T - 1, settings.friction,
                      grid.allowed_depth(settings.tolerance), settings.iterations, 1)
    drive = bundles.drive(arrays_)
    advance_with_strand_contact(flags, settings.friction > 0.0, bundles.model, bundles.state, drive,
                                bundles.contacts, grid.args())
    if grid.params.to_numpy()[DONE] > 0.5:
        return 0.0
    args = (flags, scalars, bundles.model, bundles.state, drive, bundles.contacts)
    model, state = bundles.rods
    depth = resolve_strand_contacts(grid, settings, model, state,
                                    lambda: run_stages(PROJECTION, PROJECTION + 1, *args),
                                    passes=settings.iterations - 1)
    run_stages(PROJECTION + 1, len(STAGES), *args)
    return depth
