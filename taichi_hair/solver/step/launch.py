"""The drivers' entry points: a launch of the fused step (explicit or implicit), one staged step,
one projection."""

from .bundles import launch_flags, StepBundles
from .fused import advance_strands, clear_bad, run_stages
from .implicit_launches import advance_implicit, run_stage_range
from .plan import stage_flags, StepPlan
from .stages import PROJECTION, STAGES


def advance(bundles: StepBundles, plan: StepPlan, control, h: float, n_steps: int, moving_head: bool,
            pins=None, strides: bool = False) -> None:
    """Run n_steps steps of h in one launch; counters[:, BAD] holds each strand's first bad step.
    pins: None, or (pin_mode, pin_start, pin_end, clip, f0, df, clips): after step k pinned
    nodes are min(1, f0 + (k + 1) df) of the way from start to end (see pins.py); clips: a clip
    holds twist or slides. strides: each strand steps counters[s, step_stride] x h at a time
    (explicit step, no pins; n_steps a multiple of every stride)."""
    flags, arrays_, fraction = launch_flags(plan, control, pins, moving_head, strides)
    args = (flags, bundles.scalars(plan, control, h, fraction), bundles.model, bundles.state,
            bundles.drive(arrays_), bundles.contacts)
    if flags.implicit:
        advance_implicit(bundles, args, n_steps)
        return
    advance_strands(n_steps, *args)


def staged_step(bundles: StepBundles, plan: StepPlan, model, state, control, h: float, timers=None,
               interaction=None, pins=None, strand_contact=None) -> None:
    """One step of h (head poses [prev, now] in control.head; pins as in `advance`, for this one
    step), with `interaction(model, state, control, h)` adding hair-hair forces and velocity
    smoothing after the forces: two launches around it; and `strand_contact(project)` resolving
    strand-strand contacts after the projection, calling project() to run the projection stage
    again between its passes. With `timers(name)` (a context manager timing each stage; it must
    synchronise) every stage runs in a launch of its own."""
    flags, arrays_, fraction = launch_flags(plan, control, pins)
    args = (flags, bundles.scalars(plan, control, h, fraction), bundles.model, bundles.state,
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


def project_once(bundles: StepBundles, plan: StepPlan, control, h: float = 1.0) -> None:
    """The projection stage alone, contacts on and pins off (head pose 0 -> 1): the initial
    contact solve."""
    flags = stage_flags(plan, contacts=True, pins=False, shake=False)
    clear_bad(bundles.state.counters)
    run_stages(PROJECTION, PROJECTION + 1, flags, bundles.scalars(plan, control, h), bundles.model, bundles.state,
               bundles.drive(), bundles.contacts)
