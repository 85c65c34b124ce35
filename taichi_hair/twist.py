"""Twist update: the free edges' material angles theta^j [rad] given the centreline.

Two modes (DESIGN.md):
- `quasistatic`: Newton's method on dE/dtheta^j = 0 for every free edge (j >= 1; the root edge
  is clamped). The Hessian in theta is tridiagonal per strand (Thomas algorithm). Its bending
  diagonal can be negative far from equilibrium; it is clamped at zero there, which keeps the
  system positive definite (the twist part is SPD with a clamped root) and the iteration a
  descent; near the solution it is exact Newton.
- `kmoch`: Kmoch et al.'s rule for elliptic hair: m1 (the major axis, soft bending) follows the
  curvature binormals at the edge's two end nodes (their |kb|^2-weighted mean direction, taken
  modulo pi), choosing theta, theta + pi or theta - pi by the lowest local energy. Parallel
  per edge (Jacobi: neighbours' angles from before the update).
"""

import taichi as ti

from .arrays import Ints1, Scalars1, Scalars2, Vec3s2, Vec4s1, Vec4s2, vec2
from .frames import material_directors
from .linalg import thomas_solve
from .rod import bend_terms, twist_terms

TWIST_MODES = ("kmoch", "quasistatic", "none")
PI = 3.141592653589793
MIN_CURVATURE_SQ = 1e-12  # |kb|^2 below which an edge has no bending direction to follow


@ti.func
def edge_bend_theta_terms(s, j, n, angle, bishop_u: ti.template(), bishop_v: ti.template(),
                          kb: ti.template(), rest_kappa: ti.template(), voronoi: ti.template(), k):
    """Bending energy, dE/dtheta^j and d2E/dtheta^j2 of the terms that involve edge j at angle."""
    d1, d2 = material_directors(bishop_u[s, j], bishop_v[s, j], angle)
    energy = 0.0
    grad = 0.0
    hess = 0.0
    if j >= 1:  # node j sees edge j as its next edge
        e, g, h, _ = bend_terms(kb[s, j], d1, d2, rest_kappa[s, j].zw, k.x, k.y, 0.5 / voronoi[s, j])
        energy += e
        grad += g
        hess += h
    if j + 1 <= n - 2:  # node j+1 sees edge j as its previous edge
        e, g, h, _ = bend_terms(kb[s, j + 1], d1, d2, rest_kappa[s, j + 1].xy, k.x, k.y,
                                0.5 / voronoi[s, j + 1])
        energy += e
        grad += g
        hess += h
    return energy, grad, hess


@ti.func
def strand_twist_quasistatic(s, node_count: ti.template(), bishop_u: ti.template(),
                             bishop_v: ti.template(), kb: ti.template(), theta: ti.template(),
                             rest_kappa: ti.template(), rest_twist: ti.template(),
                             voronoi: ti.template(), stiffness: ti.template(), tol, max_iterations,
                             grad: ti.template(), diag: ti.template(), upper: ti.template()):
    """Newton on strand s's free angles (see solve_twist_quasistatic). Returns (iterations,
    scaled residual when it stopped)."""
    n = node_count[s]
    k = stiffness[s]
    scale = ti.max(k.x, k.z)
    it = 0
    res = 0.0
    while True:
        res = 0.0
        for j in range(1, n - 1):
            _, gb, hb = edge_bend_theta_terms(s, j, n, theta[s, j], bishop_u, bishop_v, kb,
                                              rest_kappa, voronoi, k)
            gt, ht = twist_terms(s, j, n, theta, rest_twist, voronoi, k.z)
            grad[s, j] = gb + gt
            diag[s, j] = ti.max(hb, 0.0) + ht
            upper[s, j] = -k.z / voronoi[s, j + 1]  # couples j and j+1 (unused for the last edge)
            res = ti.max(res, ti.abs(gb + gt) * 0.5 * (voronoi[s, j] + voronoi[s, j + 1]) / scale)
        if res < tol or it >= max_iterations:
            break
        thomas_solve(s, 1, n - 2, diag, upper, grad)  # grad <- Newton step H^-1 grad
        for j in range(1, n - 1):
            # a step longer than pi/2 would jump between branches of the energy
            theta[s, j] -= ti.math.clamp(grad[s, j], -0.5 * PI, 0.5 * PI)
        it += 1
    return it, res


