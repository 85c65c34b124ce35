"""How a Simulator launches its steps: one driver, chosen once when the simulator is built.

Every driver runs `count` steps of h of the same stages (solver/step/stages.py STAGES) and differs only
in how they are grouped into kernel launches:

- `FusedDriver`: many steps per launch, one thread per strand (`step.advance`): the default.
- `StagedDriver`: one step per call, the stages in launches of their own around the hair-hair
  interaction grid, which couples strands between stages; with timers, one launch per stage
  (the benchmark's per-stage profile).
- `StrandContactDriver`: strand-strand contact, a launch per step (`step.step_with_strand_contact`);
  in a scene of at most `SMALL_CONTACT_SCENE` nodes many steps per launch on one thread
  (`step.steps_with_strand_contact`), where launches would cost more than the work.
"""

from .control import MAX_STEPS_PER_LAUNCH
from .step.contact import SMALL_CONTACT_SCENE, step_with_strand_contact, steps_with_strand_contact
from .step.launch import advance, staged_step
from .strand_contact import resolve_strand_contacts


class FusedDriver:
    """Many steps per launch (`step.advance`)."""

    name = "fused"

    def __init__(self, bundles, plan, control):
        self.bundles, self.plan, self.control = bundles, plan, control

    strides = True  # strands may step at strides of their own (step.advance)

    def launch_size(self, remaining: int, unit: int = 1) -> int:
        """Steps the next launch takes of `remaining`: a multiple of `unit` (the steps a stride
        divides) where `remaining` is."""
        return min(remaining, max(unit, MAX_STEPS_PER_LAUNCH // unit * unit))

    def launch(self, h: float, count: int, moving_head: bool, pins, strides: bool = False) -> None:
        """`count` steps of h [s]; moving_head: one head pose per step loaded; pins and strides
        as `step.advance`."""
        advance(self.bundles, self.plan, self.control, h, count, moving_head, pins, strides)


class StagedDriver:
    """One step per launch group: the stages in kernels of their own, the hair-hair grid
    (`interaction`: an InteractionGrid or None) between the forces and the integration, strand
    contact (`contact`: a StrandContactDriver or None) between the projection and the
    velocities; `timers` (a callable name -> context manager that synchronises) times every stage."""

    name = "staged"
    strides = False

    def __init__(self, bundles, plan, control, interaction=None, contact=None, timers=None):
        self.bundles, self.plan, self.control = bundles, plan, control
        self.interaction, self.contact, self.timers = interaction, contact, timers

    def launch_size(self, remaining: int, unit: int = 1) -> int:
        return 1

    def launch(self, h: float, count: int, moving_head: bool, pins, strides: bool = False) -> None:
        model, state = self.bundles.rods
        staged_step(self.bundles, self.plan, model, state, self.control, h, self.timers,
                   self.interaction.stage if self.interaction is not None else None, pins,
                   self.contact.resolve if self.contact is not None else None)


class StrandContactDriver:
    """Strand-strand contact (`grid`: a strand_contact.ContactGrid, `settings`: its StrandContact):
    a launch per step, or many steps per launch on one thread in a small scene. `depth` is the
    deepest overlap [m] its extra contact passes found since `reset_depth`."""

    name = "strand contact"
    strides = False

    def __init__(self, bundles, plan, control, grid, settings, small_nodes: int = SMALL_CONTACT_SCENE):
        self.bundles, self.plan, self.control = bundles, plan, control
        self.grid, self.settings = grid, settings
        groom = bundles.rods[0].groom
        self.small = groom.n_strands * groom.max_nodes <= small_nodes
        self.depth = 0.0

    def reset_depth(self) -> None:
        self.depth = 0.0

    def launch_size(self, remaining: int, unit: int = 1) -> int:
        return min(remaining, MAX_STEPS_PER_LAUNCH) if self.small else 1

    def launch(self, h: float, count: int, moving_head: bool, pins, strides: bool = False) -> None:
        if self.small:
            steps_with_strand_contact(self.bundles, self.plan, self.control, h, count, self.grid,
                                      self.settings, moving_head, pins)
            return
        depth = step_with_strand_contact(self.bundles, self.plan, self.control, h, self.grid, self.settings, pins)
        self.depth = max(self.depth, depth)

    def resolve(self, project) -> None:
        """The contact passes of a staged step, `project()` running the projection between them."""
        model, state = self.bundles.rods
        self.depth = max(self.depth, resolve_strand_contacts(self.grid, self.settings, model, state, project))


def choose_driver(bundles, plan, control, interaction=None, contact_grid=None, strand_contact=None,
                  small_nodes: int = SMALL_CONTACT_SCENE):
    """The driver of a simulator: staged with the hair-hair grid (strand contact, if any, inside
    its steps), strand contact's own without it, fused otherwise."""
    contact = (None if strand_contact is None else
               StrandContactDriver(bundles, plan, control, contact_grid, strand_contact, small_nodes))
    if interaction is not None:
        return StagedDriver(bundles, plan, control, interaction, contact)
    return contact if contact is not None else FusedDriver(bundles, plan, control)
