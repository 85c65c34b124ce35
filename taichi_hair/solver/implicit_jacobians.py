"""The strain Jacobians of the implicit step (taichi_hair.solver.implicit): per bending and
twisting node, the derivatives of its strains (curvature in the material frame, twist) over
the positions of nodes i-1..i+1 and the free edges' material angles, under either strain
measure (DER's curvature binormal or the rotation measure), with the energy's weights. Taichi
functions, in float64 in both precisions."""

import taichi as ti

from ..rods.arrays import mat_block, vec3d, vec_block
from ..rods.frames import material_directors
from ..rods.rod import SERIES_BELOW, edge_directors, first_node, node_edges, node_turn, rotation_scalars

mat3d = ti.types.matrix(3, 3, ti.f64)  # the stiffness is assembled in float64 (arrays.mat_block)


@ti.func
def skew(a):
    """The cross-product matrix: skew(a) b = a x b (float64)."""
    return mat3d([[0.0, -a.z, a.y], [a.z, 0.0, -a.x], [-a.y, a.x, 0.0]])


@ti.func
def kb_jacobians(e0, e1, kbi):
    """(P, N) = (d kb_i / d x_{i-1}, d kb_i / d x_{i+1}) [1/m] for the edges e0 = x_i - x_{i-1},
    e1 = x_{i+1} - x_i; d kb_i / d x_i = -(P + N). From kb = 2 e0 x e1 / (|e0||e1| + e0.e1)."""
    l0 = e0.norm()
    l1 = e1.norm()
    denom = l0 * l1 + e0.dot(e1)
    p = (2.0 * skew(e1) + kbi.outer_product(e1 + (l1 / l0) * e0)) / denom
    q = (2.0 * skew(e0) - kbi.outer_product(e0 + (l0 / l1) * e1)) / denom
    return p, q


@ti.func
def node_strain_jacobians(s, i, clamp: ti.template(), twist_free: ti.template(), rotation: ti.template(),
                          md: ti.template(), st: ti.template()):
    """Node i's strains and their Jacobians in its three nodes' unknowns (docs/model.md, "The
    implicit step", Stiffness). The strains: w_i^{i-1} (2), w_i^i (2), the twist m_i; returns
    (J0, J1, J2, W): J_a [5x5] the strains' derivatives in node i-1+a's unknowns (velocity
    columns 0-2: its position [1/m]; column 4: the angle of edge i-2+a [1/rad]; column 3, the
    multiplier, 0), W [5] the strains' stiffnesses (EI1, EI2, EI1, EI2) / (2 l_i), GJ / l_i
    [J]. The frames are taken as transported in time, so every derivative is local: the
    material frames' own turning drops out of dw/dx (kb_i is normal to both tangents) and the
    twist gains the reference twist's gradient, -grad psi_i. At a clamped node 0 the previous
    edge is the clamp, which does not move (J0 = 0), and its angle is not an unknown. Without
    twist_free (twist="none") the angles are not solved for: no twist row, no angle columns.
    rotation: the rotation measure's strain w (3, rows 0-2; rotation_strain_jacobians)."""
    first = ti.static(first_node(clamp))
    edge0, edge1 = node_edges(s, i, st.x, st.root_t)
    e0 = ti.cast(edge0, ti.f64)
    e1 = ti.cast(edge1, ti.f64)
    kbi = ti.cast(st.kb[s, i], ti.f64)
    p, q = kb_jacobians(e0, e1, kbi)
    psi_prev = kbi / (2.0 * e0.norm())  # grad psi_i at x_{i-1}; at x_{i+1}: psi_next
    psi_next = -kbi / (2.0 * e1.norm())
    g0 = p
    g1 = -(p + q)
    if i == 0:
        g0 = mat3d(0.0)
        g1 = -q
        psi_prev = vec3d(0.0)
    grads = (g0, g1, q)
    psis = (psi_prev, -(psi_prev + psi_next), psi_next)
    jac = [mat_block(0.0), mat_block(0.0), mat_block(0.0)]
    k = ti.cast(md.stiffness[s], ti.f64)
    inv_l = 1.0 / ti.cast(md.voronoi[s, i], ti.f64)
    weight = vec_block(0.0)
    if ti.static(rotation):
        weight = rotation_strain_jacobians(s, i, first, twist_free, kbi, grads, psis, k, inv_l, st, jac)
    else:
        weight = der_strain_jacobians(s, i, first, twist_free, kbi, grads, psis, k, inv_l, st, jac)
    return jac[0], jac[1], jac[2], weight


