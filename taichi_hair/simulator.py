"""The Simulator: a groom and its material turned into Taichi state, with the stages of
Kmoch's loop run on it. It holds the arrays and the options; the physics lives in the kernels
of frames.py, rod.py, twist.py (and the stepping stages of step.py)."""

import numpy as np

from . import arrays
from .frames import update_frames, update_material_frames
from .groom import Groom
from .rod import elastic_forces, strand_elastic_energy, theta_gradient
from .runtime import ensure_init, precision
from .state import build
from .twist import copy_angles, kmoch_twist_angles, solve_twist_quasistatic

TWIST_MODES = ("kmoch", "quasistatic", "none")


class Simulator:
    """Guide strands of `groom` made of `material` (one Material or one per strand).

    twist: "kmoch" (Kmoch et al.'s alignment rule for elliptic hair), "quasistatic" (Newton on
    dE/dtheta = 0 per strand) or "none" (material angles stay at their rest values).
    twist_tol: scaled residual max_j |dE/dtheta^j| l_j / max(EI1, GJ) that ends the quasistatic
    solve (default 1e-10 in float64, 1e-5 in float32); twist_iterations caps it.
    """

    def __init__(self, groom: Groom, material, *, twist: str = "kmoch", twist_tol: float | None = None,
                 twist_iterations: int = 30):
        ensure_init()
        if not isinstance(groom, Groom):
            raise ValueError(f"groom must be a taichi_hair.Groom, got {type(groom).__name__}")
        if twist not in TWIST_MODES:
            raise ValueError(f"twist must be one of {TWIST_MODES}, got {twist!r}")
        if twist_tol is None:
            twist_tol = 1e-10 if precision() == "float64" else 1e-5
        if not (twist_tol > 0):
            raise ValueError(f"twist_tol must be > 0, got {twist_tol!r}")
        if not (isinstance(twist_iterations, int) and twist_iterations >= 1):
            raise ValueError(f"twist_iterations must be an integer >= 1, got {twist_iterations!r}")
        self.groom = groom
        self.twist = twist
        self.twist_tol = float(twist_tol)
        self.twist_iterations = twist_iterations
        self.model, self.state = build(groom, material)
        self._twist_report = {"iterations": 0, "residual": 0.0}

    # ---- state in and out -------------------------------------------------------------
    @property
    def n_strands(self) -> int:
        return self.groom.n_strands

    def positions(self) -> np.ndarray:
        """Node positions [S, N, 3] in metres (padding nodes repeat each strand's last node)."""
        return self.state.x.to_numpy().astype(np.float64)

    def set_positions(self, x) -> None:
        """Set node positions [S, N, 3] (metres) and recompute the frames; the material angles
        are kept (call `update_twist` to re-solve them)."""
        x = np.asarray(x, dtype=np.float64)
        expected = (self.groom.n_strands, self.groom.max_nodes, 3)
        if x.shape != expected:
            raise ValueError(f"positions must have shape {list(expected)}, got {list(x.shape)}")
        if not np.all(np.isfinite(x)):
            s, i = np.argwhere(~np.isfinite(x))[0][:2]
            raise ValueError(f"positions must be finite; strand {s} node {i} is {x[s, i]}")
        self.state.x.from_numpy(x.astype(arrays.np_float()))
        self.update_frames()

    def material_angles(self) -> np.ndarray:
        """Material angles theta [S, N-1] in radians, measured from the Bishop frame."""
        return self.state.theta.to_numpy().astype(np.float64)

    def set_material_angles(self, theta) -> None:
        theta = np.asarray(theta, dtype=np.float64)
        if theta.shape != (self.groom.n_strands, self.groom.max_nodes - 1) or not np.all(np.isfinite(theta)):
            raise ValueError(f"material angles must be finite with shape "
                             f"[{self.groom.n_strands}, {self.groom.max_nodes - 1}], got {list(theta.shape)}")
        self.state.theta.from_numpy(theta.astype(arrays.np_float()))
        st = self.state
        update_material_frames(self.model.node_count, st.theta, st.bishop_u, st.bishop_v, st.m1, st.m2)

    def frames(self) -> dict:
        """Numpy copies [S, N-1, 3] of the Bishop frame (u, v), the material frame (m1, m2),
        the unit tangents t, and the curvature binormals kb [S, N, 3]."""
        x = self.positions()
        e = np.diff(x, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = e / np.linalg.norm(e, axis=2, keepdims=True)
        st = self.state
        return {"u": st.bishop_u.to_numpy(), "v": st.bishop_v.to_numpy(), "m1": st.m1.to_numpy(),
                "m2": st.m2.to_numpy(), "t": t, "kb": st.kb.to_numpy()}

    # ---- stages -----------------------------------------------------------------------
    def update_frames(self) -> None:
        """Bishop and material frames and curvature binormals from the current positions."""
        st, md = self.state, self.model
        update_frames(st.x, md.node_count, st.root_t, st.root_u, st.theta, st.bishop_u, st.bishop_v,
                      st.m1, st.m2, st.kb)

    def update_twist(self) -> dict:
        """Solve the free edges' material angles with the chosen twist mode. Returns
        {"iterations": max Newton iterations over strands, "residual": max scaled residual}
        for "quasistatic" (iterations 1, residual of the result otherwise)."""
        st, md = self.state, self.model
        if self.twist == "quasistatic":
            grad, diag, upper = st.scratch_edge
            solve_twist_quasistatic(md.node_count, st.bishop_u, st.bishop_v, st.kb, st.theta,
                                    md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness,
                                    self.twist_tol, self.twist_iterations, grad, diag, upper,
                                    st.strand_count, st.strand_scalar)
            self._twist_report = {"iterations": int(st.strand_count.to_numpy().max()),
                                  "residual": float(st.strand_scalar.to_numpy().max())}
        elif self.twist == "kmoch":
            theta_new = st.scratch_edge[0]
            kmoch_twist_angles(md.node_count, st.bishop_u, st.bishop_v, st.kb, st.theta,
                               md.rest_kappa, md.rest_twist, md.voronoi, md.stiffness, theta_new)
            copy_angles(md.node_count, theta_new, st.theta)
            self._twist_report = {"iterations": 1, "residual": float("nan")}
        update_material_frames(md.node_count, st.theta, st.bishop_u, st.bishop_v, st.m1, st.m2)
        return dict(self._twist_report)

    # ---- energies and forces ----------------------------------------------------------
    def strand_elastic_energy(self) -> np.ndarray:
        """Elastic energy of each strand [S] in joules, material angles as they are."""
        st, md = self.state, self.model
        strand_elastic_energy(md.node_count, st.kb, st.m1, st.m2, st.theta, md.rest_kappa,
                              md.rest_twist, md.voronoi, md.stiffness, st.strand_scalar)
        return st.strand_scalar.to_numpy().astype(np.float64)

    def elastic_energy(self) -> float:
        """Bending + twist energy of all strands in joules, material angles held as they are."""
        return float(self.strand_elastic_energy().sum())

    def elastic_forces(self) -> np.ndarray:
        """Elastic forces [S, N, 3] in newtons: minus the gradient of `elastic_energy` with the
        material angles held fixed (holonomy term included). At twist equilibrium (after
        `update_twist` with "quasistatic") this is also the total force."""
        st, md = self.state, self.model
        elastic_forces(st.x, md.node_count, st.kb, st.m1, st.m2, md.rest_kappa, md.voronoi,
                       md.stiffness, st.force)
        return st.force.to_numpy().astype(np.float64)

    def theta_gradient(self) -> np.ndarray:
        """dE/dtheta^j [S, N-1] in joules per radian (the twist solve drives the free ones to 0)."""
        st, md = self.state, self.model
        out = st.scratch_edge[0]
        theta_gradient(md.node_count, st.kb, st.m1, st.m2, st.theta, md.rest_kappa, md.rest_twist,
                       md.voronoi, md.stiffness, out)
        return out.to_numpy().astype(np.float64)

    # ---- head transform -----------------------------------------------------------------
    def set_root_transform(self, rotation, translation) -> None:
        """Place the head: root nodes and the root edges' reference frames follow the rigid
        transform x -> R x + t of the groom's rest pose. rotation: 3x3 proper rotation;
        translation: [3] metres."""
        rotation, translation = check_rigid_transform(rotation, translation)
        self._root_rotation, self._root_translation = rotation, translation
        st, md = self.state, self.model
        st.root_t.from_numpy((md.root_tangent @ rotation.T).astype(arrays.np_float()))
        st.root_u.from_numpy((md.root_reference @ rotation.T).astype(arrays.np_float()))


def check_rigid_transform(rotation, translation):
    """Validated (R [3, 3], t [3]) float64 arrays, or ValueError naming the bad one."""
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64)
    if rotation.shape != (3, 3) or not np.all(np.isfinite(rotation)):
        raise ValueError(f"rotation must be a finite 3x3 matrix, got shape {rotation.shape}")
    if (np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-6
            or abs(np.linalg.det(rotation) - 1.0) > 1e-6):
        raise ValueError("rotation must be a proper rotation matrix (R^T R = I within 1e-6, det R = +1)")
    if translation.shape != (3,) or not np.all(np.isfinite(translation)):
        raise ValueError(f"translation must be a finite vector of 3 metres, got {translation!r}")
    return rotation, translation
