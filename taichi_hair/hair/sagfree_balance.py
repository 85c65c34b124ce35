"""The per-strand balance behind the sag-free start (taichi_hair.hair.sagfree, whose docstring
states the problem): which nodes and edges carry what, the linear map from rest curvature to
elastic force probed with the simulator's own kernel, the head contacts, the regularised
least-squares solve (active-set NNLS), the rest twist that balances the angles, and the check of
the balance at the final rest shape."""

from dataclasses import dataclass

import numpy as np

from ..rods import arrays
from ..rods.materials import stiffness_table
from ..rods.rod import first_node
from ..world.scene import ColliderUnion


@dataclass(frozen=True)
class BalanceLayout:
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
    def of(cls, model) -> "BalanceLayout":
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


def balance_rest_twist(groom, sim, layout):
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


# ---- the linear map wbar -> elastic force -----------------------------------------------------

def probe_rods(groom, material, twist, root):
    """The groom's rods (no stepping, no gravity: forces are elastic), built for this solve: its
    rest curvature is the solve's unknown, set each round (set_rest_curvature)."""
    from ..solver.system import RodSystem
    return RodSystem(groom, material, twist=twist, root=root, strain="der")  # the rest values solved for are DER's


def set_rest_curvature(sim, wbar):
    kappa = sim.model.rest_kappa
    kappa.from_numpy(wbar.astype(kappa.to_numpy().dtype))


def set_rest_twist(sim, rest_twist):
    twist = sim.model.rest_twist
    twist.from_numpy(rest_twist.astype(twist.to_numpy().dtype))


def linearise(sim, layout):
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


def energy_weights(groom, materials, voronoi):
    """W [S, N, 4]: sqrt(EI / (4 l_i)) for each rest-curvature component (EI1 pairs with
    components 0 and 2, EI2 with 1 and 3), so |W dw|^2 is the bending energy of a change dw;
    l_i the model's Voronoi length (the clamped root node's is half the first edge)."""
    table = stiffness_table(materials)
    ei = np.stack([table["ei1"], table["ei2"], table["ei1"], table["ei2"]], axis=1)  # [S, 4]
    return np.sqrt(ei[:, None, :] / (4.0 * voronoi[:, :, None]))


# ---- contacts -----------------------------------------------------------------------------

def head_contacts(groom, head, tolerance, layout):
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


# ---- the per-strand solve -------------------------------------------------------------------

class BalanceProblem:
    """The per-strand regularised balance (taichi_hair.hair.sagfree's docstring), linearised
    about the current rest curvature at the simulator's current angles."""

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


def clip_rest_curvature(wbar, limit):
    """Each (node, edge-view) pair of wbar clipped to norm <= limit; returns (wbar, clipped [S])."""
    pairs = wbar.reshape(wbar.shape[:2] + (2, 2))
    norm = np.linalg.norm(pairs, axis=3, keepdims=True)
    factor = np.minimum(1.0, limit / np.maximum(norm, 1e-300))
    clipped = np.any(factor < 1.0, axis=(1, 2, 3))
    return (pairs * factor).reshape(wbar.shape), clipped


# ---- verification -------------------------------------------------------------------------

def verify_balance(groom, sim, g, contacts, layout):
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
