"""Sag-free start: rest curvatures that make the groomed shape the shape at rest
under gravity.

A groom modelled under gravity sags further the moment gravity is switched on if it is taken as
the unloaded rest shape. The elastic force of a discrete rod is affine in the rest material
curvatures wbar (taichi_hair.rods.rod): at fixed positions x and material angles theta,
F(x; wbar) = F0 + J wbar. `sag_free` asks, strand by strand, for the wbar nearest the groom's own
rest curvature wbar0 such that the groomed pose is a static equilibrium with the root node
clamped and the edges inextensible:

    F0 + J wbar + m g + sum_j T_j grad_j + sum_k mu_k n_k = 0   on every free node,

T_j the tension [N] of edge j (its force on the nodes is T_j along the unit tangent: the
inextensibility constraint's multiplier), mu_k >= 0 [N] a normal contact force at node k along
the collider's outward normal n_k where the node lies within the head's margin.

The clamp is the simulator's (taichi_hair.rods.rod; `_Layout` says which nodes and edges are what):
only node 0 rides on the head, and it is a bending and twisting node whose previous "edge" is
the clamp (the head-carried root frame, material angle 0), its Voronoi length half the first
edge. So the free nodes are 1..n-1, the bending nodes (rest-curvature unknowns) are 0..n-2 with
both (node, edge-view) pairs of wbar variable (node 0's clamp-side pair too), every edge 0..n-2
carries a tension (edge 0 pulls on node 1 only) and every edge's material angle is free. A
pinned root is a hinge, which cannot carry the moment of the strand's weight: no balance exists
and `sag_free` refuses it.

J is probed with the simulator's own force kernel (4 N launches for all strands at once: one
rest-curvature component set to 1 on every strand), so the balance holds for exactly the forces
the simulation applies. Each strand then solves one regularised least-squares problem

    min |A z - b|^2 / w0^2 + alpha^2 |W (wbar - wbar0)|^2,   mu >= 0,

rows scaled by the strand's mean nodal weight w0, W the energy weights sqrt(EI / (4 l_i)) of the
bending term (so "nearest" means least bending energy between the two rest shapes), solved by a
small active-set NNLS (Lawson-Hanson, free variables always passive). The 3 (n-1) equations have
5 (n-1) + contacts unknowns, so an exact balance exists unless the contact signs forbid it; the
regulariser picks the smallest change.

Twist: the material frames enter w = (kb . m2, -kb . m1), so the balance is set up at the angles
the simulator will hold at the groomed pose. "none" and "quasistatic" hold the groom's own rest
angles theta0 (where a simulation starts): the balance is solved at theta0, and for
"quasistatic" the rest twist is then chosen so that dE/dtheta = 0 there too (the twist moment
T_j = GJ (theta_j - theta_{j-1} - mbar_j) / l_j must carry the bending term's torque from the tip
down: T_j = T_{j+1} - dE_bend/dtheta_j, T_{n-1} = 0, one backward sweep), so the quasistatic
update leaves the angles where they are (the sweep runs down to edge 0: node 0's twist
theta_0 - 0 - mbar_0 is taken against the clamp). Letting the angles move instead finds
equilibria that are saddles of the twist energy (measured: a curly strand drifting away
exponentially, doubling every 0.5 s). "kmoch" turns the major axis to the curvature binormals
(geometry alone decides the angle; the rest curvature only picks the branch theta or
theta +- pi): the solve alternates balance and twist update until the angles stop moving
(`iterations` rounds at most). The residual in the report is measured afterwards, at the final
angles, with forces from the simulator and only the tensions and contact forces solved: an
independent check of the balance.

Reachability: a rest curvature |wbar| = 2 tan(phi / 2) means a rest turning angle phi at the
node. Where the balance needs more than `max_turning_deg` the rest curvature is clipped to it
(the best rest shape the rod can still represent; the strand will sag where it was clipped) and
the strand is flagged, as is any strand whose residual exceeds `max_relative_residual` of its
weight.
"""

from contextlib import contextmanager
import ctypes
from dataclasses import dataclass
import math
import time

import numpy as np

from ..rods import arrays
from ..rods.groom import Groom
from ..rods.materials import per_strand_materials, stiffness_table
from ..rods.rod import first_node
from ..world.scene import ColliderUnion, Head
from ..runtime import precision
from ..rods.modes import Root, Twist
from ..validation import integer, real, vector3

ANGLE_TOLERANCE = 1e-7  # [rad]: the twist update no longer moves the angles
# a smallest eigenvalue below -this x (nodal weight / segment length) is a saddle, not a minimum
# (the scale gravity's destabilising stiffness has); float32 force differences are noisier
SADDLE_TOLERANCE = {"float64": 1e-3, "float32": 1e-2}