@ti.func
def der_strain_jacobians(s, i, first, twist_free: ti.template(), kbi, grads: ti.template(),
                         psis: ti.template(), k, inv_l, st: ti.template(), jac: ti.template()):
    """node_strain_jacobians' DER rows: w_i^{i-1} (rows 0-1), w_i^i (2-3), the twist (4), into
    jac; returns their weights."""
    for j in ti.static(range(2)):
        d1, d2 = edge_directors(s, i - 1 + j, st.m1, st.m2, st.root_t, st.root_u)
        m1 = ti.cast(d1, ti.f64)
        m2 = ti.cast(d2, ti.f64)
        for a in ti.static(range(3)):
            r1 = grads[a].transpose() @ m2
            r2 = -(grads[a].transpose() @ m1)
            for c in ti.static(range(3)):
                jac[a][2 * j, c] = r1[c]
                jac[a][2 * j + 1, c] = r2[c]
        if ti.static(twist_free):
            if i - 1 + j >= first:  # the angle of edge i-1+j, stored with node i+j: dw/dtheta = (w2, -w1)
                jac[1 + j][2 * j, 4] = -kbi.dot(m1)
                jac[1 + j][2 * j + 1, 4] = -kbi.dot(m2)
                jac[1 + j][4, 4] = 2.0 * j - 1.0  # m_i = theta^i - theta^{i-1} + ...
    weight = vec_block(0.5 * k.x * inv_l, 0.5 * k.y * inv_l, 0.5 * k.x * inv_l, 0.5 * k.y * inv_l, 0.0)
    if ti.static(twist_free):
        weight[4] = k.z * inv_l
        for a in ti.static(range(3)):
            for c in ti.static(range(3)):
                jac[a][4, c] = -psis[a][c]
    return weight


@ti.func
def rotation_strain_jacobians(s, i, first, twist_free: ti.template(), kbi, grads: ti.template(),
                              psis: ti.template(), k, inv_l, st: ti.template(), jac: ti.template()):
    """node_strain_jacobians' rotation rows (rods/rod.py rotation_node_terms): w = G (k/2, sn),
    k = kb in the mid frame, a function of kb, the mean angle beta and the turn. With the frames
    transported in time dk = mid^T dkb + (dk/dbeta) dbeta, the turn = theta^i - theta^{i-1} less
    the reference twist's change (d turn = dtheta^i - dtheta^{i-1} - grad psi_i . dx, as the DER
    twist) and the mid frame, edge i's frame turned back by turn/2, at
    dbeta = (dtheta^{i-1} + dtheta^i) / 2 + grad psi_i . dx / 2. Into jac (rows 0-2); returns
    the weights (EI2, EI1, GJ) / l_i."""
    turn = ti.cast(node_turn(s, i, st.theta), ti.f64)
    c = ti.cos(0.5 * turn)
    sn = ti.sin(0.5 * turn)
    mid1, mid2 = material_directors(ti.cast(st.m1[s, i], ti.f64), ti.cast(st.m2[s, i], ti.f64), -0.5 * turn)
    kv = ti.Vector([kbi.dot(mid1), kbi.dot(mid2)], dt=ti.f64)
    G, P, Q, Z = rotation_scalars(0.25 * kv.dot(kv), sn, c, ti.static(SERIES_BELOW["float64"]))
    u = vec3d(0.5 * kv.x, 0.5 * kv.y, sn)
    w_kv1 = 0.5 * Q * kv.x * u + vec3d(0.5 * G, 0.0, 0.0)  # dw / dk1, dk2
    w_kv2 = 0.5 * Q * kv.y * u + vec3d(0.0, 0.5 * G, 0.0)
    w_beta = G * vec3d(0.5 * kv.y, -0.5 * kv.x, 0.0)
    w_turn = vec3d(sn * P * 0.5 * kv.x, sn * P * 0.5 * kv.y, sn * sn * P + 0.5 * G * c)
    for a in ti.static(range(3)):
        dk1 = grads[a].transpose() @ mid1
        dk2 = grads[a].transpose() @ mid2
        for c3 in ti.static(range(3)):
            column = w_kv1 * dk1[c3] + w_kv2 * dk2[c3]
            if ti.static(twist_free):
                column += (0.5 * w_beta - w_turn) * psis[a][c3]
            for r in ti.static(range(3)):
                jac[a][r, c3] = column[r]
    if ti.static(twist_free):
        before = 0.5 * w_beta - w_turn  # dw / dtheta^{i-1}, held by node i
        after = 0.5 * w_beta + w_turn  # dw / dtheta^i, held by node i+1
        for r in ti.static(range(3)):
            if i - 1 >= first:
                jac[1][r, 4] = before[r]
            jac[2][r, 4] = after[r]
    return vec_block(k.y * inv_l, k.x * inv_l, k.z * inv_l, 0.0, 0.0)
