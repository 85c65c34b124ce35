"""Which stages a simulator runs and with what tolerances: StepPlan (from the solver's options), the
compile-time StageFlags of a launch, the thresholds that judge a step."""

import functools
from dataclasses import dataclass

from ...rods.modes import Integrator, Projection, Root, Strain, Twist
from ...rods.state import COUNTERS


TWIST_NONE, TWIST_KMOCH = Twist.NONE.code, Twist.KMOCH.code  # StageFlags.twist_mode


# StageFlags.root_mode (docs/model.md, "The clamp at the root")
ROOT_CLAMPED, ROOT_PINNED, ROOT_EDGE, ROOT_FREE = (Root[k].code for k in ("CLAMPED", "PINNED", "EDGE", "FREE"))


STALL_BELOW = 1e-3  # a stall ends the projection only this close to satisfied (the rounding floor)


FAILED_ABOVE = 1e-2  # a residual left above this (0.5 % strain) is a failed step, not a result


# a twist solve that stalled at the rounding floor above this scaled residual is a failed step
TWIST_FAILED_ABOVE = 1e-3


PROJ_IT, PROJ_CAP, PROJ_STALL, TWIST_IT, BAD, TWIST_CAP, TWIST_STALL, TWIST_SWITCH = (
    COUNTERS[k] for k in ("projection_iterations", "projection_cap_hits", "projection_stalls",
                          "twist_iterations", "bad_step", "twist_cap_hits", "twist_stalls",
                          "twist_branch_switches"))


PROJ_IT_SUM, PROJ_COUNT = COUNTERS["projection_iterations_sum"], COUNTERS["projections"]
STRIDE = COUNTERS["step_stride"]


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


@dataclass(frozen=True)
class StageFlags:
    """The compile-time switches of the step kernels (passed as ti.template, so each distinct
    value compiles its own kernel once per process): a stage whose flag is off is neither
    compiled nor run. twist_mode: a Twist's code; root_mode: a Root's code; user: user forces;
    moving_head: one head pose per step (else [prev, now]); pins: pins or clips are held; clips:
    a clip holds twist or slides (pins.py); implicit: the implicit step (implicit.py) instead of
    symplectic Euler; shake: the projection's constraint forces along the start-of-step edges
    (strand_project); stretch: the edges are compliant constraints with axial stiffness EA
    (assemble_projection); rotation: the rotation strain measure (rods/rod.py); strides: each
    strand steps at its own stride of launch steps (fused.advance_strands)."""

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
    strides: bool = False


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