@dataclass(frozen=True)
class _Layout:
    """Which nodes and edges of an n-node strand the balance treats as what, from the
    simulator's root mode (taichi_hair.rods.rod.first_node). With a clamped root (the only mode a
    balance exists for): node 0 is held; the free nodes 1..n-1 carry the force balance, the
    contacts and the position Hessian; the bending nodes 0..n-2 carry the rest-curvature
    unknowns (4 components each); every edge touching a free node, 0..n-2, carries a tension;
    the free edges 0..n-2 (node 0 twists against the clamp) carry the twist balance and the
    twist Hessian."""

    held: int  # nodes 0..held-1 ride on the head
    first_bending: int  # the first node carrying bending and twist = the first free edge

    @classmethod
    def of(cls, model) -> "_Layout":
        """The layout of `model` (a RodModel); ValueError for a pinned root."""
        if not model.clamp:
            raise ValueError("sag_free needs a clamped root: a pinned root is a hinge, which "
                             "cannot carry the moment of the strand's weight (no balance exists)")
        layout = cls(held=1, first_bending=first_node(model.clamp))
        inv_mass = model.inv_mass.to_numpy()
        if np.any(inv_mass[:, :layout.held] != 0) or np.any(inv_mass[:, layout.held] == 0):
            raise RuntimeError("sag_free's layout does not match the simulator's: expected nodes "
                               f"0..{layout.held - 1} held (inv_mass 0) and node {layout.held} free")
        return layout

    def free_nodes(self, n: int) -> slice:
        return slice(self.held, n)

    def n_free(self, n: int) -> int:
        return n - self.held

    def bending_nodes(self, n: int) -> slice:
        return slice(self.first_bending, n - 1)

    def n_bending(self, n: int) -> int:
        return n - 1 - self.first_bending

    def tension_edges(self, n: int) -> range:
        """Edges with a free node (edge j joins nodes j and j + 1)."""
        return range(self.held - 1, n - 1)

    def free_edges(self, n: int) -> slice:
        """Edges whose material angle is free (twist balance and Hessian)."""
        return slice(self.first_bending, n - 1)


@dataclass(frozen=True)
class SagFreeReport:
    """What `sag_free` found, per strand (arrays [S]).

    residual [N]: |net force| over the free nodes (elastic + gravity + best tensions and contact
        forces), measured after the solve with the simulator's forces at its final angles.
    weight [N]: the strand's free weight sum m_i |g|; relative_residual = residual / weight.
    rest_change [1]: max |wbar - wbar0| over the strand's nodes (wbar0: the groom's own).
    max_turning_deg [deg]: the largest rest turning angle 2 atan(|wbar| / 2) the solution implies.
    clipped: the rest curvature was clipped to max_turning_deg somewhere on the strand.
    reachable: not clipped, not fell_back and relative_residual <= max_relative_residual (True
        for strands not solved).
    contact_nodes: free nodes within the head's margin (+ contact_tolerance) at the groomed pose.
    contact_force [N]: sum of the normal contact forces the balance used.
    torsion_stable: for twist="quasistatic", d^2E/dtheta^2 over the free edges is positive
        definite at the balance (else the angles roll away from it: the strand turns its rest
        curl downward and falls; simulate such a groom with twist="none"); True otherwise.
    shape_stable: the balance is a minimum of the energy over the positions (angles held), on
        the motions that keep edge lengths and contacts; a saddle is left at once.
    fell_back: the balance was found but is a saddle (not torsion_stable or not shape_stable):
        the strand keeps its groomed rest shape (it sags as without sag_free).
    solved: the strand was made sag-free (`strands`); the others keep their groomed rest shape,
        and their residual measures how far from balance that leaves them.
    twist: the twist mode solved for; iterations: balance/twist rounds run; converged: the
        angles stopped moving; seconds: wall time of the whole solve.
    """

    residual: np.ndarray
    weight: np.ndarray
    relative_residual: np.ndarray
    rest_change: np.ndarray
    max_turning_deg: np.ndarray
    clipped: np.ndarray
    reachable: np.ndarray
    contact_nodes: np.ndarray
    contact_force: np.ndarray
    torsion_stable: np.ndarray
    shape_stable: np.ndarray
    fell_back: np.ndarray
    solved: np.ndarray
    twist: str
    iterations: int
    converged: bool
    seconds: float

    @property
    def n_unreachable(self) -> int:
        return int(np.count_nonzero(self.solved & ~self.reachable))

    def summary(self) -> str:
        """One paragraph for a log."""
        s = int(self.solved.sum())
        if s == 0:
            return "sag-free rest shape for 0 strands (none chosen)"
        held = self.solved & ~self.fell_back
        rel = self.relative_residual[held] if held.any() else np.full(1, np.nan)
        return (f"sag-free rest shape for {s} strands in {self.seconds:.2f} s "
                f"({1e3 * self.seconds / s:.2f} ms per strand; twist {self.twist!r}, "
                f"{self.iterations} round(s), {'converged' if self.converged else 'NOT converged'}): "
                f"residual max {rel.max():.2e} of strand weight (median {np.median(rel):.2e}) "
                f"over the {int(held.sum())} held; largest rest turning angle "
                f"{self.max_turning_deg[held].max() if held.any() else 0.0:.1f} deg; "
                f"{int(self.clipped.sum())} strand(s) clipped, "
                f"{int(np.count_nonzero(self.fell_back))} kept as groomed (balance a saddle: "
                f"{int(np.count_nonzero(~self.torsion_stable))} in twist, "
                f"{int(np.count_nonzero(~self.shape_stable))} in shape), "
                f"{self.n_unreachable} unreachable; {int(self.contact_nodes.sum())} contact node(s).")


