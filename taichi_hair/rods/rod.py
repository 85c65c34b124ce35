"""Discrete elastic rod energy (bending + twist) and the elastic force with its holonomy term.

Notation of docs/model.md: interior node i lies between edges i-1 and i; its material curvature
seen from edge j in {i-1, i} is w_i^j = (kb_i . m2^j, -kb_i . m1^j), its rest value wbar_i^j
is stored in rest_kappa[s, i] = (wbar_i^{i-1}, wbar_i^i) as a vec4, and l_i is its Voronoi
length [m]. stiffness[s] = (EI1, EI2, GJ, EA) [N m^2, N m^2, N m^2, N].

    E_bend  = sum_i 1/(4 l_i) sum_{j in {i-1,i}} (w - wbar)^T diag(EI1, EI2) (w - wbar)
    E_twist = sum_i GJ (theta^i - theta^{i-1} - mbar_i)^2 / (2 l_i)

Clamped root (docs/model.md, "The clamp at the root"): node 0 is a bending and twisting node
too. Its previous "edge" is the clamp, the head-carried root frame (root_t, root_u) with
material angle 0, and its Voronoi length is half the first edge (the part of its cell inside
the hair), so the strand bends from the groomed root node. Every function taking `clamp`
(ti.template) sums over nodes first_node(clamp)..n-2; a pinned root (clamp False) is a hinge
and starts at node 1 as in plain DER.
"""

import taichi as ti

from .arrays import Ints1, Points2, Scalars1, Scalars2, Vec3s1, Vec3s2, Vec4s1, Vec4s2, edge, vec2, vec3


@ti.func
def bend_terms(kbi, d1, d2, wbar, ei1, ei2, inv_2l):
    """One (node, edge) bending term for kb_i seen in material frame (d1, d2) = (m1, m2).

    Returns (energy [J], dE/dtheta [J/rad], d2E/dtheta2 [J/rad^2], dE/dkb [J] as vec3)."""
    w = vec2(kbi.dot(d2), -kbi.dot(d1))
    dw = w - wbar
    bdw = vec2(ei1 * dw.x, ei2 * dw.y)
    energy = 0.5 * inv_2l * dw.dot(bdw)
    # dw/dtheta = -J w = (w2, -w1)
    d_theta = inv_2l * (bdw.x * w.y - bdw.y * w.x)
    d2_theta = inv_2l * (ei1 * (w.y * w.y - w.x * dw.x) + ei2 * (w.x * w.x - w.y * dw.y))
    d_kb = inv_2l * (bdw.x * d2 - bdw.y * d1)
    return energy, d_theta, d2_theta, d_kb


def first_node(clamp) -> int:
    """The first node carrying bending and twist: 0 with a clamped root, 1 at a hinge."""
    return 0 if clamp else 1


@ti.func
def edge_directors(s, j, m1: ti.template(), m2: ti.template(), root_t: ti.template(),
                   root_u: ti.template()):
    """(m1, m2) of edge j; edge -1 is the clamp: the head-carried root frame at angle 0."""
    d1 = root_u[s]
    d2 = root_t[s].cross(root_u[s])
    if j >= 0:
        d1 = m1[s, j]
        d2 = m2[s, j]
    return d1, d2


@ti.func
def node_twist(s, i, theta: ti.template(), rest_twist: ti.template()):
    """theta^i - theta^{i-1} - mbar_i [rad]; the clamp's angle (edge -1) is 0."""
    previous = 0.0
    if i >= 1:
        previous = theta[s, i - 1]
    return theta[s, i] - previous - rest_twist[s, i]


@ti.func
def twist_terms(s, j, n, first, theta: ti.template(), rest_twist: ti.template(),
                voronoi: ti.template(), gj):
    """Twist gradient dE/dtheta^j [J/rad] and its Hessian diagonal [J/rad^2] for edge j; nodes
    first..n-2 carry twist."""
    grad = 0.0
    diag = 0.0
    if j >= first:  # node j twists between edges j-1 (or the clamp) and j
        grad += gj * node_twist(s, j, theta, rest_twist) / voronoi[s, j]
        diag += gj / voronoi[s, j]
    if j + 1 <= n - 2:  # node j+1 twists between edges j and j+1
        grad -= gj * node_twist(s, j + 1, theta, rest_twist) / voronoi[s, j + 1]
        diag += gj / voronoi[s, j + 1]
    return grad, diag


