"""How a simulator's step is fitted: the step count that fills an interval (a video frame), the
substeps within the explicit stability bound, and each strand's own share of them
(docs/model.md, "Stability bound"). A mixin of `simulator.Simulator`: it reads the simulator's
dt, bound, integrator, pins and counters."""

import math

from ..rods.state import COUNTERS
from ..validation import real
from .control import MAX_STEPS_PER_LAUNCH
from .stability import strand_substeps, substeps_for


class StepFitting:
    """Simulator methods: fit_step and the substeps (and the strands' strides) it implies."""

    def fit_step(self, interval: float) -> int:
        """Take equal steps of at most dt that fill `interval` [s] (a video frame, say), as few
        strand steps in all as the explicit bound allows: sets dt to interval / count and returns
        the count. The fewest steps within both dt and the bound, one substep each (the implicit
        step: within dt alone); or, where strands keep strides of their own, the count whose
        steps, each strand substepped within its own bound, take the fewest strand steps.
        Substeps of a fixed dt would waste up to half the bound: 0.992 ms steps over a 0.96 ms
        bound run as two of 0.496 ms."""
        interval = real("interval", interval, "s", low=0.0, low_open=True)
        largest = self.dt if self.integrator == "implicit" else min(self.dt, self.stable_dt)
        count = max(1, math.ceil(interval / largest - 1e-9))
        if (self.integrator == "explicit" and self._strides_possible and not self._pins.active
                and self.bound.strands is not None):
            count = self._fewest_strand_steps(interval, count)
        self._set_dt(interval / count)
        self._history_h = None
        return count

    def _substeps(self, strict) -> int:
        """Substeps per step: the explicit step's bound sets them; the implicit step needs none.
        Where strands may keep strides of their own, strand s takes strand_substeps[s] of a step
        (a divisor of the substeps; stability.strand_substeps), each within its own bound."""
        self.strand_substeps, self._strides_loaded = None, False
        if self.integrator == "implicit":
            return 1
        substeps = substeps_for(self.dt, self.bound, strict, self.max_substeps)
        if substeps == 1 or not self._strides_possible or self._pins.active or self.bound.strands is None:
            return substeps  # pins are placed at every substep: every strand takes them all
        total, per_strand = strand_substeps(self.dt, self.bound.strands,
                                            min(self.max_substeps, MAX_STEPS_PER_LAUNCH))
        if total > MAX_STEPS_PER_LAUNCH or int(per_strand.min()) == total:
            return substeps  # a step must fit one launch; or every strand needs every substep
        self.strand_substeps = per_strand
        return total

    def _fewest_strand_steps(self, interval: float, most: int) -> int:
        """The step count from ceil(interval / dt) to `most` (one substep per step) whose steps
        take the fewest strand steps with each strand at its own substeps (strand_substeps);
        of equal ones, the fewest substeps. At most ~200 counts are tried, evenly spread."""
        strands = self.bound.strands
        largest = min(self.max_substeps, MAX_STEPS_PER_LAUNCH)
        best, best_cost = most, (most * len(strands), most)
        fewest = max(1, math.ceil(interval / self.dt - 1e-9))
        for count in range(fewest, most, max(1, (most - fewest) // 200)):
            total, per_strand = strand_substeps(interval / count, strands, largest)
            cost = (count * int(per_strand.sum()), count * total)
            if total <= MAX_STEPS_PER_LAUNCH and cost < best_cost:
                best, best_cost = count, cost
        return best

    def _load_strides(self) -> None:
        """Each strand's stride (substeps over its own) into counters' step_stride column."""
        counters = self.state.counters.to_numpy()
        counters[:, COUNTERS["step_stride"]] = self.substeps // self.strand_substeps
        self.state.counters.from_numpy(counters)
        self._strides_loaded = True