def sag_free(groom: Groom, material, gravity=(0.0, 0.0, -9.81), head: Head | None = None, *,
             twist: str = "quasistatic", regularization: float = 1e-5, max_turning_deg: float = 90.0,
             max_relative_residual: float = 0.01, contact_tolerance: float = 5e-4,
             iterations: int = 6, strands=None, keep_saddles: bool = False,
             root: str = "clamped") -> tuple[Groom, SagFreeReport]:
    """Rest curvatures that hold `groom` in place under `gravity` [m/s^2].

    Returns (groom with `rest_curvature` set, SagFreeReport). The new groom has the same
    positions; a Simulator built from it (same material, twist mode and gravity; drag and head
    as you like) starts at rest. head: a `Head` (or None): free nodes within a collider's margin
    + contact_tolerance [m] may lean on it with a normal force (head coordinates, rest pose).
    twist: the Simulator's twist mode ("kmoch", "quasistatic" or "none"): the balance is solved
    at the material angles that mode holds. regularization: weight alpha of the pull toward the
    groom's own rest curvature, relative to the force equations (smaller: smaller residual,
    larger change). max_turning_deg: the largest rest turning angle per node allowed, in
    (0, 180). max_relative_residual: the residual (over strand weight) above which a strand is
    reported unreachable. iterations: the most balance/twist-update rounds. strands: indices
    (or a boolean mask [S]) of the strands to make sag-free; the others keep the rest shape
    measured on their groomed positions (default: all). keep_saddles: return the balancing
    rest shape even where the balance is a saddle (report.fell_back stays all False; for
    inspection: such a strand leaves the groomed pose at once). root: the Simulator's root mode;
    only "clamped" (its default) can hold a strand up: "pinned" raises ValueError.

    Simulate the result with the same twist mode. For round or nearly round hair twist="none"
    is the robust choice: under "quasistatic" the angles are free to roll, and a strand whose
    rest curl must point against its groomed curvature to hold it up can roll its curl downward
    and fall (report.torsion_stable flags the strands where the angles alone are unstable;
    a strand may still be unstable through the coupling of angles and positions).
    """
    started = time.perf_counter()
    g = _check_inputs(groom, material, gravity, head, twist, regularization, max_turning_deg,
                      max_relative_residual, contact_tolerance, iterations, root)
    chosen = _strand_mask(strands, groom.n_strands)
    sim = _probe_rods(groom, material, twist, root)
    layout = _Layout.of(sim.model)
    twist0 = sim.model.rest_twist.to_numpy().astype(np.float64)
    wbar0 = sim.model.rest_kappa.to_numpy().astype(np.float64)
    problem = _Problem(groom, sim, g, wbar0, regularization,
                       _energy_weights(groom, per_strand_materials(material, groom.n_strands),
                                       sim.model.voronoi.to_numpy()),
                       _contacts(groom, head, contact_tolerance, layout), layout)
    limit = 2.0 * math.tan(math.radians(max_turning_deg) / 2.0)
    wbar, clipped, converged, rounds = wbar0, np.zeros(groom.n_strands, dtype=bool), False, 0
    for rounds in range(1, iterations + 1):
        if twist == "kmoch":
            sim.update_twist()
        with single_threaded_blas():
            wbar = problem.solve(_linearise(sim, layout), wbar)
        wbar, clipped = _clip(wbar, limit)
        wbar[~chosen], clipped[~chosen] = wbar0[~chosen], False
        _set_rest_curvature(sim, wbar)
        if twist != "kmoch":
            converged = True
            break
        before = sim.material_angles()
        sim.update_twist()
        if np.abs(sim.material_angles() - before).max() < ANGLE_TOLERANCE:
            converged = True
            break
    rest_twist = None
    if twist == "quasistatic":
        rest_twist = _balance_twist(groom, sim, layout)
        rest_twist[~chosen] = twist0[~chosen]
        _set_rest_twist(sim, rest_twist)
    torsion = (_twist_hessian_min(groom, sim, layout) > 0.0 if twist == "quasistatic"
               else np.ones(groom.n_strands, dtype=bool))
    with single_threaded_blas():
        residual, weight, contact_force, multipliers = _verify(groom, sim, g, problem.contacts, layout)
        shape = _position_hessian_min(groom, sim, multipliers, problem.contacts, g,
                                      layout) > -SADDLE_TOLERANCE[precision()]
    # a balance that is a saddle is worthless (the strand leaves it at once): such a strand
    # keeps its groomed rest shape (it sags, but stays put where it sags), flagged in the report
    fallback = chosen & ~clipped & ~(torsion & shape) & (not keep_saddles)
    if fallback.any():  # the balance changed: measure the rest shape actually returned
        wbar[fallback] = wbar0[fallback]
        _set_rest_curvature(sim, wbar)
        if rest_twist is not None:
            rest_twist[fallback] = twist0[fallback]
            _set_rest_twist(sim, rest_twist)
        with single_threaded_blas():
            residual, weight, contact_force, _ = _verify(groom, sim, g, problem.contacts, layout)
    report = _report(groom, wbar, wbar0, clipped, torsion | ~chosen, shape | ~chosen, fallback, chosen,
                     residual, weight, contact_force, problem.contacts, max_relative_residual, twist,
                     rounds, converged, time.perf_counter() - started)
    return groom.with_rest_curvature(wbar, rest_twist), report


