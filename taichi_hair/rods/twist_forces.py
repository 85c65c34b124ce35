"""The elastic force's terms from material angles that follow the centreline: under Kmoch's rule
(elliptic strands, docs/model.md, "Kmoch's rule and energy consistency") and on edges whose
frame a twist-holding clip holds in space (docs/model.md, "Clips that hold twist"). Each adds
to the fixed-angle force of rod.elastic_forces, so the sum is minus the total derivative of
E(x, theta(x)).

The ti.funcs take the rods' model and state bundles whole (arrays.ModelArgs,
arrays.StateArgs) and add to the state's force row.
"""

import taichi as ti

from .arrays import ModelArgs, StateArgs, vec2, Vec3s3
from .rod import add_holonomy_gradient, add_kb_gradient, first_node, node_edges
from .twist import edge_theta_gradient, edge_twist_held, MIN_CURVATURE_SQ


@ti.func
def strand_kmoch_forces(s, clamp: ti.template(), md: ti.template(), st: ti.template()):
    """st.force[s] -= sum_j dE/dtheta^j dtheta_kmoch^j/dx: with Kmoch's rule the angles are a
    function of the centreline, so the force of E(x, theta_kmoch(x)) needs this term on top of
    the fixed-angle gradient (docs/model.md, "Kmoch's rule and energy consistency"). Elliptic
    strands only (round ones are solved to dE/dtheta = 0). With eta^j = arg(S_j) / 2,
    S_j = sum_n z_n^2, z_n = kb_n . (u^j + i v^j) over the edge's end nodes n in {j, j+1}:
    d eta^j = sum_n d kb_n . Im(z_n (u + i v) / S_j) - d Psi^j, the last term because the angle
    is measured from the Bishop vector u^j, which turns with the holonomy. md, st: the rods'
    model and state arrays (arrays.ModelArgs, arrays.StateArgs)."""
    x, bishop_u, bishop_v, kb, root_t, force = ti.static(st.x, st.bishop_u, st.bishop_v, st.kb, st.root_t, st.force)
    k = md.stiffness[s]
    if k.x != k.y:
        n = md.node_count[s]
        first = ti.static(first_node(clamp))
        suffix = 0.0
        for r in range(n - 1 - first):
            j = n - 2 - r
            g = edge_theta_gradient(s, j, n, first, False, md, st, k)
            suffix += g  # sum over free edges >= j: the coefficient of grad psi_j
            e0, e1 = node_edges(s, j, x, root_t)
            add_holonomy_gradient(s, j, e0, e1, kb[s, j], suffix, force)
            u = bishop_u[s, j]
            v = bishop_v[s, j]
            total = vec2(0.0)
            for node in ti.static(range(2)):
                z = vec2(kb[s, j + node].dot(u), kb[s, j + node].dot(v))
                total += vec2(z.x * z.x - z.y * z.y, 2.0 * z.x * z.y)
            norm_sq = total.dot(total)
            if ti.sqrt(norm_sq) > MIN_CURVATURE_SQ:  # else the rule keeps theta: no derivative
                for node in ti.static(range(2)):
                    i = j + node
                    if i <= n - 2:  # the tip has no curvature
                        z = vec2(kb[s, i].dot(u), kb[s, i].dot(v))
                        q = vec2(z.x * total.x + z.y * total.y, z.y * total.x - z.x * total.y) / norm_sq
                        a0, a1 = node_edges(s, i, x, root_t)
                        add_kb_gradient(s, i, a0, a1, kb[s, i], -g * (q.x * v + q.y * u), force)


@ti.kernel
def kmoch_forces(clamp: ti.template(), md: ModelArgs, st: StateArgs):
    """strand_kmoch_forces for every strand (added to st.force [S, N] N). One thread per strand."""
    for s in range(st.x.shape[0]):
        strand_kmoch_forces(s, clamp, md, st)


@ti.func
def strand_held_twist_forces(s, clamp: ti.template(), rotation: ti.template(), md: ti.template(), st: ti.template(),
                             clip: ti.template()):
    """st.force[s] += g_c grad Psi^c for every edge c whose material frame a clip holds in space
    (clip[s, c, 1].z > 0; docs/model.md, "Clips that hold twist"). Its angle from the Bishop frame
    is theta^c = alpha_c - Psi^c(x), alpha_c the clip's fixed angle and Psi^c = sum_{k<=c} psi_k
    the Bishop frame's turn from the root to edge c, so E(x) = E(x, theta^c(x)) has the extra
    gradient dE/dtheta^c (-grad Psi^c) on top of the fixed-angle gradient that elastic_forces
    computes: writhe traded for twist, which is what buckles a twisted rod. g_c = dE/dtheta^c
    [J/rad] (bending and twist). md, st: as in strand_kmoch_forces."""
    x, kb, root_t, force = ti.static(st.x, st.kb, st.root_t, st.force)
    n = md.node_count[s]
    k = md.stiffness[s]
    first = ti.static(first_node(clamp))
    for c in range(first, n - 1):
        if edge_twist_held(s, c, True, clip):
            g = edge_theta_gradient(s, c, n, first, rotation, md, st, k)
            for i in range(first, c + 1):
                e0, e1 = node_edges(s, i, x, root_t)
                add_holonomy_gradient(s, i, e0, e1, kb[s, i], g, force)


@ti.kernel
def held_twist_forces(clamp: ti.template(), rotation: ti.template(), md: ModelArgs, st: StateArgs, clip: Vec3s3):
    """strand_held_twist_forces for every strand (added to st.force [S, N] N). One thread per strand."""
    for s in range(st.x.shape[0]):
        strand_held_twist_forces(s, clamp, rotation, md, st, clip)
