"""What a Simulator records and restores: its solver report (`stats`), checkpoints, and the
snapshot it rolls back to when a step blows up (`SimulationDiverged` with the likely cause).
A mixin of `simulator.Simulator`: it reads the simulator's state, counters, clock and plan."""

import math

import numpy as np

from ..rods import arrays
from ..rods.state import COUNTERS
from .checkpoint import load_state, save_state
from .stability import SimulationDiverged, likely_cause
from .step.plan import STALL_BELOW, TWIST_FAILED_ABOVE


class Records:
    """Simulator methods: stats, save_state / load_state, and the rollback on blow-up."""

    def _take_snapshot(self):
        st = self.state
        if self._snapshot is None:
            self._snapshot = {name: arrays.like(getattr(st, name))
                              for name in ("x", "v", "theta", "root_t", "root_u")}
        for name, copy in self._snapshot.items():
            copy.copy_from(getattr(st, name))
        self._snapshot_clock = (self._substep, self.steps_taken, self._head, self._clock_offset)

    def _diverged(self, h, bad_step):
        bad = np.flatnonzero(bad_step >= 0)
        first = bad[np.argmin(bad_step[bad])]
        counters = self.state.counters.to_numpy()
        cap_hits = int(counters[:, COUNTERS["projection_cap_hits"]].sum())
        t = (self._step_index() + bad_step[first] + 1) * h
        start = (self._snapshot_clock[3] + self._snapshot_clock[0]) * h
        step = self._snapshot_clock[1] + int(math.ceil((t - start) / self.dt - 1e-9))
        for name, copy in self._snapshot.items():
            getattr(self.state, name).copy_from(copy)
        self._history_h = None
        self._substep, self.steps_taken, self._head, self._clock_offset = self._snapshot_clock
        self._head_prev = self._head
        self._orient_roots()
        self.update_frames()
        residual = float(self.state.residuals.to_numpy()[first, 0])
        cause = likely_cause(h, self.stable_dt, cap_hits, self.control.max_speed, residual,
                             implicit=self.integrator == "implicit")
        twist_residual = float(self.state.residuals.to_numpy()[first, 1])
        # the kernel's rule (step.strand_twist): a cap, or a stall above TWIST_FAILED_ABOVE
        if counters[first, COUNTERS["twist_cap_hits"]] or (
                counters[first, COUNTERS["twist_stalls"]] and twist_residual > TWIST_FAILED_ABOVE):
            cause = (f"the twist solve of strand {first} did not converge (scaled residual "
                     f"{twist_residual:.3g} after up to {self.twist_iterations} "
                     f"iterations): its forces would not be the energy's gradient; raise "
                     f"twist_iterations or twist_tol")
        raise SimulationDiverged(
            f"simulation diverged at step {step} (t = {t:.4g} s): strand {first} "
            f"({len(bad)} strand(s) in all) went non-finite, faster than {self.control.max_speed:g} m/s, "
            f"out of its inextensibility constraints or out of twist equilibrium; "
            f"likely cause: {cause}. State rolled back to t = {self.time:.4g} s.",
            step=step, strand=int(first))

    def save_state(self, path, extra=None) -> None:
        """Write the dynamic state to `path` (.npz) atomically; see checkpoint.save_state."""
        save_state(self, path, extra)

    def load_state(self, path) -> None:
        """Restore a state written by `save_state` for this same groom; see checkpoint.load_state."""
        load_state(self, path)

    def stats(self, reset: bool = False) -> dict:
        """Solver report since the last reset: time, steps, dt and substeps (and the strands'
        mean share of them), the stability bound,
        projection iterations (max, and mean over strand-steps), its final residual (max), how many strand-steps ended above
        projection_tol at the iteration cap (projection_cap_hits) or stalled (projection_stalls:
        an iteration removed under 10 % of a residual already below projection_stall_below,
        1e-3: the rounding floor in float32, or contacts pushing nodes back against the edge
        lengths in any precision), the twist solve's iterations and residual, and with
        strand_contact the deepest overlap [m] a step's last contact pass found
        (strand_contact_depth_max)."""
        counters = self.state.counters.to_numpy()
        residuals = self.state.residuals.to_numpy()
        report = {
            "time": self.time, "steps": self.steps_taken, "dt": self.dt, "integrator": self.integrator,
            "projection": self.plan.projection, "extensible": self.plan.extensible, "strain": self.plan.strain,
            "substeps": self.substeps,
            # each strand's substeps per step, mean over strands (less than substeps where strands
            # step within their own bounds: Simulator.strand_substeps)
            "strand_substeps_mean": (float(self.substeps) if self.strand_substeps is None
                                     else float(self.strand_substeps.mean())),
            "substep_dt": self.dt / self.substeps, "stable_dt": float(self.stable_dt),
            "projection_tol": self.plan.projection_tol,
            "projection_iterations_max": int(counters[:, COUNTERS["projection_iterations"]].max()),
            "projection_iterations_mean": (float(counters[:, COUNTERS["projection_iterations_sum"]].sum())
                                           / max(1, int(counters[:, COUNTERS["projections"]].sum()))),
            "projection_residual_max": float(residuals[:, 0].max()),
            "projection_cap_hits": int(counters[:, COUNTERS["projection_cap_hits"]].sum()),
            "projection_stalls": int(counters[:, COUNTERS["projection_stalls"]].sum()),
            "projection_stall_below": STALL_BELOW,
            "twist": self.twist,
        }
        if self.twist != "none":  # kmoch solves round strands exactly too
            report["twist_iterations_max"] = int(counters[:, COUNTERS["twist_iterations"]].max())
            report["twist_residual_max"] = float(residuals[:, 1].max())
            report["twist_cap_hits"] = int(counters[:, COUNTERS["twist_cap_hits"]].sum())
            report["twist_stalls"] = int(counters[:, COUNTERS["twist_stalls"]].sum())
        if self.twist == "kmoch":
            report["twist_branch_switches"] = int(counters[:, COUNTERS["twist_branch_switches"]].sum())
        if self.strand_contact is not None:
            fused = self._contact_grid.deepest_since_reset(reset)
            report["strand_contact_depth_max"] = max(self._contact.depth, fused)
        if reset:
            self._reset_counters()
            if self._contact is not None:
                self._contact.reset_depth()
        return report

    def _reset_counters(self):
        self.rods.reset_counters()
        self._strides_loaded = False  # the strides share the counters' array (rods/state.py)