def _twist_hessian_min(groom, sim, layout):
    """Smallest eigenvalue [S] of d^2E/dtheta^2 over the free edges (0..n-2), relative to the
    twist stiffness GJ / l. The Hessian is tridiagonal (an edge's angle meets its neighbours' in
    one twist and one bending term), so three central differences of dE/dtheta, each moving every
    third edge of every strand, give all of it."""
    step = 1e-5 if precision() == "float64" else 1e-2  # [rad]
    theta = sim.material_angles()
    s_count, edges = theta.shape
    hess = np.zeros((s_count, edges, 3))  # [sub, diag, super] of row k
    for colour in range(3):
        moved = np.zeros(edges, dtype=bool)
        moved[colour::3] = True
        grads = []
        for sign in (1.0, -1.0):
            sim.set_material_angles(theta + sign * step * moved[None, :])
            grads.append(sim.theta_gradient().astype(np.float64))
        d = (grads[0] - grads[1]) / (2 * step)  # column j of H lands on rows j-1, j, j+1
        for k in range(edges):
            for offset, slot in ((-1, 0), (0, 1), (1, 2)):
                if 0 <= k + offset < edges and moved[k + offset]:
                    hess[:, k, slot] = d[:, k]
    sim.set_material_angles(theta)
    voronoi = sim.model.voronoi.to_numpy().astype(np.float64)
    gj = sim.model.stiffness.to_numpy()[:, 2].astype(np.float64)
    out = np.zeros(s_count)
    for s, n in enumerate(groom.node_counts):
        free = layout.free_edges(n)
        block = hess[s, free]  # rows of the free edges; their sub/super entries couple free edges
        if not len(block):
            out[s] = 1.0
            continue
        h = np.diag(block[:, 1]) + np.diag(block[1:, 0], -1) + np.diag(block[:-1, 2], 1)
        scale = gj[s] / voronoi[s, free].mean()  # edge j's twist node j: l_0 is half the first edge
        out[s] = np.linalg.eigvalsh(0.5 * (h + h.T))[0] / scale
    return out


def _balance_twist(groom, sim, layout):
    """Rest twist [S, N] (not yet set on sim) that makes dE/dtheta = 0 on every free edge at the
    simulator's current angles: dE/dtheta_j is affine in the rest twist, d/dmbar_j of it is
    -GJ / l_j on edge j and +GJ / l_j on edge j-1, so the change dmbar_j = l_j / GJ * sum_{k>=j}
    g_k cancels the gradient g exactly. Free edges 0..n-2: node 0's twist is against the clamp
    (angle 0, no edge -1 to balance), so its rest twist mbar_0 is the sweep's last unknown."""
    grad = sim.theta_gradient().astype(np.float64)  # [S, N-1]
    voronoi = sim.model.voronoi.to_numpy().astype(np.float64)
    gj = sim.model.stiffness.to_numpy()[:, 2].astype(np.float64)
    rest_twist = sim.model.rest_twist.to_numpy().astype(np.float64)
    for s, n in enumerate(groom.node_counts):
        free = layout.free_edges(n)  # edge j's twist lives on node j
        tail = np.cumsum(grad[s, free][::-1])[::-1]  # sum_{k >= j} g_k over the free edges
        rest_twist[s, free] += voronoi[s, free] / gj[s] * tail
    return rest_twist


