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

The clamp is the simulator's (taichi_hair.rods.rod; `BalanceLayout` says which nodes and edges are what):
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

from dataclasses import dataclass
import math
import time

import numpy as np

from ..rods.groom import Groom
from ..rods.materials import per_strand_materials
from ..world.scene import Head
from ..runtime import precision
from ..rods.modes import Root, Twist
from ..validation import integer, real, vector3
from .blas_threads import single_threaded_blas
from .sagfree_balance import (BalanceLayout, BalanceProblem, balance_rest_twist, clip_rest_curvature,
                              energy_weights, head_contacts, linearise, probe_rods, set_rest_curvature,
                              set_rest_twist, verify_balance)
from .sagfree_stability import position_hessian_min, twist_hessian_min

ANGLE_TOLERANCE = 1e-7  # [rad]: the twist update no longer moves the angles
# a smallest eigenvalue below -this x (nodal weight / segment length) is a saddle, not a minimum
# (the scale gravity's destabilising stiffness has); float32 force differences are noisier
SADDLE_TOLERANCE = {"float64": 1e-3, "float32": 1e-2}


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
    sim = probe_rods(groom, material, twist, root)
    layout = BalanceLayout.of(sim.model)
    twist0 = sim.model.rest_twist.to_numpy().astype(np.float64)
    wbar0 = sim.model.rest_kappa.to_numpy().astype(np.float64)
    problem = BalanceProblem(groom, sim, g, wbar0, regularization,
                             energy_weights(groom, per_strand_materials(material, groom.n_strands),
                                            sim.model.voronoi.to_numpy()),
                             head_contacts(groom, head, contact_tolerance, layout), layout)
    limit = 2.0 * math.tan(math.radians(max_turning_deg) / 2.0)
    wbar, clipped, converged, rounds = wbar0, np.zeros(groom.n_strands, dtype=bool), False, 0
    for rounds in range(1, iterations + 1):
        if twist == "kmoch":
            sim.update_twist()
        with single_threaded_blas():
            wbar = problem.solve(linearise(sim, layout), wbar)
        wbar, clipped = clip_rest_curvature(wbar, limit)
        wbar[~chosen], clipped[~chosen] = wbar0[~chosen], False
        set_rest_curvature(sim, wbar)
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
        rest_twist = balance_rest_twist(groom, sim, layout)
        rest_twist[~chosen] = twist0[~chosen]
        set_rest_twist(sim, rest_twist)
    torsion = (twist_hessian_min(groom, sim, layout) > 0.0 if twist == "quasistatic"
               else np.ones(groom.n_strands, dtype=bool))
    with single_threaded_blas():
        residual, weight, contact_force, multipliers = verify_balance(groom, sim, g, problem.contacts,
                                                                      layout)
        shape = position_hessian_min(groom, sim, multipliers, problem.contacts, g,
                                     layout) > -SADDLE_TOLERANCE[precision()]
    # a balance that is a saddle is worthless (the strand leaves it at once): such a strand
    # keeps its groomed rest shape (it sags, but stays put where it sags), flagged in the report
    fallback = chosen & ~clipped & ~(torsion & shape) & (not keep_saddles)
    if fallback.any():  # the balance changed: measure the rest shape actually returned
        wbar[fallback] = wbar0[fallback]
        set_rest_curvature(sim, wbar)
        if rest_twist is not None:
            rest_twist[fallback] = twist0[fallback]
            set_rest_twist(sim, rest_twist)
        with single_threaded_blas():
            residual, weight, contact_force, _ = verify_balance(groom, sim, g, problem.contacts, layout)
    report = _report(groom, wbar, wbar0, clipped, torsion | ~chosen, shape | ~chosen, fallback, chosen,
                     residual, weight, contact_force, problem.contacts, max_relative_residual, twist,
                     rounds, converged, time.perf_counter() - started)
    return groom.with_rest_curvature(wbar, rest_twist), report


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