@ti.kernel
def solve_twist_quasistatic(node_count: Ints1, bishop_u: Vec3s2, bishop_v: Vec3s2, kb: Vec3s2,
                            theta: Scalars2, rest_kappa: Vec4s2, rest_twist: Scalars2,
                            voronoi: Scalars2, stiffness: Vec4s1, tol: float, max_iterations: int,
                            grad: Scalars2, diag: Scalars2, upper: Scalars2,
                            iterations: Ints1, residual: Scalars1):
    """Newton iterations on the free edges' angles until max_j |dE/dtheta^j| l_j / max(EI1, GJ)
    < tol (l_j the edge's length); grad, diag, upper [S, N-1] are scratch. Keeps running maxima
    of the iterations and final residuals in iterations[s], residual[s]. One thread per strand."""
    for s in range(node_count.shape[0]):
        it, res = strand_twist_quasistatic(s, node_count, bishop_u, bishop_v, kb, theta, rest_kappa,
                                           rest_twist, voronoi, stiffness, tol, max_iterations,
                                           grad, diag, upper)
        iterations[s] = ti.max(iterations[s], it)
        residual[s] = ti.max(residual[s], res)


@ti.func
def kmoch_edge_angle(s, j, n, bishop_u: ti.template(), bishop_v: ti.template(), kb: ti.template(),
                     theta: ti.template(), rest_kappa: ti.template(), rest_twist: ti.template(),
                     voronoi: ti.template(), k):
    """Kmoch's new angle for free edge j of strand s, neighbours' angles as they are."""
    u = bishop_u[s, j]
    v = bishop_v[s, j]
    # squaring (ku + i kv) doubles the angle, so directions equal modulo pi average properly
    # and each node weighs in with |kb|^2
    doubled = vec2(0.0)
    for node in ti.static(range(2)):
        kbn = kb[s, j + node]
        ku = kbn.dot(u)
        kv = kbn.dot(v)
        doubled += vec2(ku * ku - kv * kv, 2.0 * ku * kv)
    best = theta[s, j]
    if doubled.norm() > MIN_CURVATURE_SQ:
        eta = 0.5 * ti.atan2(doubled.y, doubled.x)
        base = eta + PI * ti.round((theta[s, j] - eta) / PI)
        best_energy = 0.0
        for c in ti.static(range(3)):
            angle = base + (c - 1) * PI
            e, _, _ = edge_bend_theta_terms(s, j, n, angle, bishop_u, bishop_v, kb, rest_kappa, voronoi, k)
            e += local_twist_energy(s, j, n, angle, theta, rest_twist, voronoi, k.z)
            if c == 0 or e < best_energy:
                best = angle
                best_energy = e
    return best


@ti.func
def strand_twist_kmoch(s, node_count: ti.template(), bishop_u: ti.template(), bishop_v: ti.template(),
                       kb: ti.template(), theta: ti.template(), rest_kappa: ti.template(),
                       rest_twist: ti.template(), voronoi: ti.template(), stiffness: ti.template(),
                       theta_new: ti.template()):
    """Kmoch's rule on every free edge of strand s at once (Jacobi: all from the old angles)."""
    n = node_count[s]
    for j in range(1, n - 1):
        theta_new[s, j] = kmoch_edge_angle(s, j, n, bishop_u, bishop_v, kb, theta, rest_kappa,
                                           rest_twist, voronoi, stiffness[s])
    for j in range(1, n - 1):
        theta[s, j] = theta_new[s, j]


@ti.kernel
def kmoch_twist_angles(node_count: Ints1, bishop_u: Vec3s2, bishop_v: Vec3s2, kb: Vec3s2,
                       theta: Scalars2, rest_kappa: Vec4s2, rest_twist: Scalars2, voronoi: Scalars2,
                       stiffness: Vec4s1, theta_new: Scalars2):
    """Kmoch's update of every free edge's angle (the root edge keeps its own); theta_new
    [S, N-1] is scratch. One thread per strand."""
    for s in range(node_count.shape[0]):
        strand_twist_kmoch(s, node_count, bishop_u, bishop_v, kb, theta, rest_kappa, rest_twist,
                           voronoi, stiffness, theta_new)


@ti.func
def local_twist_energy(s, j, n, angle, theta: ti.template(), rest_twist: ti.template(),
                       voronoi: ti.template(), gj):
    """Twist energy of nodes j and j+1 with theta^j = angle and the neighbours' angles as they are."""
    energy = 0.0
    if j >= 1:
        m = angle - theta[s, j - 1] - rest_twist[s, j]
        energy += gj * m * m * 0.5 / voronoi[s, j]
    if j + 1 <= n - 2:
        m = theta[s, j + 1] - angle - rest_twist[s, j + 1]
        energy += gj * m * m * 0.5 / voronoi[s, j + 1]
    return energy
