"""How a Simulator starts: the groom placed at the head's first pose, the roots a collider
holds reported, groomed nodes inside a collider moved out before the first step, and the
stability bound measured on (and tightened to) the shape the groom starts in. A mixin of
`simulator.Simulator`: it reads the simulator's rods, control, plan and bound."""

import warnings

import numpy as np

from ..rods.groom import Groom
from ..world.colliders import host_distance
from .checkpoint import pose_rows
from .collisions import root_keeps_collider
from .control import load_poses, load_tools
from .stability import MEASURE_ABOVE, curvature_stiffening, rest_turns, strand_time_steps, stiffest_mode_ratio
from .step.launch import project_once
from .step.plan import FAILED_ABOVE

INITIAL_PROJECTION_ROUNDS = 50  # projection calls at most to move a groom out of the colliders


class StartSetup:
    """Simulator methods run while it is built: placing the groom, the colliders holding roots,
    the initial contacts, and the stability bound of the start shape."""

    def _place_groom(self, rotation, translation):
        """Put the whole groom rigidly at the head's pose (used for the initial pose only)."""
        self._head = self._head_prev = (rotation, translation)
        x = self.groom.positions @ rotation.T + translation
        self.state.x.from_numpy(x.astype(np.float64))
        self._orient_roots(reference=True)

    def _colliders_holding_roots(self, colliders) -> list[tuple[int, int]]:
        """(strand, collider index) pairs whose root starts inside the collider by more than its
        margin: the contact stage skips them (collisions.root_keeps_collider), so say so once.
        Head-attached colliders see the roots in head coordinates, world ones at the start pose."""
        head_roots = self.groom.positions[:, 0]
        world_roots = self.positions()[:, 0]
        skipped = []
        for k, c in enumerate(colliders):
            roots = head_roots if c.attached == "head" else world_roots
            depth = host_distance(c, roots)
            skipped += [(int(s), k) for s in np.flatnonzero(~root_keeps_collider(depth, c.margin))]
        if skipped:
            kinds = sorted({type(colliders[k]).__name__ + f" (colliders[{k}])" for _, k in skipped})
            warnings.warn(f"{len(skipped)} strand root(s) (first: strand {skipped[0][0]}) lie inside "
                          f"{', '.join(kinds)} by more than its margin: those strands do not collide with "
                          f"it (sim.skipped_colliders lists the pairs); move the roots onto the surface "
                          f"to keep the hair out", RuntimeWarning, stacklevel=3)
        return skipped

    def _resolve_initial_contacts(self):
        """Move groomed nodes that start inside a collider's margin out of it before the first
        step, so the correction does not turn into a velocity kick (the push over one substep
        would read as metres per second)."""
        st, c = self.state, self.control
        load_poses(c, np.stack([pose_rows(*self._head), pose_rows(*self._head)]))
        load_tools(c, self.touch, np.full(2, self.time))
        st.x_prev.copy_from(st.x)
        # A strand groomed into the head may need many more iterations than one step allows;
        # this runs once, so keep going (up to INITIAL_PROJECTION_ROUNDS calls) until it holds.
        for _ in range(INITIAL_PROJECTION_ROUNDS):
            st.residuals.fill(0.0)
            project_once(self._bundles, self.plan, c)
            residual = st.residuals.to_numpy()[:, 0]
            if residual.max() <= self.plan.projection_tol:
                break
        stuck = np.flatnonzero(~(residual <= FAILED_ABOVE))
        if len(stuck):
            warnings.warn(f"{len(stuck)} strand(s) (first: {stuck[0]}) start inside a collider and "
                          f"could not be moved out with their edge lengths kept (relative residual "
                          f"{residual[stuck].max():.3g}); check the groom against the head",
                          RuntimeWarning, stacklevel=3)
        st.x_prev.copy_from(st.x)
        self._reset_counters()

    def _tighten_bound_to_start(self, strict):
        """Contacts may have bent the groom at the start: the bound must hold for that shape too."""
        x = self.positions()
        start = Groom.from_polylines([x[s, : n] for s, n in enumerate(self.groom.node_counts)])
        self.bound = self.bound.tightened(
            strand_time_steps(start, self.model.materials, self.control.drag, self.stability_factor,
                              kmoch=self.twist == "kmoch", measured=self._measured_stiffening()),
            "the shape the colliders left the groom in at the start (sharp bends)")
        self.substeps = self._substeps(strict)

    def _measured_stiffening(self) -> dict:
        """{strand: EI_eff / EI} of the strands whose current shape the curvature rule charges
        more than MEASURE_ABOVE: their stiffest bending mode (stiffest_mode_ratio) from central
        differences of the elastic forces. Under the rotation measure only (the rule holds for
        DER's rest shapes but not once they bend away), explicit step, twist not Kmoch's.
        Positions and frames are as they were afterwards."""
        if self.strain != "rotation" or self.twist == "kmoch" or self.integrator != "explicit":
            return {}
        counts = self.groom.node_counts
        x0 = self.state.x.to_numpy()
        if self._measured_for is not None and np.array_equal(self._measured_for[0], x0):
            return self._measured_for[1]  # the start shape is the groom's: no collider moved a node
        measured = self._stiffening_of(x0, counts)
        self._measured_for = (x0, measured)
        return measured

    def _stiffening_of(self, x0, counts) -> dict:
        """_measured_stiffening's answer at positions x0 [S, N, 3] m."""
        strands = [s for s in range(len(counts))
                   if curvature_stiffening(rest_turns(x0[s, : counts[s]])) > MEASURE_ABOVE]
        if not strands:
            return {}
        h = 1e-4 * min(np.linalg.norm(np.diff(x0[s, : counts[s]], axis=0), axis=1).min() for s in strands)
        hessian = self.rods.elastic_hessian(x0, strands, h)
        mass = self.model.mass.to_numpy()
        measured = {}
        for k, s in enumerate(strands):
            n, m = counts[s], self.model.materials[s]
            measured[s] = stiffest_mode_ratio(x0[s, :n], mass[s, :n], hessian[k, : 3 * n, : 3 * n],
                                              max(m.bending_stiffness), m.linear_density)
        return measured