# ---- inputs ---------------------------------------------------------------------------------

def _check_inputs(groom, material, gravity, head, twist, regularization, max_turning_deg,
                  max_relative_residual, contact_tolerance, iterations, root):
    if not isinstance(groom, Groom):
        raise ValueError(f"groom must be a taichi_hair.Groom, got {type(groom).__name__}")
    per_strand_materials(material, groom.n_strands)  # raises naming `material`
    g = vector3("gravity", gravity, "m/s^2")
    if head is not None and not isinstance(head, Head):
        raise ValueError(f"head must be a taichi_hair.Head or None, got {type(head).__name__}")
    Twist.parse("twist", twist)
    Root.parse("root", root)
    if root != "clamped":
        raise ValueError(f"root must be 'clamped' for sag_free, got {root!r}: a pinned root is a "
                         "hinge, which cannot carry the moment of the strand's weight, so no rest "
                         "shape holds a pinned strand up")
    real("regularization", regularization, low=0.0, low_open=True)
    real("max_turning_deg", max_turning_deg, "degrees", low=0.0, high=180.0, low_open=True, high_open=True)
    real("max_relative_residual", max_relative_residual, low=0.0, low_open=True)
    real("contact_tolerance", contact_tolerance, "m", low=0.0)
    integer("iterations", iterations, low=1)
    return g


def _strand_mask(strands, count):
    if strands is None:
        return np.ones(count, dtype=bool)
    picked = np.asarray(strands)
    if picked.size == 0:
        return np.zeros(count, dtype=bool)
    if picked.dtype == bool:
        if picked.shape != (count,):
            raise ValueError(f"strands as a mask must have shape [{count}], got {list(picked.shape)}")
        return picked.copy()
    if picked.ndim != 1 or not np.issubdtype(picked.dtype, np.integer) or \
            (picked.size and (picked.min() < 0 or picked.max() >= count)):
        raise ValueError(f"strands must be strand indices in [0, {count - 1}] or a boolean mask, got {strands!r}")
    mask = np.zeros(count, dtype=bool)
    mask[picked] = True
    return mask


# ---- the linear map wbar -> elastic force -----------------------------------------------------

def _probe_rods(groom, material, twist, root):
    """The groom's rods (no stepping, no gravity: forces are elastic), built for this solve: its
    rest curvature is the solve's unknown, set each round (_set_rest_curvature)."""
    from ..solver.system import RodSystem
    return RodSystem(groom, material, twist=twist, root=root, strain="der")  # the rest values solved for are DER's


def _set_rest_curvature(sim, wbar):
    kappa = sim.model.rest_kappa
    kappa.from_numpy(wbar.astype(kappa.to_numpy().dtype))


def _set_rest_twist(sim, rest_twist):
    twist = sim.model.rest_twist
    twist.from_numpy(rest_twist.astype(twist.to_numpy().dtype))


def _linearise(sim, layout):
    """The balance's derivatives at the simulator's current rest curvature and angles: force
    [S, N, 3] N and jac_w [S, N, 3, N, 4] = dforce / dwbar (exact: the force is affine in wbar;
    one launch per (bending node, component), all strands at once)."""
    s_count, n_max = sim.groom.n_strands, sim.groom.max_nodes
    out = {"force": sim.elastic_forces(), "jac_w": np.zeros((s_count, n_max, 3, n_max, 4))}
    probe = np.zeros((s_count, n_max, 4))
    kappa = arrays.vectors(4, (s_count, n_max), probe)  # the rest curvature probed, not the model's
    f0 = sim.elastic_forces(rest_kappa=kappa)
    for i in range(n_max)[layout.bending_nodes(n_max)]:
        for c in range(4):
            probe[:, i, c] = 1.0
            kappa.from_numpy(probe.astype(arrays.np_float()))
            out["jac_w"][:, :, :, i, c] = sim.elastic_forces(rest_kappa=kappa) - f0
            probe[:, i, c] = 0.0
    return out


def _energy_weights(groom, materials, voronoi):
    """W [S, N, 4]: sqrt(EI / (4 l_i)) for each rest-curvature component (EI1 pairs with
    components 0 and 2, EI2 with 1 and 3), so |W dw|^2 is the bending energy of a change dw;
    l_i the model's Voronoi length (the clamped root node's is half the first edge)."""
    table = stiffness_table(materials)
    ei = np.stack([table["ei1"], table["ei2"], table["ei1"], table["ei2"]], axis=1)  # [S, 4]
    return np.sqrt(ei[:, None, :] / (4.0 * voronoi[:, :, None]))