@ti.func
def node_bend_terms(s, i, j, kb: ti.template(), m1: ti.template(), m2: ti.template(),
                    root_t: ti.template(), root_u: ti.template(), rest_kappa: ti.template(),
                    voronoi: ti.template(), k):
    """bend_terms of node i seen from edge j in {i-1, i} (edge -1: the clamp)."""
    d1, d2 = edge_directors(s, j, m1, m2, root_t, root_u)
    rk = rest_kappa[s, i]
    wbar = rk.zw
    if j < i:
        wbar = rk.xy
    return bend_terms(kb[s, i], d1, d2, wbar, k.x, k.y, 0.5 / voronoi[s, i])


@ti.func
def strand_energy(s, clamp: ti.template(), node_count: ti.template(), kb: ti.template(),
                  m1: ti.template(), m2: ti.template(), theta: ti.template(), root_t: ti.template(),
                  root_u: ti.template(), rest_kappa: ti.template(), rest_twist: ti.template(),
                  voronoi: ti.template(), stiffness: ti.template()):
    """E_bend + E_twist of strand s [J] with the material frames (m1, m2) and angles as they are."""
    n = node_count[s]
    k = stiffness[s]
    total = 0.0
    for i in range(ti.static(first_node(clamp)), n - 1):
        e_prev, _, _, _ = node_bend_terms(s, i, i - 1, kb, m1, m2, root_t, root_u, rest_kappa, voronoi, k)
        e_next, _, _, _ = node_bend_terms(s, i, i, kb, m1, m2, root_t, root_u, rest_kappa, voronoi, k)
        twist = node_twist(s, i, theta, rest_twist)
        total += e_prev + e_next + k.z * twist * twist * 0.5 / voronoi[s, i]
    return total


@ti.kernel
def strand_elastic_energy(clamp: ti.template(), node_count: Ints1, kb: Vec3s2, m1: Vec3s2,
                          m2: Vec3s2, theta: Scalars2, root_t: Vec3s1, root_u: Vec3s1,
                          rest_kappa: Vec4s2, rest_twist: Scalars2, voronoi: Scalars2,
                          stiffness: Vec4s1, energy: Scalars1):
    """energy[s] = E_bend + E_twist of strand s [J], material angles as they are. One thread per strand."""
    for s in range(node_count.shape[0]):
        energy[s] = strand_energy(s, clamp, node_count, kb, m1, m2, theta, root_t, root_u,
                                  rest_kappa, rest_twist, voronoi, stiffness)


@ti.kernel
def theta_gradient(clamp: ti.template(), node_count: Ints1, kb: Vec3s2, m1: Vec3s2, m2: Vec3s2,
                   theta: Scalars2, root_t: Vec3s1, root_u: Vec3s1, rest_kappa: Vec4s2,
                   rest_twist: Scalars2, voronoi: Scalars2, stiffness: Vec4s1, grad: Scalars2):
    """grad[s, j] = dE/dtheta^j [J/rad] for every edge. One thread per edge."""
    for s, j in ti.ndrange(theta.shape[0], theta.shape[1]):
        n = node_count[s]
        if j < n - 1:
            k = stiffness[s]
            first = ti.static(first_node(clamp))
            g, _ = twist_terms(s, j, n, first, theta, rest_twist, voronoi, k.z)
            if j >= first:
                _, d, _, _ = node_bend_terms(s, j, j, kb, m1, m2, root_t, root_u, rest_kappa, voronoi, k)
                g += d
            if j + 1 <= n - 2:
                _, d, _, _ = node_bend_terms(s, j + 1, j, kb, m1, m2, root_t, root_u, rest_kappa,
                                             voronoi, k)
                g += d
            grad[s, j] = g


@ti.func
def node_edges(s, i, x: ti.template(), root_t: ti.template()):
    """The two edge vectors at node i [m]; at node 0 the first is the clamp's direction (kb and
    psi are scale-free in each edge, so a unit vector serves)."""
    e0 = root_t[s]
    if i >= 1:
        e0 = edge(x, s, i - 1, i)
    return e0, edge(x, s, i, i + 1)


@ti.func
def add_node_gradient(s, i, d_prev, d_next, grad: ti.template()):
    """grad[x_{i-1}] += d_prev, grad[x_{i+1}] += d_next, grad[x_i] -= both (a function of the two
    edges at node i); at node 0 the previous edge is the clamp, which does not move."""
    if i >= 1:
        grad[s, i - 1] += d_prev
        grad[s, i] -= d_prev
    grad[s, i + 1] += d_next
    grad[s, i] -= d_next


