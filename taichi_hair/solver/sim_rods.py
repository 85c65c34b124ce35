"""The rods of a Simulator seen from outside: state in and out, frames, the twist update, the
elastic energy and forces, and the energies of the motion. A mixin of `simulator.Simulator`,
delegating to its `system.RodSystem` (`self.rods`)."""

import numpy as np

from .system import strand_mechanical_energy


class RodAccess:
    """Simulator methods over the rods' state (positions [S, N, 3] m, velocities m/s, material
    angles rad, frames) and their energies [J]."""

    @property
    def n_strands(self) -> int:
        return self.groom.n_strands

    def positions(self) -> np.ndarray:
        """Node positions [S, N, 3] in metres (padding nodes repeat each strand's last node)."""
        return self.rods.positions()

    def velocities(self) -> np.ndarray:
        """Node velocities [S, N, 3] in m/s."""
        return self.rods.velocities()

    def set_positions(self, x) -> None:
        """Set node positions [S, N, 3] (metres) and recompute the frames (RodSystem.set_positions)."""
        self.rods.set_positions(x)
        self._history_h = None

    def set_velocities(self, v) -> None:
        """Set node velocities [S, N, 3] in m/s."""
        self.rods.set_velocities(v)
        self._history_h = None

    def material_angles(self) -> np.ndarray:
        """Material angles theta [S, N-1] in radians, measured from the Bishop frame."""
        return self.rods.material_angles()

    def set_material_angles(self, theta) -> None:
        self.rods.set_material_angles(theta)

    def material_directors(self) -> np.ndarray:
        """The guides' first material directors m1 [S, N-1, 3] (unit vectors normal to each
        edge) from the positions and material angles now (RodSystem.material_directors): what
        `Interpolator.interpolate(directors=...)` takes for an imported style."""
        return self.rods.material_directors()

    def frames(self) -> dict:
        """Bishop and material frames, tangents and curvature binormals (RodSystem.frames)."""
        return self.rods.frames()

    def update_frames(self) -> None:
        """Bishop and material frames and curvature binormals from the current positions."""
        self.rods.update_frames()

    def update_twist(self) -> dict:
        """Solve the free edges' material angles with the chosen twist mode (RodSystem.update_twist);
        edges held by twist-holding clips take the clips' latest angles."""
        return self.rods.update_twist(self._clip_arrays())

    def _clip_arrays(self):
        """The pin table's device arrays when clips hold twist, else None."""
        if not self._pins.clips:
            return None
        self._pins.upload()
        return self._pins.device

    def strand_elastic_energy(self) -> np.ndarray:
        """Elastic energy of each strand [S] in joules, material angles as they are."""
        return self.rods.strand_elastic_energy()

    def elastic_energy(self) -> float:
        """Bending + twist energy of all strands in joules, material angles held as they are."""
        return self.rods.elastic_energy()

    def elastic_forces(self) -> np.ndarray:
        """Elastic forces [S, N, 3] in newtons (RodSystem.elastic_forces), with the term of edges
        whose material frame a clip holds in space."""
        arrays_ = self._clip_arrays()
        return self.rods.elastic_forces(clip=None if arrays_ is None else arrays_[3])

    def bending_stiffness(self) -> np.ndarray:
        """The implicit step's stiffness matrix [S, 3N, 3N] in N/m (RodSystem.bending_stiffness)."""
        return self.rods.bending_stiffness()

    def theta_gradient(self) -> np.ndarray:
        """dE/dtheta^j [S, N-1] in joules per radian (the twist solve drives the free ones to 0)."""
        return self.rods.theta_gradient()

    # ---- energies of the motion ---------------------------------------------------------
    def _mechanical(self):
        """Per-strand kinetic and gravitational energy [S], [S] in joules."""
        st, md = self.state, self.model
        strand_mechanical_energy(md.node_count, md.mass, self._pins.free_inv_mass, st.x, st.v,
                                 self.control.loads, st.strand_scalar, self._potential)
        return st.strand_scalar.to_numpy().astype(np.float64), self._potential.to_numpy().astype(np.float64)

    def kinetic_energy(self) -> float:
        """Sum of 1/2 m |v|^2 over free nodes [J] (the head-driven root node excluded)."""
        return float(self._mechanical()[0].sum())

    def gravity_energy(self) -> float:
        """Gravitational potential -sum m g . x over free nodes [J] (zero at the origin)."""
        return float(self._mechanical()[1].sum())

    def stretch_energy(self) -> float:
        """Stretch energy sum_j EA (|e_j| - |ebar_j|)^2 / (2 |ebar_j|) [J] of extensible strands
        (Simulator(extensible=True)); 0 for inextensible ones."""
        if not self.plan.extensible:
            return 0.0
        lengths = np.linalg.norm(np.diff(self.positions(), axis=1), axis=2)
        rest = self.model.rest_length.to_numpy().astype(np.float64)
        ea = self.model.stiffness.to_numpy()[:, 3].astype(np.float64)
        used = np.arange(rest.shape[1])[None, :] < (self.model.node_count.to_numpy() - 1)[:, None]
        return float(np.sum(np.where(used, ea[:, None] * (lengths - rest) ** 2 / (2 * np.where(used, rest, 1.0)),
                                     0.0)))

    def total_energy(self) -> float:
        """kinetic + gravity + elastic (+ stretch, extensible strands) [J]."""
        k, p = self._mechanical()
        return float(k.sum() + p.sum()) + self.elastic_energy() + self.stretch_energy()