# ---- contacts -----------------------------------------------------------------------------

def _contacts(groom, head, tolerance, layout):
    """Per strand: (node indices [K], outward unit normals [K, 3]) of free nodes within a
    collider's margin + tolerance at the groomed pose. As in the simulation, a collider holding
    the strand's root (root inside it) does not touch that strand."""
    empty = [(np.zeros(0, dtype=int), np.zeros((0, 3))) for _ in range(groom.n_strands)]
    if head is None or not head.colliders:
        return empty
    x = groom.positions.reshape(-1, 3)
    fields = [ColliderUnion((c,)) for c in head.colliders]
    gap = np.stack([f.sample(x) - c.margin for f, c in zip(fields, head.colliders)])  # [C, S*N]
    holds_root = np.stack([f.sample(groom.positions[:, 0]) <= 0.0 for f in fields])  # [C, S]
    gap[np.repeat(holds_root, groom.max_nodes, axis=1)] = np.inf
    nearest = np.argmin(gap, axis=0)
    close = gap.min(axis=0) < tolerance
    normals = np.zeros_like(x)
    for k, f in enumerate(fields):
        pick = close & (nearest == k)
        if pick.any():
            normals[pick] = f.gradient(x[pick])
    close = close.reshape(groom.n_strands, groom.max_nodes)
    normals = normals.reshape(close.shape + (3,))
    out = []
    for s, n in enumerate(groom.node_counts):
        nodes = np.flatnonzero(close[s, layout.free_nodes(n)]) + layout.held
        nrm = normals[s, nodes]
        nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        out.append((nodes, nrm))
    return out


# ---- BLAS threads ---------------------------------------------------------------------------

_BLAS_SYMBOLS = (("openblas_set_num_threads", "openblas_get_num_threads"),
                 ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
                 ("openblas_set_num_threads64_", "openblas_get_num_threads64_"))


@contextmanager
def single_threaded_blas():
    """Run numpy's OpenBLAS on one thread inside the block. The per-strand problems are small
    (about 100 x 150); with Taichi's CPU threads running beside it, a multithreaded OpenBLAS
    spends 10-200x longer waking threads than computing (measured: 0.9 s against 4 ms for
    one 240 x 150 lstsq on 2 cores). A no-op where no OpenBLAS is found."""
    handles = []
    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower() and "/" in line}
    except OSError:
        paths = set()
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for set_name, get_name in _BLAS_SYMBOLS:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                setter, getter = getattr(lib, set_name), getattr(lib, get_name)
                handles.append((setter, int(getter())))
                setter(1)
                break
    try:
        yield
    finally:
        for setter, threads in handles:
            setter(threads)


# ---- the per-strand solve -------------------------------------------------------------------

class _Problem:
    """The per-strand regularised balance (module docstring), linearised about the current
    rest curvature at the simulator's current angles."""

    def __init__(self, groom, sim, g, wbar0, regularization, weights, contacts, layout):
        self.groom, self.sim, self.g, self.wbar0 = groom, sim, g, wbar0
        self.regularization, self.weights, self.contacts = regularization, weights, contacts
        self.layout = layout
        self.mass = sim.model.mass.to_numpy().astype(np.float64)

    def solve(self, lin, wbar):
        """New wbar [S, N, 4] from one (exact, the force being affine) least-squares step."""
        wbar = wbar.copy()
        for s, n in enumerate(self.groom.node_counts):
            a, b, nonneg = self._system(s, n, lin, wbar)
            z = nnls(a, b, nonneg)
            m = self.layout.n_bending(n)
            wbar[s, self.layout.bending_nodes(n)] += z[: 4 * m].reshape(m, 4)
        return wbar

    def _system(self, s, n, lin, wbar):
        """(a, b, nonneg) of strand s: columns dwbar (bending nodes), tensions, contact forces;
        rows force balance (free nodes) then the regulariser."""
        layout = self.layout
        free, bending = layout.free_nodes(n), layout.bending_nodes(n)
        rows, m = 3 * layout.n_free(n), 4 * layout.n_bending(n)
        scale = max(self.mass[s, free].mean() * 9.81, 1e-300)  # reference nodal weight [N]
        side = np.hstack([_tension_columns(self.groom.positions[s, :n], layout),
                          _contact_columns(n, *self.contacts[s], layout)]) / scale
        jw = lin["jac_w"][s, free, :, bending, :].reshape(rows, m) / scale
        rhs = -(lin["force"][s, free] + self.mass[s, free, None] * self.g).reshape(-1) / scale
        w = self.weights[s, bending].reshape(-1)
        alpha = self.regularization * np.median(np.linalg.norm(jw, axis=0)) / np.median(w)
        a = np.vstack([np.hstack([jw, side]),
                       np.hstack([np.diag(alpha * w), np.zeros((m, side.shape[1]))])])
        b = np.concatenate([rhs, alpha * w * (self.wbar0[s, bending] - wbar[s, bending]).reshape(-1)])
        nonneg = np.zeros(a.shape[1], dtype=bool)
        nonneg[a.shape[1] - len(self.contacts[s][0]):] = True
        return a, b, nonneg


