"""Discrete elastic rod energy (bending + twist) and the elastic force with its holonomy term.

Notation of DESIGN.md: interior node i lies between edges i-1 and i; its material curvature
seen from edge j in {i-1, i} is w_i^j = (kb_i . m2^j, -kb_i . m1^j), its rest value wbar_i^j
is stored in rest_kappa[s, i] = (wbar_i^{i-1}, wbar_i^i) as a vec4, and l_i is its Voronoi
length [m]. stiffness[s] = (EI1, EI2, GJ, rho A) [N m^2, N m^2, N m^2, kg/m].

    E_bend  = sum_i 1/(4 l_i) sum_{j in {i-1,i}} (w - wbar)^T diag(EI1, EI2) (w - wbar)
    E_twist = sum_i GJ (theta^i - theta^{i-1} - mbar_i)^2 / (2 l_i)
"""

import taichi as ti

from .arrays import Ints1, Scalars1, Scalars2, Vec3s2, Vec4s1, Vec4s2, vec2, vec3


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


@ti.func
def twist_terms(s, j, n, theta: ti.template(), rest_twist: ti.template(), voronoi: ti.template(), gj):
    """Twist gradient dE/dtheta^j [J/rad] and its Hessian diagonal [J/rad^2] for edge j."""
    grad = 0.0
    diag = 0.0
    if j >= 1:  # node j is interior: twist theta^j - theta^{j-1}
        grad += gj * (theta[s, j] - theta[s, j - 1] - rest_twist[s, j]) / voronoi[s, j]
        diag += gj / voronoi[s, j]
    if j + 1 <= n - 2:  # node j+1 is interior: twist theta^{j+1} - theta^j
        grad -= gj * (theta[s, j + 1] - theta[s, j] - rest_twist[s, j + 1]) / voronoi[s, j + 1]
        diag += gj / voronoi[s, j + 1]
    return grad, diag


@ti.kernel
def strand_elastic_energy(node_count: Ints1, kb: Vec3s2, m1: Vec3s2, m2: Vec3s2, theta: Scalars2,
                          rest_kappa: Vec4s2, rest_twist: Scalars2, voronoi: Scalars2,
                          stiffness: Vec4s1, energy: Scalars1):
    """energy[s] = E_bend + E_twist of strand s [J], material angles as they are. One thread per strand."""
    for s in range(node_count.shape[0]):
        n = node_count[s]
        k = stiffness[s]
        total = 0.0
        for i in range(1, n - 1):
            inv_2l = 0.5 / voronoi[s, i]
            rk = rest_kappa[s, i]
            e_prev, _, _, _ = bend_terms(kb[s, i], m1[s, i - 1], m2[s, i - 1], rk.xy, k.x, k.y, inv_2l)
            e_next, _, _, _ = bend_terms(kb[s, i], m1[s, i], m2[s, i], rk.zw, k.x, k.y, inv_2l)
            twist = theta[s, i] - theta[s, i - 1] - rest_twist[s, i]
            total += e_prev + e_next + k.z * twist * twist * inv_2l
        energy[s] = total


@ti.kernel
def theta_gradient(node_count: Ints1, kb: Vec3s2, m1: Vec3s2, m2: Vec3s2, theta: Scalars2,
                   rest_kappa: Vec4s2, rest_twist: Scalars2, voronoi: Scalars2, stiffness: Vec4s1,
                   grad: Scalars2):
    """grad[s, j] = dE/dtheta^j [J/rad] for every edge. One thread per edge."""
    for s, j in ti.ndrange(theta.shape[0], theta.shape[1]):
        n = node_count[s]
        if j < n - 1:
            k = stiffness[s]
            g, _ = twist_terms(s, j, n, theta, rest_twist, voronoi, k.z)
            if j >= 1:
                _, d, _, _ = bend_terms(kb[s, j], m1[s, j], m2[s, j], rest_kappa[s, j].zw, k.x, k.y,
                                        0.5 / voronoi[s, j])
                g += d
            if j + 1 <= n - 2:
                _, d, _, _ = bend_terms(kb[s, j + 1], m1[s, j], m2[s, j], rest_kappa[s, j + 1].xy,
                                        k.x, k.y, 0.5 / voronoi[s, j + 1])
                g += d
            grad[s, j] = g