@ti.func
def add_kb_gradient(s, i, e0, e1, kbi, g, grad: ti.template()):
    """grad[x_{i-1..i+1}] += (d kb_i / d x)^T g, current-length kb (docs/model.md)."""
    l0 = e0.norm()
    l1 = e1.norm()
    denom = l0 * l1 + e0.dot(e1)
    gk = g.dot(kbi)
    d_prev = (2.0 * g.cross(e1) + gk * (e1 + (l1 / l0) * e0)) / denom
    d_next = (2.0 * g.cross(e0) - gk * (e0 + (l0 / l1) * e1)) / denom
    add_node_gradient(s, i, d_prev, d_next, grad)


@ti.func
def add_holonomy_gradient(s, i, e0, e1, kbi, coeff, grad: ti.template()):
    """grad[x_{i-1..i+1}] += coeff * grad psi_i, psi_i the holonomy of node i."""
    add_node_gradient(s, i, coeff * kbi / (2.0 * e0.norm()), -coeff * kbi / (2.0 * e1.norm()), grad)


@ti.func
def strand_elastic_forces(s, clamp: ti.template(), x: ti.template(), node_count: ti.template(),
                          kb: ti.template(), m1: ti.template(), m2: ti.template(),
                          root_t: ti.template(), root_u: ti.template(), rest_kappa: ti.template(),
                          voronoi: ti.template(), stiffness: ti.template(), force: ti.template()):
    """force[s, :] = -dE/dx for strand s (see elastic_forces)."""
    n = node_count[s]
    k = stiffness[s]
    first = ti.static(first_node(clamp))
    for i in range(n):
        force[s, i] = vec3(0.0)
    suffix = 0.0
    for r in range(n - 1 - first):
        i = n - 2 - r
        kbi = kb[s, i]
        _, dth_prev, _, g_prev = node_bend_terms(s, i, i - 1, kb, m1, m2, root_t, root_u, rest_kappa,
                                                 voronoi, k)
        _, dth_next, _, g_next = node_bend_terms(s, i, i, kb, m1, m2, root_t, root_u, rest_kappa,
                                                 voronoi, k)
        suffix += dth_next  # now the sum over edges j >= i is complete
        e0, e1 = node_edges(s, i, x, root_t)
        add_kb_gradient(s, i, e0, e1, kbi, g_prev + g_next, force)
        add_holonomy_gradient(s, i, e0, e1, kbi, suffix, force)
        suffix += dth_prev  # the clamp's angle (i = 0) is not a variable: its term is never used
    for i in range(n):
        force[s, i] = -force[s, i]


@ti.kernel
def elastic_forces(clamp: ti.template(), x: Points2, node_count: Ints1, kb: Vec3s2, m1: Vec3s2,
                   m2: Vec3s2, root_t: Vec3s1, root_u: Vec3s1, rest_kappa: Vec4s2,
                   voronoi: Scalars2, stiffness: Vec4s1, force: Vec3s2):
    """force[s, i] = -dE/dx_i [N] with the material angles held fixed (holonomy term included).

    Twist energy does not depend on x at fixed theta in a Bishop frame. The bending energy does
    through kb and through the material frames, which turn with the reference frame's holonomy:
    dE/dx = sum_i (dkb_i/dx)^T dE/dkb_i + sum_j dE_bend/dtheta^j grad Psi^j, Psi^j = sum_{k<=j} psi_k
    (k from first_node(clamp): with a clamp, psi_0 turns the clamp frame onto edge 0). One
    thread per strand; the suffix sum C_k = sum_{j>=k} dE_bend/dtheta^j runs from tip to root."""
    for s in range(x.shape[0]):
        strand_elastic_forces(s, clamp, x, node_count, kb, m1, m2, root_t, root_u, rest_kappa,
                              voronoi, stiffness, force)


@ti.kernel
def material_curvatures(clamp: ti.template(), node_count: Ints1, kb: Vec3s2, m1: Vec3s2,
                        m2: Vec3s2, root_t: Vec3s1, root_u: Vec3s1, kappa: Vec4s2):
    """kappa[s, i] = (w_i^{i-1}, w_i^i) [1] at the bending nodes (edge -1 is the clamp), zero
    elsewhere. One thread per node."""
    for s, i in ti.ndrange(kappa.shape[0], kappa.shape[1]):
        n = node_count[s]
        value = ti.math.vec4(0.0)
        if ti.static(first_node(clamp)) <= i <= n - 2:
            p1, p2 = edge_directors(s, i - 1, m1, m2, root_t, root_u)
            value = ti.math.vec4(kb[s, i].dot(p2), -kb[s, i].dot(p1),
                                 kb[s, i].dot(m2[s, i]), -kb[s, i].dot(m1[s, i]))
        kappa[s, i] = value