def _tension_columns(x, layout):
    """[3 F, E]: the force of a unit tension [N] in each tension edge j (edge 0..n-2) on the F
    free nodes (1..n-1): +t_j on node j, -t_j on node j+1 (held nodes have no rows)."""
    n = len(x)
    e = np.diff(x, axis=0)
    t = e / np.linalg.norm(e, axis=1, keepdims=True)
    edges = layout.tension_edges(n)
    cols = np.zeros((layout.n_free(n), 3, len(edges)))
    for col, j in enumerate(edges):
        if j >= layout.held:
            cols[j - layout.held, :, col] = t[j]
        cols[j + 1 - layout.held, :, col] = -t[j]
    return cols.reshape(3 * layout.n_free(n), len(edges))


def _contact_columns(n, nodes, normals, layout):
    """[3 F, K]: a unit normal force [N] at each contact node (F free nodes)."""
    cols = np.zeros((layout.n_free(n), 3, len(nodes)))
    for k, (i, nrm) in enumerate(zip(nodes, normals)):
        cols[i - layout.held, :, k] = nrm
    return cols.reshape(3 * layout.n_free(n), len(nodes))


def nnls(a, b, nonneg, max_rounds=None):
    """argmin |a z - b| with z[nonneg] >= 0 and the other entries free (Lawson-Hanson active
    set; free entries always passive). Columns are scaled to unit norm internally."""
    norms = np.linalg.norm(a, axis=0)
    norms[norms == 0] = 1.0
    a = a / norms
    passive = ~nonneg
    z = np.zeros(a.shape[1])
    z[passive] = np.linalg.lstsq(a[:, passive], b, rcond=None)[0]
    tol = 1e-12 * max(np.linalg.norm(b), 1e-300)
    for _ in range(max_rounds or 3 * a.shape[1] + 10):
        grad = a.T @ (b - a @ z)
        candidates = nonneg & ~passive & (grad > tol)
        if not candidates.any():
            break
        passive[np.argmax(np.where(candidates, grad, -np.inf))] = True
        while True:
            trial = np.zeros_like(z)
            trial[passive] = np.linalg.lstsq(a[:, passive], b, rcond=None)[0]
            negative = nonneg & passive & (trial <= 0)
            if not negative.any():
                z = trial
                break
            step = np.min(z[negative] / (z[negative] - trial[negative]))
            z = z + step * (trial - z)
            passive &= ~(nonneg & (z <= 1e-15))
            z[~passive] = 0.0
    return z / norms


def _clip(wbar, limit):
    """Each (node, edge-view) pair of wbar clipped to norm <= limit; returns (wbar, clipped [S])."""
    pairs = wbar.reshape(wbar.shape[:2] + (2, 2))
    norm = np.linalg.norm(pairs, axis=3, keepdims=True)
    factor = np.minimum(1.0, limit / np.maximum(norm, 1e-300))
    clipped = np.any(factor < 1.0, axis=(1, 2, 3))
    return (pairs * factor).reshape(wbar.shape), clipped


# ---- verification and report ----------------------------------------------------------------

def _verify(groom, sim, g, contacts, layout):
    """Net force [S] N on the free nodes at the final rest curvature and angles, with only the
    tensions and contact forces solved; the free weight [S] N, the contact force [S] N and per
    strand the multipliers (tensions of the tension edges 0..n-2, then contact forces) [N]."""
    f = sim.elastic_forces()
    mass = sim.model.mass.to_numpy().astype(np.float64)
    residual, weight, contact = (np.zeros(groom.n_strands) for _ in range(3))
    multipliers = []
    for s, n in enumerate(groom.node_counts):
        free = layout.free_nodes(n)
        rhs = -(f[s, free] + mass[s, free, None] * g).reshape(-1)
        a = np.hstack([_tension_columns(groom.positions[s, :n], layout),
                       _contact_columns(n, *contacts[s], layout)])
        tensions = len(layout.tension_edges(n))
        nonneg = np.zeros(a.shape[1], dtype=bool)
        nonneg[tensions:] = True
        z = nnls(a, rhs, nonneg)
        residual[s] = np.linalg.norm(a @ z - rhs)
        weight[s] = mass[s, free].sum() * np.linalg.norm(g)
        contact[s] = z[tensions:].sum()
        multipliers.append(z)
    return residual, weight, contact, multipliers


