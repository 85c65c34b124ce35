"""Guide strands as rods, without time stepping: the model and state of a groom and what they
define (frames, the elastic energy, its forces, the twist solve). The Simulator steps one; the
sag-free solve and the cosseratbench plugin probe one. Units: SI throughout."""

import math

import numpy as np
import taichi as ti

from ..rods import arrays
from ..rods.arrays import Ints1, point, Points2, Scalars1, Scalars2, Vec3s1, Vec3s2
from ..rods.frames import update_frames, update_material_frames
from ..rods.groom import MAX_TURNING_ANGLE_DEG, MIN_SEGMENT_LENGTH, Groom
from ..rods.modes import Root, Twist
from ..rods.rod import elastic_forces, first_node, strand_elastic_energy, theta_gradient
from ..rods.state import COUNTERS, build
from ..rods.twist_forces import held_twist_forces, kmoch_forces
from ..runtime import ensure_init, precision
from ..world.options import Environment, SolverOptions, split_keywords
from .implicit import assemble_stiffness, clear_system
from .pins import strand_hold_clip_twist
from .step.bundles import DriveArgs, ModelArgs, StateArgs, StepBundles, StepScalars
from .step.plan import BAD, StageFlags
from .step.stages import strand_twist

MAX_SET_STRETCH = 2.0  # set_positions: an inextensible edge at most this x its rest length