@ti.func
def add_kb_gradient(s, i, e0, e1, kbi, g, grad: ti.template()):
    """grad[x_{i-1..i+1}] += (d kb_i / d x)^T g, current-length kb (DESIGN.md)."""
    l0 = e0.norm()
    l1 = e1.norm()
    denom = l0 * l1 + e0.dot(e1)
    gk = g.dot(kbi)
    d_prev = (2.0 * g.cross(e1) + gk * (e1 + (l1 / l0) * e0)) / denom
    d_next = (2.0 * g.cross(e0) - gk * (e0 + (l0 / l1) * e1)) / denom
    grad[s, i - 1] += d_prev
    grad[s, i + 1] += d_next
    grad[s, i] -= d_prev + d_next


@ti.func
def add_holonomy_gradient(s, i, e0, e1, kbi, coeff, grad: ti.template()):
    """grad[x_{i-1..i+1}] += coeff * grad psi_i, psi_i the holonomy of node i."""
    d_prev = coeff * kbi / (2.0 * e0.norm())
    d_next = -coeff * kbi / (2.0 * e1.norm())
    grad[s, i - 1] += d_prev
    grad[s, i + 1] += d_next
    grad[s, i] -= d_prev + d_next


@ti.func
def strand_elastic_forces(s, x: ti.template(), node_count: ti.template(), kb: ti.template(),
                          m1: ti.template(), m2: ti.template(), rest_kappa: ti.template(),
                          voronoi: ti.template(), stiffness: ti.template(), force: ti.template()):
    """force[s, :] = -dE/dx for strand s (see elastic_forces)."""
    n = node_count[s]
    k = stiffness[s]
    for i in range(n):
        force[s, i] = vec3(0.0)
    suffix = 0.0
    for r in range(n - 2):
        i = n - 2 - r
        inv_2l = 0.5 / voronoi[s, i]
        rk = rest_kappa[s, i]
        kbi = kb[s, i]
        _, dth_prev, _, g_prev = bend_terms(kbi, m1[s, i - 1], m2[s, i - 1], rk.xy, k.x, k.y, inv_2l)
        _, dth_next, _, g_next = bend_terms(kbi, m1[s, i], m2[s, i], rk.zw, k.x, k.y, inv_2l)
        suffix += dth_next  # now the sum over edges j >= i is complete
        e0 = x[s, i] - x[s, i - 1]
        e1 = x[s, i + 1] - x[s, i]
        add_kb_gradient(s, i, e0, e1, kbi, g_prev + g_next, force)
        add_holonomy_gradient(s, i, e0, e1, kbi, suffix, force)
        suffix += dth_prev
    for i in range(n):
        force[s, i] = -force[s, i]


@ti.kernel
def elastic_forces(x: Vec3s2, node_count: Ints1, kb: Vec3s2, m1: Vec3s2, m2: Vec3s2,
                   rest_kappa: Vec4s2, voronoi: Scalars2, stiffness: Vec4s1, force: Vec3s2):
    """force[s, i] = -dE/dx_i [N] with the material angles held fixed (holonomy term included).

    Twist energy does not depend on x at fixed theta in a Bishop frame. The bending energy does
    through kb and through the material frames, which turn with the reference frame's holonomy:
    dE/dx = sum_i (dkb_i/dx)^T dE/dkb_i + sum_j dE_bend/dtheta^j grad Psi^j, Psi^j = sum_{k<=j} psi_k.
    The root edge is clamped but Psi^0 = 0, so it adds no term. One thread per strand; the
    suffix sum C_k = sum_{j>=k} dE_bend/dtheta^j runs from tip to root."""
    for s in range(x.shape[0]):
        strand_elastic_forces(s, x, node_count, kb, m1, m2, rest_kappa, voronoi, stiffness, force)


@ti.kernel
def material_curvatures(node_count: Ints1, kb: Vec3s2, m1: Vec3s2, m2: Vec3s2, kappa: Vec4s2):
    """kappa[s, i] = (w_i^{i-1}, w_i^i) [1] at interior nodes, zero at the ends. One thread per node."""
    for s, i in ti.ndrange(kappa.shape[0], kappa.shape[1]):
        n = node_count[s]
        value = ti.math.vec4(0.0)
        if 1 <= i <= n - 2:
            value = ti.math.vec4(kb[s, i].dot(m2[s, i - 1]), -kb[s, i].dot(m1[s, i - 1]),
                                 kb[s, i].dot(m2[s, i]), -kb[s, i].dot(m1[s, i]))
        kappa[s, i] = value