def _position_hessian_min(groom, sim, multipliers, contacts, g, layout):
    """Smallest eigenvalue [S] of the energy's Hessian on the constraint manifold at the groomed
    pose (angles held), in units of the strand's mean nodal weight over its mean segment
    length: negative means the balance is a saddle, and
    the strand leaves it (measured: an e-fold every ~7 ms for hair leaving the scalp sideways
    and bending down, whatever the time step). H = -dF/dx (central differences of the
    simulator's force, one node coordinate of every strand at a time) + sum_j T_j d^2|e_j|/dx^2,
    T_j the balance's tensions, projected on the motions that keep the edge lengths and the
    contact nodes' normal offsets."""
    x0 = sim.positions().astype(np.float64)
    s_count, n_max = x0.shape[:2]
    lengths = sim.model.rest_length.to_numpy()
    step = (1e-6 if precision() == "float64" else 1e-3) * float(np.median(lengths[lengths > 0]))
    hess = np.zeros((s_count, n_max, 3, n_max, 3))
    for i in range(n_max)[layout.free_nodes(n_max)]:
        for c in range(3):
            forces = []
            for sign in (1.0, -1.0):
                x = x0.copy()
                x[:, i, c] += sign * step
                sim.set_positions(x)
                forces.append(sim.elastic_forces().astype(np.float64))
            hess[:, :, :, i, c] = -(forces[0] - forces[1]) / (2.0 * step)
    sim.set_positions(x0)
    out = np.ones(s_count)
    held = layout.held
    for s, n in enumerate(groom.node_counts):
        free = layout.free_nodes(n)
        m = 3 * layout.n_free(n)
        h = hess[s, free, :, free, :].reshape(m, m)
        h = 0.5 * (h + h.T)
        e = np.diff(x0[s, :n], axis=0)
        norm = np.linalg.norm(e, axis=1)
        t = e / norm[:, None]
        rows = []
        for col, j in enumerate(layout.tension_edges(n)):  # edge j joins nodes j and j+1
            block = multipliers[s][col] * (np.eye(3) - np.outer(t[j], t[j])) / norm[j]
            row = np.zeros(m)
            for node, sign in ((j, -1.0), (j + 1, 1.0)):
                if node >= held:
                    k = 3 * (node - held)
                    row[k:k + 3] = sign * t[j]
            rows.append(row)
            a, b = 3 * (j - held), 3 * (j + 1 - held)
            h[b:b + 3, b:b + 3] += block
            if j >= held:
                h[a:a + 3, a:a + 3] += block
                h[a:a + 3, b:b + 3] -= block
                h[b:b + 3, a:a + 3] -= block
        for node, normal in zip(*contacts[s]):
            row = np.zeros(m)
            row[3 * (node - held):3 * (node - held) + 3] = normal
            rows.append(row)
        _, sv, vt = np.linalg.svd(np.array(rows))
        rank = int(np.count_nonzero(sv > 1e-10 * sv.max()))
        basis = vt[rank:].T
        eig = np.linalg.eigvalsh(basis.T @ h @ basis)
        mass = sim.model.mass.to_numpy()[s, free].mean()
        out[s] = eig[0] / max(mass * np.linalg.norm(g) / norm.mean(), 1e-300)
    return out


def _report(groom, wbar, wbar0, clipped, torsion, shape, fallback, chosen, residual, weight,
            contact_force, contacts, max_relative_residual, twist, rounds, converged, seconds):
    relative = residual / np.maximum(weight, 1e-300)
    pairs = np.linalg.norm(wbar.reshape(wbar.shape[:2] + (2, 2)), axis=3)
    turning = np.degrees(2.0 * np.arctan(pairs.max(axis=(1, 2)) / 2.0))
    return SagFreeReport(
        residual=residual, weight=weight, relative_residual=relative,
        rest_change=np.abs(wbar - wbar0).max(axis=(1, 2)), max_turning_deg=turning,
        clipped=clipped, fell_back=fallback,
        reachable=~chosen | (~clipped & ~fallback & (relative <= max_relative_residual)),
        contact_nodes=np.array([len(c[0]) for c in contacts]), contact_force=contact_force,
        torsion_stable=torsion, shape_stable=shape, solved=chosen,
        twist=twist, iterations=rounds, converged=converged, seconds=seconds)
