"""Model (what never changes in a run) and state (what each step changes) of all guide strands.

Arrays are Taichi ndarrays indexed [strand, node] (N = the groom's widest strand) or
[strand, edge] (N - 1 edges); a strand s uses node_count[s] nodes, the rest is padding.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from . import arrays
from .frames import update_frames, update_material_frames
from .groom import Groom
from .modes import Strain
from .materials import per_strand_materials, stiffness_table
from .rod import material_curvatures, rotation_strains

STRAINS = Strain.names()  # the strain measures (rod.py; docs/model.md, "Strains from rotations")


@dataclass(frozen=True)
class RodModel:
    """Rest data and constants. Shapes: S strands, N nodes.

    node_count int32 [S]; rest_length [S, N-1] m; voronoi [S, N] m (interior nodes: half the
    two rest edges; the two end nodes: half their edge, which is also the clamped root node's
    share of the strand); inv_mass [S, N] 1/kg (0 on the root node, which rides on the head);
    clamp: the root is clamped (node 0 bends and twists against the head-carried root frame)
    (False: a hinge or a rigid first edge); stiffness vec4 [S] (EI1, EI2, GJ [N m^2], EA [N]: EA
    is read by extensible strands only);
    rest_kappa vec4 [S, N] (wbar_i^{i-1}, wbar_i^i) [1] under the DER measure, (wbar, 0) [rad]
    under the rotation measure (strain "rotation": the rest rotation vector about m1, m2, t);
    rest_twist [S, N] rad (DER only); mass [S, N] kg (rho A l_i, every node); root_frame vec3 [S, 4]:
    the root edge's two nodes [m], its unit tangent and its reference u (the root edge's rest
    material direction m1, so the clamp's angle is 0 and the first rest angle is 0), all in head
    coordinates (the rest pose)."""

    groom: Groom
    materials: tuple
    clamp: bool
    node_count: object
    rest_length: object
    voronoi: object
    inv_mass: object
    mass: object
    stiffness: object
    rest_kappa: object
    rest_twist: object
    root_frame: object
    strain: str = "der"

    @property
    def rotation(self) -> bool:
        """The rotation strain measure (a compile-time switch of the energy kernels)."""
        return self.strain == "rotation"

    @property
    def n_strands(self) -> int:
        return self.groom.n_strands

    @property
    def max_nodes(self) -> int:
        return self.groom.max_nodes


# RodState.history's slots: the friction totals and the collider queries of the step's
# projection (every integrator), then the implicit step's history
(FRICTION_SHIFT, FRICTION_PUSH, CONTACT_QUERY, CONTACT_CLEARANCE, CONTACT_NORMAL, HIST_V, HIST_DX,
 HIST_ELASTIC, HIST_CHANGE) = range(9)
CONTACT_SLOTS = CONTACT_NORMAL + 1  # the slots every integrator has

# columns of RodState.counters: running maxima / counts since the last stats reset, and the
# first step at which a strand went bad in the last launch (-1: none)
COUNTERS = {"projection_iterations": 0, "projection_cap_hits": 1, "projection_stalls": 2,
            "twist_iterations": 3, "bad_step": 4, "twist_cap_hits": 5, "twist_stalls": 6,
            "twist_branch_switches": 7, "projection_iterations_sum": 8, "projections": 9,
            "step_stride": 10}
# counters[s, "step_stride"] is no counter but strand s's step in launch steps (1, or the
# simulator's substeps over the strand's own: solver/stability.strand_substeps), read by the fused
# step where StageFlags.strides is on; it lives here because the fused kernel's 64 argument slots
# are all taken (docs/architecture.md)


@dataclass
class RodState:
    """Per-step state [S, N] / [S, N-1] / [S]: positions x [m], velocities v [m/s], material
    angles theta [rad], Bishop frames (bishop_u, bishop_v), material frames (m1, m2),
    curvature binormals kb [1], the head-carried root reference (root_t, root_u), forces [N],
    positions before the step x_prev [m], per-strand solver counters (running maxima since the
    last stats reset), and scratch arrays."""

    x: object
    v: object
    theta: object
    bishop_u: object
    bishop_v: object
    m1: object
    m2: object
    kb: object
    root_t: object
    root_u: object
    force: object
    x_prev: object
    dx: object  # [S, N] vec3: the step's displacement of each node (strand_velocities)
    scratch_edge: tuple  # three [S, N-1] float arrays
    strand_scalar: object  # [S] float
    counters: object  # [S, len(COUNTERS)] int, see COUNTERS
    residuals: object  # [S, 2] float: projection and twist residual maxima
    # history [S, N, 9] vec3 with the implicit step, [S, N, 5] without (one array: Taichi caps
    # a kernel's argument count): [..., FRICTION_SHIFT] the friction shift given to the node so
    # far in this step's projection [m, world axes], [..., FRICTION_PUSH].x its pushes so far [m],
    # .y the collider holding it, .z minus its friction coefficient while static friction holds it
    # (0 if it slides), the coefficient once the step's friction has settled
    # (collisions.contact_with_friction, projection.settle_friction), [..., CONTACT_QUERY]
    # the node's step displacement dx [m] when the colliders were last queried for it and
    # [..., CONTACT_CLEARANCE] (its smallest distance beyond the margins of the analytic shapes and
    # hands, the groups this pass queries it for as bits, the same for the distance grid [m])
    # (collisions.plan_queries), [..., CONTACT_NORMAL] the outward
    # normal [1, world axes] of the collider that last pushed the node this step, zero if none or
    # released (the projection holds the node on that surface: projection.inverse_mass_times);
    # the implicit step's history: [..., HIST_V] the
    # velocities one step back [m/s], [..., HIST_DX] the last step's displacements [m],
    # [..., HIST_ELASTIC] the last step's elastic forces [N] (NaN: none yet), [..., HIST_CHANGE]
    # this step's elastic forces minus those [N]
    history: object = None
    # the implicit step's system (solver/implicit.py); [1, 1] placeholders when the integrator
    # is explicit
    # [S, N-1]: the edges' tensions at the last step [N] (the implicit step's, or an extensible
    # strand's, accumulated by its projection; a [1, 1] placeholder otherwise)
    tension: object = None
    blocks: object = None  # [S, N, 3] float64 5x5: the block-banded saddle-point matrix (diagonal,
    # 1st and 2nd sub-diagonal blocks of each node's row), then its factor
    block_rhs: object = None  # [S, N] float64 vec5: the right-hand side, then the solution


def _voronoi_and_mass(groom: Groom, linear_density: np.ndarray):
    s_count, n_max = groom.n_strands, groom.max_nodes
    rest_length = np.zeros((s_count, n_max - 1))
    voronoi = np.ones((s_count, n_max))
    inv_mass = np.zeros((s_count, n_max))
    mass = np.zeros((s_count, n_max))
    for s in range(s_count):
        n = groom.node_counts[s]
        lengths = np.linalg.norm(np.diff(groom.strand(s), axis=0), axis=1)
        rest_length[s, : n - 1] = lengths
        vor = np.zeros(n)
        vor[:-1] += 0.5 * lengths
        vor[1:] += 0.5 * lengths
        voronoi[s, :n] = vor
        mass[s, :n] = linear_density[s] * vor
        inv_mass[s, 1:n] = 1.0 / mass[s, 1:n]
    return rest_length, voronoi, inv_mass, mass


def perpendicular_unit(t: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to each unit row of t [S, 3] (deterministic)."""
    helper = np.where(np.abs(t[:, [2]]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = helper - np.sum(helper * t, axis=1)[:, None] * t
    return u / np.linalg.norm(u, axis=1)[:, None]


def allocate_state(groom: Groom, root_t: np.ndarray, root_u: np.ndarray, implicit: bool = False,
                   extensible: bool = False) -> RodState:
    s_count, n_max = groom.n_strands, groom.max_nodes
    edges = (s_count, n_max - 1)
    nodes = (s_count, n_max) if implicit else (1, 1)
    return RodState(
        x=arrays.vectors(3, (s_count, n_max), groom.positions, dtype=ti.f64),
        v=arrays.vectors(3, (s_count, n_max)),
        theta=arrays.scalars(edges),
        bishop_u=arrays.vectors(3, edges), bishop_v=arrays.vectors(3, edges),
        m1=arrays.vectors(3, edges), m2=arrays.vectors(3, edges),
        kb=arrays.vectors(3, (s_count, n_max)),
        root_t=arrays.vectors(3, (s_count,), root_t), root_u=arrays.vectors(3, (s_count,), root_u),
        force=arrays.vectors(3, (s_count, n_max)),
        x_prev=arrays.vectors(3, (s_count, n_max), groom.positions, dtype=ti.f64),
        dx=arrays.vectors(3, (s_count, n_max)),
        scratch_edge=tuple(arrays.scalars(edges) for _ in range(3)),
        strand_scalar=arrays.scalars((s_count,)),
        counters=arrays.ints((s_count, len(COUNTERS)), 0),
        residuals=arrays.scalars((s_count, 2)),
        history=arrays.vectors(3, (s_count, n_max, HIST_CHANGE + 1 if implicit else CONTACT_SLOTS)), tension=arrays.scalars(edges if implicit or extensible else (1, 1)),
        blocks=arrays.matrices(arrays.BLOCK, nodes + (3,), ti.f64),
        block_rhs=arrays.vectors(arrays.BLOCK, nodes, dtype=ti.f64),
    )


def align_to_curvature(kb: np.ndarray, bishop_u: np.ndarray, bishop_v: np.ndarray,
                       node_counts: np.ndarray) -> np.ndarray:
    """Rest angles [S, N-1] putting m1 (the major axis) along the curvature binormals, as Kmoch's
    rule does, continuous along the strand (each edge takes the branch nearest its predecessor);
    straight stretches inherit the angle of the curved part next to them."""
    s_count, n_edges = bishop_u.shape[:2]
    theta = np.full((s_count, n_edges), np.nan)
    prev = np.full(s_count, np.nan)
    for j in range(n_edges):
        doubled = np.zeros((s_count, 2))
        for node in (j, j + 1):
            interior = (node >= 1) & (node <= node_counts - 2)
            ku = np.sum(kb[:, node] * bishop_u[:, j], axis=1) * interior
            kv = np.sum(kb[:, node] * bishop_v[:, j], axis=1) * interior
            doubled += np.stack([ku * ku - kv * kv, 2 * ku * kv], axis=1)
        curved = np.linalg.norm(doubled, axis=1) > 1e-12
        eta = 0.5 * np.arctan2(doubled[:, 1], doubled[:, 0])
        branch = np.where(np.isnan(prev), eta, eta + np.pi * np.round((np.nan_to_num(prev) - eta) / np.pi))
        theta[:, j] = np.where(curved, branch, prev)
        prev = theta[:, j]
    for s in range(s_count):  # fill the leading straight part backwards, and all-straight strands
        row = theta[s]
        known = np.flatnonzero(~np.isnan(row))
        row[: known[0] if len(known) else n_edges] = row[known[0]] if len(known) else 0.0
    return theta


def build(groom: Groom, material, clamp: bool = True, implicit: bool = False,
          extensible: bool = False, strain: str = "der") -> tuple[RodModel, RodState]:
    """Model and state for `groom` with `material` (one Material or one per strand), the state
    at the rest shape with rest material frames; clamp: node 0 bends against the root frame
    (root="clamped"; False for a hinge or a rigid first edge); implicit: allocate the implicit
    step's arrays; extensible: allocate the edge tensions (Simulator(extensible=True)); strain:
    one of STRAINS, the strain measure whose rest values rest_kappa holds.
    Rest curvatures and twists are measured on the rest shape with the same kernels the
    simulation uses, so the rest shape has zero energy."""
    materials = per_strand_materials(material, groom.n_strands)
    table = stiffness_table(materials)
    rest_length, voronoi, inv_mass, mass = _voronoi_and_mass(groom, table["linear_density"])
    root_t = groom.positions[:, 1] - groom.positions[:, 0]
    root_t /= np.linalg.norm(root_t, axis=1)[:, None]
    root_u = perpendicular_unit(root_t)
    state = allocate_state(groom, root_t, root_u, implicit, extensible)
    node_count = arrays.ints((groom.n_strands,), groom.node_counts)
    update_frames(clamp, state.x, node_count, state.root_t, state.root_u, state.theta, state.bishop_u,
                  state.bishop_v, state.m1, state.m2, state.kb)
    elliptic = np.array([m.ellipticity > 1.0 for m in materials])
    rest_theta = np.zeros((groom.n_strands, groom.max_nodes - 1))
    if elliptic.any():
        aligned = align_to_curvature(state.kb.to_numpy(), state.bishop_u.to_numpy(),
                                     state.bishop_v.to_numpy(), groom.node_counts)
        rest_theta[elliptic] = aligned[elliptic]
        # turn the reference onto the root edge's rest m1: every Bishop frame turns with it (the
        # transport commutes with turns about the tangent), so each angle drops by theta^0
        c, s_ = np.cos(rest_theta[:, :1]), np.sin(rest_theta[:, :1])
        root_u = c * root_u + s_ * np.cross(root_t, root_u)
        rest_theta -= rest_theta[:, :1]
        state.root_u.from_numpy(root_u.astype(arrays.np_float()))
        update_frames(clamp, state.x, node_count, state.root_t, state.root_u, state.theta,
                      state.bishop_u, state.bishop_v, state.m1, state.m2, state.kb)
    state.theta.from_numpy(rest_theta.astype(arrays.np_float()))
    update_material_frames(node_count, state.theta, state.bishop_u, state.bishop_v, state.m1, state.m2)
    rest_kappa = arrays.vectors(4, (groom.n_strands, groom.max_nodes))
    stiffness = arrays.vectors(4, (groom.n_strands,), np.stack(
        [table["ei1"], table["ei2"], table["gj"], table["axial"]], axis=1))
    voronoi_lengths = arrays.scalars(voronoi.shape, voronoi)
    if strain == "rotation":  # (a groom's own rest curvatures are DER's: world.options.SolverOptions.for_groom)
        rotation_strains(clamp, node_count, state.kb, state.m1, state.m2, state.theta, stiffness,
                         voronoi_lengths, rest_kappa)
    else:
        material_curvatures(clamp, node_count, state.kb, state.m1, state.m2, state.root_t, state.root_u,
                            rest_kappa)
    if groom.rest_curvature is not None:  # e.g. a sag-free rest shape: not the groomed one
        rest_kappa.from_numpy(np.asarray(groom.rest_curvature).astype(arrays.np_float()))
    rest_twist = np.zeros((groom.n_strands, groom.max_nodes))
    rest_twist[:, 1:-1] = np.diff(rest_theta, axis=1)
    if groom.rest_twist is not None:  # a sag-free rest shape holds the groomed angles in balance
        rest_twist = np.asarray(groom.rest_twist, dtype=np.float64)
    model = RodModel(
        groom=groom, materials=tuple(materials), clamp=bool(clamp), node_count=node_count,
        rest_length=arrays.scalars(rest_length.shape, rest_length),
        voronoi=voronoi_lengths,
        inv_mass=arrays.scalars(inv_mass.shape, inv_mass),
        mass=arrays.scalars(mass.shape, mass),
        stiffness=stiffness,
        rest_kappa=rest_kappa, rest_twist=arrays.scalars(rest_twist.shape, rest_twist),
        root_frame=arrays.vectors(3, (groom.n_strands, 4), np.concatenate(
            [groom.positions[:, :2], root_t[:, None], root_u[:, None]], axis=1)),
        strain=strain,
    )
    return model, state