class RodSystem:
    """The rods of `groom` made of `material` (one Material or one per strand).

    options: a SolverOptions (world/options.py), or its fields as keywords (twist="kmoch"); the
    rods use its twist mode and solve's tolerance and cap, root, strain measure (resolved for
    the groom: `options.strain`), extensibility, and the integrator (the implicit step's arrays
    are allocated for it). Attributes: groom, options, model (state.RodModel), state
    (state.RodState), bundles (step.StepBundles)."""

    def __init__(self, groom: Groom, material, options: SolverOptions | None = None, **keywords):
        ensure_init()
        if not isinstance(groom, Groom):
            raise ValueError(f"groom must be a taichi_hair.Groom, got {type(groom).__name__}")
        options, environment = split_keywords(options, None, keywords, "RodSystem")
        if environment != Environment():
            raise TypeError("RodSystem takes solver options only (gravity, drag, wind, motion and touch "
                            "are the Simulator's)")
        options = options.for_groom(groom, material)
        self.options = options
        self.groom, self.twist, self.root, self.integrator = groom, options.twist, options.root, options.integrator
        self.strain, self.extensible = options.strain, options.extensible
        self.twist_iterations = options.twist_iterations
        self.twist_tol = default_twist_tol() if options.twist_tol is None else options.twist_tol
        root, integrator, strain, extensible = self.root, self.integrator, self.strain, self.extensible
        self.model, self.state = build(groom, material, clamp=root == "clamped",
                                       implicit=integrator == "implicit", extensible=bool(extensible),
                                       strain=strain)
        if root in ("edge", "free"):  # edge: node 1 rides on the head too; free: node 0 does not
            inv_mass = self.model.inv_mass.to_numpy()
            if root == "edge":
                inv_mass[:, 1] = 0.0
            else:
                inv_mass[:, 0] = 1.0 / self.model.mass.to_numpy()[:, 0]
            self.model.inv_mass.from_numpy(inv_mass)
        self.bundles = StepBundles(self.model, self.state)
        self._frame_scratch = None  # material_directors' frames, allocated on first use

    # ---- state in and out -------------------------------------------------------------
    @property
    def n_strands(self) -> int:
        return self.groom.n_strands

    def positions(self) -> np.ndarray:
        """Node positions [S, N, 3] in metres (padding nodes repeat each strand's last node)."""
        return self.state.x.to_numpy().astype(np.float64)

    def velocities(self) -> np.ndarray:
        """Node velocities [S, N, 3] in m/s."""
        return self.state.v.to_numpy().astype(np.float64)

    def set_positions(self, x) -> None:
        """Set node positions [S, N, 3] (metres) and recompute the frames; the material angles
        are kept (call `update_twist` to re-solve them). Refused like a Groom: segments shorter
        than MIN_SEGMENT_LENGTH, turns sharper than MAX_TURNING_ANGLE_DEG (a fold), and for
        inextensible strands an edge longer than MAX_SET_STRETCH x its rest length (the projection
        would pull it back in one step: a kick the step reads as a blow-up)."""
        x = self._checked_nodes("positions", x, np.float64)  # positions are float64 (arrays.Points2)
        check_strand_geometry(x, self.groom.node_counts)
        if not self.extensible:
            self._check_stretch(x)
        self._place(x)

    def _place(self, x: np.ndarray) -> None:
        """`set_positions` without its checks: x [S, N, 3] float64 m, known to be valid."""
        self.state.x.from_numpy(x)
        self.update_frames()

    def _check_stretch(self, x):
        rest = self.model.rest_length.to_numpy().astype(np.float64)
        used = np.arange(rest.shape[1])[None, :] < (self.groom.node_counts - 1)[:, None]
        ratio = np.where(used, np.linalg.norm(np.diff(x, axis=1), axis=2) / np.where(used, rest, 1.0), 1.0)
        if ratio.max() > MAX_SET_STRETCH:
            s, j = np.unravel_index(np.argmax(ratio), ratio.shape)
            raise ValueError(f"positions: edge {j} of strand {s} is {ratio[s, j]:.3g} x its rest length "
                             f"{rest[s, j]:.3g} m; inextensible edges may be set at most {MAX_SET_STRETCH:g} x "
                             f"their rest length")

    def set_velocities(self, v) -> None:
        """Set node velocities [S, N, 3] in m/s."""
        self.state.v.from_numpy(self._checked_nodes("velocities", v))

    def _checked_nodes(self, name, values, dtype=None):
        """values [S, N, 3] as an array of `dtype` (default the precision's float), or ValueError
        naming `name` for a wrong shape or a non-finite entry."""
        values = np.asarray(values, dtype=np.float64)
        expected = (self.groom.n_strands, self.groom.max_nodes, 3)
        if values.shape != expected:
            raise ValueError(f"{name} must have shape {list(expected)}, got {list(values.shape)}")
        if not np.all(np.isfinite(values)):
            s, i = np.argwhere(~np.isfinite(values))[0][:2]
            raise ValueError(f"{name} must be finite; strand {s} node {i} is {values[s, i]}")
        return values.astype(dtype or arrays.np_float())

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
        e = np.diff(self.positions(), axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = e / np.linalg.norm(e, axis=2, keepdims=True)
        st = self.state
        return {"u": st.bishop_u.to_numpy(), "v": st.bishop_v.to_numpy(), "m1": st.m1.to_numpy(),
                "m2": st.m2.to_numpy(), "t": t, "kb": st.kb.to_numpy()}

    def material_directors(self) -> np.ndarray:
        """Numpy copy [S, N-1, 3] of the first material director m1 of every edge, from the
        positions and material angles as they are now. Computed into arrays of its own: the
        state's frames (which the next step reads) are left as the last step left them."""
        st, md = self.state, self.model
        if self._frame_scratch is None:
            self._frame_scratch = tuple(arrays.like(a) for a in (st.bishop_u, st.bishop_v, st.m1, st.m2, st.kb))
        update_frames(md.clamp, st.x, md.node_count, st.root_t, st.root_u, st.theta, *self._frame_scratch)
        return self._frame_scratch[2].to_numpy()

    # ---- frames and twist -------------------------------------------------------------
    def update_frames(self) -> None:
        """Bishop and material frames and curvature binormals from the current positions."""
        st, md = self.state, self.model
        update_frames(md.clamp, st.x, md.node_count, st.root_t, st.root_u, st.theta, st.bishop_u,
                      st.bishop_v, st.m1, st.m2, st.kb)

    def update_twist(self, clip_arrays=None) -> dict:
        """Solve the free edges' material angles with the chosen twist mode (clip_arrays: the
        simulator's pin arrays when clips hold twist, pins.PinTable.device). Returns
        {"iterations", "residual", "cap_hits", "stalls"}: the quasistatic solve's max over strands
        (the scaled residual max |dE/dtheta| l / max(EI1, GJ)) and how many strands ended at the
        iteration cap or stalled above tolerance at the rounding floor; "kmoch" reports its exact
        solve of round strands, 1 iteration and residual NaN when every strand is elliptic;
        "none": 0 iterations, residual NaN."""
        self.reset_counters()
        run_twist_update(self.bundles, self.twist, self.root, self.twist_tol, self.twist_iterations,
                         clip_arrays)
        counters = self.state.counters.to_numpy()
        exact = [m.ellipticity == 1.0 for m in self.model.materials]
        report = {"iterations": int(counters[:, COUNTERS["twist_iterations"]].max()),
                  "residual": float(self.state.residuals.to_numpy()[:, 1].max()),
                  "cap_hits": int(counters[:, COUNTERS["twist_cap_hits"]].sum()),
                  "stalls": int(counters[:, COUNTERS["twist_stalls"]].sum())}
        if self.twist == "none" or (self.twist == "kmoch" and not any(exact)):
            report.update(iterations=int(self.twist == "kmoch"), residual=float("nan"))
        return report

    def reset_counters(self) -> None:
        """Zero the per-strand solver counters and residual maxima."""
        self.state.counters.fill(0)
        self.state.residuals.fill(0.0)

    # ---- energy and forces ------------------------------------------------------------
    def strand_elastic_energy(self) -> np.ndarray:
        """Elastic energy of each strand [S] in joules, material angles as they are."""
        st, md = self.state, self.model
        strand_elastic_energy(md.clamp, md.rotation, self.bundles.model, self.bundles.state, st.strand_scalar)
        return st.strand_scalar.to_numpy().astype(np.float64)

    def elastic_energy(self) -> float:
        """Bending + twist energy of all strands in joules, material angles held as they are."""
        return float(self.strand_elastic_energy().sum())

    def elastic_forces(self, rest_kappa=None, clip=None) -> np.ndarray:
        """Elastic forces [S, N, 3] in newtons: minus the gradient of `elastic_energy` with the
        material angles held fixed (holonomy term included). At twist equilibrium (after
        `update_twist` with "quasistatic") this is also the total force. With twist="kmoch" the
        angles of elliptic strands follow the centreline by Kmoch's rule, and this is minus the
        total derivative of E(x, theta_kmoch(x)) (after `update_twist`). rest_kappa: a vec4
        [S, N] ndarray of rest curvatures to use instead of the model's (the sag-free solve
        probes the force's dependence on them this way, leaving the model as it is). clip: the
        pin table's clip array when clips hold twist: their edges' angles follow the centreline
        (twist_forces.strand_held_twist_forces)."""
        total_elastic_forces(self.bundles, self.twist, rest_kappa)
        if clip is not None:
            md = self.model
            held_twist_forces(md.clamp, md.rotation, self.bundles.model_with(rest_kappa), self.bundles.state, clip)
        return self.state.force.to_numpy().astype(np.float64)

    def elastic_hessian(self, x0, strands, h: float) -> np.ndarray:
        """d^2 E / dx^2 [len(strands), 3 n, 3 n] N/m of the listed strands at positions x0
        [S, N, 3] m (n the largest of their node counts), from central differences of
        `elastic_forces` with step h [m] (material angles held as they are). Node 0 is held: its
        columns stay zero. Positions and frames are x0's afterwards. h in (0, 1e-3 x the
        shortest edge]: x0 is checked as `set_positions` checks, the moved positions are not
        (the checks cost more than the force evaluations, two per column)."""
        x0 = self._checked_nodes("positions", x0, np.float64)
        check_strand_geometry(x0, counts := self.groom.node_counts)
        used = np.arange(x0.shape[1] - 1)[None, :] < (np.asarray(counts)[:, None] - 1)
        shortest = float(np.linalg.norm(np.diff(x0, axis=1), axis=2)[used].min())
        if not 0.0 < h <= 1e-3 * shortest:
            raise ValueError(f"h must be in (0, 1e-3 x the shortest edge = {1e-3 * shortest:.3g}] m, got {h:g}")
        strands = list(strands)
        n_max = max(counts[s] for s in strands)
        hessian = np.zeros((len(strands), 3 * n_max, 3 * n_max))
        for i in range(1, n_max):
            rows = [s for s in strands if i < counts[s]]
            for c in range(3):
                forces = []
                for sign in (1.0, -1.0):
                    x = x0.copy()
                    x[rows, i, c] += sign * h
                    self._place(x)   # h <= 1e-3 of the shortest edge: no edge collapses
                    forces.append(self.elastic_forces()[strands, :n_max].reshape(len(strands), -1))
                hessian[:, :, 3 * i + c] = -(forces[0] - forces[1]) / (2.0 * h)
        self._place(x0)
        return hessian

    def bending_stiffness(self, condensed: bool = True) -> np.ndarray:
        """The implicit step's stiffness matrix K [S, 3N, 3N] in N/m at the current frames: the
        Gauss-Newton Hessian of the elastic energy over the free nodes, the free edges'
        material angles condensed out at equilibrium (K_xx - K_xt K_tt^-1 K_tx; held rows and
        columns zero; docs/model.md, "The implicit step"). At rest it is the Jacobian of the
        forces with the twist re-solved. condensed=False: the matrix over positions and angles
        as the step's solve holds it, [S, 5N, 5N], node i's unknowns 5i..5i+4 (position,
        a zero multiplier slot, edge i-1's angle; held positions and angles zero). Needs
        integrator="implicit"."""
        if self.integrator != "implicit":
            raise ValueError('bending_stiffness needs a RodSystem built with integrator="implicit"')
        stiffness_blocks(self.model.clamp, self.twist != "none", self.model.rotation, self.bundles.model,
                         self.bundles.state)
        blocks = self.state.blocks.to_numpy().astype(np.float64)
        s_count, n_max = blocks.shape[:2]
        inv_mass = self.model.inv_mass.to_numpy()
        first_angle = first_node(self.model.clamp) + 1  # node i holds edge i-1's angle (theta_free)
        size = 3 if condensed else arrays.BLOCK
        out = np.zeros((s_count, size * n_max, size * n_max))
        for s in range(s_count):
            n = self.groom.node_counts[s]
            dense = dense_from_blocks(blocks[s], n)
            if not condensed:
                out[s, :arrays.BLOCK * n, :arrays.BLOCK * n] = dense
                continue
            free = np.flatnonzero(inv_mass[s, :n] > 0)
            xs = (arrays.BLOCK * free[:, None] + np.arange(3)).ravel()
            ts = arrays.BLOCK * np.arange(first_angle, n) + 4 if self.twist != "none" else np.zeros(0, int)
            k_xx = dense[np.ix_(xs, xs)]
            if len(ts):
                k_xt = dense[np.ix_(xs, ts)]
                k_xx = k_xx - k_xt @ np.linalg.solve(dense[np.ix_(ts, ts)], k_xt.T)
            rows = (3 * free[:, None] + np.arange(3)).ravel()
            out[s][np.ix_(rows, rows)] = k_xx
        return out

    def theta_gradient(self) -> np.ndarray:
        """dE/dtheta^j [S, N-1] in joules per radian (the twist solve drives the free ones to 0)."""
        st, md = self.state, self.model
        out = st.scratch_edge[0]
        theta_gradient(md.clamp, md.rotation, self.bundles.model, self.bundles.state, out)
        return out.to_numpy().astype(np.float64)


def dense_from_blocks(blocks, n) -> np.ndarray:
    """The symmetric matrix [B n, B n] (B = arrays.BLOCK) of one strand's block-pentadiagonal
    blocks [N, 3, B, B] (diagonal, first and second sub-diagonal blocks of each node's row,
    linalg.block_pentadiagonal_solve's layout), its first n node rows."""
    size = arrays.BLOCK
    dense = np.zeros((size * n, size * n))
    for i in range(n):
        for k in range(min(3, i + 1)):
            j = i - k
            dense[size * i:size * i + size, size * j:size * j + size] = blocks[i, k]
            if k:
                dense[size * j:size * j + size, size * i:size * i + size] = blocks[i, k].T
    return dense


def default_twist_tol() -> float:
    return 1e-10 if precision() == "float64" else 1e-5


def check_strand_geometry(x, node_counts):
    """ValueError naming the first strand and node of x [S, N, 3] m whose segment is shorter than
    MIN_SEGMENT_LENGTH or whose turn exceeds MAX_TURNING_ANGLE_DEG (the Groom's own rules: the
    curvature binormal is undefined there, so the energy would be NaN). Vectorised over strands."""
    x = np.asarray(x, dtype=np.float64)
    edges = np.diff(x, axis=1)
    lengths = np.linalg.norm(edges, axis=2)
    real = np.arange(x.shape[1] - 1)[None, :] < (np.asarray(node_counts)[:, None] - 1)
    short = np.argwhere(real & (lengths < MIN_SEGMENT_LENGTH))
    if len(short):
        s, i = short[0]
        raise ValueError(f"positions: strand {s} segment {i} (nodes {i}-{i + 1}) has length {lengths[s, i]:.3g} m; "
                         f"segments must be >= {MIN_SEGMENT_LENGTH:g} m long (coincident nodes)")
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_turn = np.sum(edges[:, 1:] * edges[:, :-1], axis=2) / (lengths[:, 1:] * lengths[:, :-1])
    folded = np.argwhere(real[:, 1:] & (cos_turn < math.cos(math.radians(MAX_TURNING_ANGLE_DEG))))
    if len(folded):
        s, i = folded[0]
        angle = math.degrees(math.acos(max(-1.0, min(1.0, cos_turn[s, i]))))
        raise ValueError(f"positions: strand {s} turns by {angle:.1f} degrees at node {i + 1}; turning angles "
                         f"must be <= {MAX_TURNING_ANGLE_DEG:g} degrees (the strand folds back on itself)")


# ---- kernels over the rods outside a step: twist update, elastic forces and energy, stiffness ----

@ti.kernel
def update_twist_kernel(fl: ti.template(), twist_tol: float, twist_iterations: ti.i32, md: ModelArgs,
                        st: StateArgs, dr: DriveArgs):
    """The twist stage alone (twist-holding clips at their latest angles, head pose 1);
    counters[s, BAD] = 0 where it failed, else -1."""
    sc = StepScalars(h=1.0, k0=0.0, drag=0.0, max_speed=0.0, projection_tol=0.0, projection_iterations=0,
                     twist_tol=twist_tol, twist_iterations=twist_iterations, n_analytic=0, pin_f0=1.0,
                     pin_df=0.0, stride=1)
    for s in range(st.theta.shape[0]):
        st.counters[s, BAD] = -1
        if ti.static(fl.clips):
            strand_hold_clip_twist(s, 1.0, md.node_count, dr.pin_mode, dr.clip, dr.head, 1, st.bishop_u,
                                   st.bishop_v, st.theta)
        if strand_twist(s, fl, sc, md, st, dr):
            st.counters[s, BAD] = 0


def total_elastic_forces(bundles: StepBundles, twist: str, rest_kappa=None) -> None:
    """state.force = the elastic force [S, N] N: minus the gradient at fixed angles, plus, under
    Kmoch's rule, the term from the angles' dependence on the centreline (elliptic strands).
    rest_kappa: rest curvatures to use instead of the model's (None: the model's)."""
    md, model = bundles.rods[0], bundles.model_with(rest_kappa)
    elastic_forces(md.clamp, md.rotation, model, bundles.state)
    if twist == "kmoch":
        kmoch_forces(md.clamp, model, bundles.state)


def run_twist_update(bundles: StepBundles, twist: str, root: str, twist_tol: float, twist_iterations: int,
                     clip_arrays=None):
    """The twist stage alone (no-op for "none"); material frames follow the new angles.
    clip_arrays: the pin table's (mode, start, end, clip) when clips hold twist (else None)."""
    if twist == "none":
        return
    flags = StageFlags(external=False, wind_field=False, twist_mode=Twist.parse("twist", twist).code, user=False,
                       moving_head=False, contacts=False, mesh=False, touch=False,
                       pins=clip_arrays is not None, root_mode=Root.parse("root", root).code, clips=clip_arrays is not None,
                       rotation=bundles.rods[0].rotation)
    update_twist_kernel(flags, twist_tol, twist_iterations, bundles.model, bundles.state,
                        bundles.twist_drive(clip_arrays))


@ti.kernel
def strand_mechanical_energy(node_count: Ints1, mass: Scalars2, inv_mass: Scalars2, x: Points2,
                             v: Vec3s2, loads: Vec3s1, kinetic: Scalars1, potential: Scalars1):
    """kinetic[s] = sum 1/2 m |v|^2, potential[s] = -sum m g . x [J] over the free nodes (the root
    edge is driven by the head, not by forces). One thread per strand."""
    for s in range(x.shape[0]):
        k = 0.0
        p = 0.0
        for i in range(node_count[s]):
            if inv_mass[s, i] > 0.0:
                k += 0.5 * mass[s, i] * v[s, i].dot(v[s, i])
                p -= mass[s, i] * loads[0].dot(point(x, s, i))
        kinetic[s] = k
        potential[s] = p


@ti.kernel
def stiffness_blocks(clamp: ti.template(), twist_free: ti.template(), rotation: ti.template(), md: ModelArgs,
                     st: StateArgs):
    """st.blocks = the implicit step's Gauss-Newton stiffness of every strand over the free
    nodes' positions [N/m] and the free edges' angles (implicit.assemble_stiffness; blocks as
    in linalg.block_pentadiagonal_solve) at the current frames. One thread per strand."""
    for s in range(st.x.shape[0]):
        clear_system(s, md.node_count[s], True, st)
        assemble_stiffness(s, clamp, twist_free, rotation, 1.0, md, st, 0)
