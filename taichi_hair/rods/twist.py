"""Twist update: the free edges' material angles theta^j [rad] given the centreline.

Free edges: every edge with a clamped root (the clamp frame holds angle 0, docs/model.md);
edges 1.. with a pinned root, whose root edge keeps its own angle.

Two modes (docs/model.md, "Twist"):
- `quasistatic`: minimise the strand's energy over its free angles, E(theta) = E_bend +
  E_twist with the centreline fixed, by Newton's method with guaranteed descent. The Hessian
  in theta is tridiagonal per strand: each bending term depends on one angle, the twist terms
  couple neighbours. Far from a minimum the bending diagonal can be negative; when the exact
  Hessian is not positive definite (a pivot of its LDL^T factorisation <= 0) it is shifted by
  a multiple of the identity until it is (Levenberg-Marquardt, SHIFT_TRIES tries), and failing
  that its bending diagonal is clamped at zero, which is positive definite (the twist part is,
  with the clamp or the held root edge), so the step is a descent direction. A backtracking
  line search on the energy (Armijo) takes it, capped at pi/2 per angle: the energy decreases
  every iteration, so the iteration cannot cycle between branches, and near a minimum it is
  exact Newton (quadratic); an exact Newton step that turns no angle by more than
  WHOLE_NEWTON_STEP is taken whole, without the line search's energy evaluations (the
  quasi-static case in a time step).
  It ends converged (scaled residual below tol), stalled (no step changes theta in this
  precision) or at the iteration cap; callers count stalls and refuse caps.
- `kmoch`: Kmoch et al.'s rule for elliptic hair: m1 (the major axis, soft bending) follows the
  curvature binormals at the edge's two end nodes (their |kb|^2-weighted mean direction, taken
  modulo pi), choosing theta, theta + pi or theta - pi by the lowest local energy. Parallel
  per edge (Jacobi: neighbours' angles from before the update). Round strands have no axis to
  follow: they are solved exactly, as in `quasistatic`.

The quasistatic solve and the clips take `rotation` (ti.template): the strain measure (rod.py;
Kmoch's rule on elliptic strands runs with DER, world.options.SolverOptions.for_groom). Under the
rotation measure node i's energy depends on theta^{i-1} and theta^i together (through their mean,
which turns its mid frame, and their difference, its twist), so the Hessian stays tridiagonal; its
indefinite fallback is the Gauss-Newton Hessian, positive semi-definite node by node and definite
on the chain for the same reason as the DER one.
"""

import taichi as ti

from .arrays import vec2
from .frames import material_directors
from .linalg import back_substitute
from .rod import bend_terms, first_node, node_twist, rotation_node_terms, twist_terms
from .modes import Twist
from ..runtime import precision

TWIST_MODES = Twist.names()
PI = 3.141592653589793
MIN_CURVATURE_SQ = 1e-12  # |kb|^2 below which an edge has no bending direction to follow
ARMIJO = 1e-4  # fraction of the predicted decrease a line-search step must deliver
MAX_HALVINGS = 40
# a free root's gauge: relative damping of edge 0's Newton diagonal (a round strand's energy does
# not change when every angle turns together, so its Hessian is singular along that turn)
GAUGE_DAMPING = 1e-6
# an indefinite Newton system is shifted by SHIFT_START x its largest diagonal entry, then ten
# times that, ... for SHIFT_TRIES tries, before the bending diagonal is clamped (module doc)
SHIFT_START, SHIFT_TRIES = 1e-3, 4
# how a quasistatic solve ended: callers count stalls and refuse caps
CONVERGED, STALLED, CAPPED = 0, 1, 2


def rounding_epsilon() -> float:
    """Machine epsilon of the process's float (compile-time constant in kernels)."""
    return 2.3e-16 if precision() == "float64" else 1.2e-7


@ti.func
def edge_bend_theta_terms(s, j, n, first, angle, bishop_u: ti.template(), bishop_v: ti.template(),
                          kb: ti.template(), rest_kappa: ti.template(), voronoi: ti.template(), k):
    """Bending energy, dE/dtheta^j and d2E/dtheta^j2 of the terms that involve edge j at angle."""
    d1, d2 = material_directors(bishop_u[s, j], bishop_v[s, j], angle)
    energy = 0.0
    grad = 0.0
    hess = 0.0
    if j >= first:  # node j sees edge j as its next edge
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
def angle_before(s, i, theta: ti.template()):
    """theta^{i-1} [rad]; the clamp's (edge -1) is 0."""
    before = 0.0
    if i >= 1:
        before = theta[s, i - 1]
    return before


@ti.func
def rotation_node_at(s, i, before, after, bishop_u: ti.template(), bishop_v: ti.template(),
                     kb: ti.template(), rest_kappa: ti.template(), voronoi: ti.template(), k):
    """rod.rotation_node_terms of node i with theta^{i-1} = before and theta^i = after: its mid
    frame is edge i's Bishop frame turned by their mean (kb is normal to both edges, so edge i's
    frame serves node 0 too, whose previous frame is the clamp)."""
    mid1, mid2 = material_directors(bishop_u[s, i], bishop_v[s, i], 0.5 * (before + after))
    return rotation_node_terms(kb[s, i], mid1, mid2, after - before, rest_kappa[s, i].xyz, k,
                               1.0 / voronoi[s, i])


@ti.func
def edge_theta_gradient(s, j, n, first, rotation: ti.template(), md: ti.template(), st: ti.template(), k):
    """dE/dtheta^j [J/rad] at the angles as they are (bending and twist, either measure; under
    the rotation measure the nodes j and j+1, where theta^j is theta^i and theta^{i-1}). md, st:
    the rods' model and state arrays (arrays.ModelArgs, arrays.StateArgs)."""
    bishop_u, bishop_v, kb, theta = ti.static(st.bishop_u, st.bishop_v, st.kb, st.theta)
    rest_kappa, rest_twist, voronoi = ti.static(md.rest_kappa, md.rest_twist, md.voronoi)
    g = 0.0
    if ti.static(rotation):
        if j >= first:
            _w, _e, d, _h, _gn, _g_kb = rotation_node_at(s, j, angle_before(s, j, theta), theta[s, j], bishop_u,
                                                         bishop_v, kb, rest_kappa, voronoi, k)
            g += 0.5 * d.x + d.y
        if j + 1 <= n - 2:
            _w, _e, d, _h, _gn, _g_kb = rotation_node_at(s, j + 1, theta[s, j], theta[s, j + 1], bishop_u,
                                                         bishop_v, kb, rest_kappa, voronoi, k)
            g += 0.5 * d.x - d.y
    else:
        _, gb, _ = edge_bend_theta_terms(s, j, n, first, theta[s, j], bishop_u, bishop_v, kb,
                                         rest_kappa, voronoi, k)
        gt, _ = twist_terms(s, j, n, first, theta, rest_twist, voronoi, k.z)
        g = gb + gt
    return g


@ti.func
def theta_energy(s, n, first, rotation: ti.template(), md: ti.template(), st: ti.template(), k):
    """The part of strand s's energy [J] that depends on its material angles: every bending
    term seen from an edge and every twist term (node 0's clamp-side bending term is constant);
    rotation: every node's energy. md, st: the rods' model and state arrays (arrays.ModelArgs,
    arrays.StateArgs: rest curvature, rest twist, Voronoi lengths; Bishop frames, curvature
    binormals, angles)."""
    bishop_u, bishop_v, kb, theta = ti.static(st.bishop_u, st.bishop_v, st.kb, st.theta)
    rest_kappa, rest_twist, voronoi = ti.static(md.rest_kappa, md.rest_twist, md.voronoi)
    total = 0.0
    if ti.static(rotation):
        for i in range(first, n - 1):
            _w, e, _d, _h, _gn, _g_kb = rotation_node_at(s, i, angle_before(s, i, theta), theta[s, i], bishop_u,
                                                bishop_v, kb, rest_kappa, voronoi, k)
            total += e
    else:
        for j in range(0, n - 1):
            e, _, _ = edge_bend_theta_terms(s, j, n, first, theta[s, j], bishop_u, bishop_v, kb,
                                            rest_kappa, voronoi, k)
            total += e
        for i in range(first, n - 1):
            m = node_twist(s, i, theta, rest_twist)
            total += 0.5 * k.z * m * m / voronoi[s, i]
    return total


@ti.func
def edge_twist_held(s, j, clips: ti.template(), clip: ti.template()):
    """1 if edge j of strand s is held by a clip that holds twist (clip[s, j, 1].z > 0), else 0."""
    held = 0
    if ti.static(clips):
        if clip[s, j, 1].z > 0.0:
            held = 1
    return held


@ti.func
def assemble_newton(s, n, first, lo, clamp_bending, rotation: ti.template(), md: ti.template(), st: ti.template(),
                    k, clips: ti.template(), clip: ti.template()):
    """Gradient and tridiagonal Hessian of theta_energy on the free edges lo..n-2 (first: the
    first node that bends and twists; lo = first, or 0 for a free root, whose edge 0 is free too
    and whose Hessian is singular along a uniform turn of a round strand: GAUGE_DAMPING on edge
    0's diagonal fixes that gauge without biasing the minimum); clamp_bending = 1 clamps the
    bending diagonal at 0 (rotation: takes the Gauss-Newton Hessian). An edge whose twist a clip
    holds is not free: its row is the identity with zero gradient. Returns the scaled residual
    max_j |dE/dtheta^j| l_j / max(EI1, GJ), l_j the edge's Voronoi span. The gradient, diagonal
    and upper diagonal go into the state's three edge scratch rows (st.diag, st.upper, st.rhs)."""
    bishop_u, bishop_v, kb, theta = ti.static(st.bishop_u, st.bishop_v, st.kb, st.theta)
    rest_kappa, rest_twist, voronoi = ti.static(md.rest_kappa, md.rest_twist, md.voronoi)
    grad, diag, upper = ti.static(st.diag, st.upper, st.rhs)
    scale = ti.max(k.x, k.z)
    res = 0.0
    if ti.static(rotation):
        for j in range(lo, n - 1):
            grad[s, j] = 0.0
            diag[s, j] = 0.0
            upper[s, j] = 0.0
        for i in range(first, n - 1):  # node i couples edges i-1 and i
            _w, _e, d, h, gauss_newton, _g_kb = rotation_node_at(s, i, angle_before(s, i, theta), theta[s, i],
                                                           bishop_u, bishop_v, kb, rest_kappa, voronoi, k)
            if clamp_bending:
                h = gauss_newton
            if i - 1 >= lo:
                grad[s, i - 1] += 0.5 * d.x - d.y
                diag[s, i - 1] += 0.25 * h.x - h.y + h.z
                upper[s, i - 1] = 0.25 * h.x - h.z
            grad[s, i] += 0.5 * d.x + d.y
            diag[s, i] += 0.25 * h.x + h.y + h.z
        if lo < first:  # a free root's edge 0
            diag[s, lo] *= 1.0 + GAUGE_DAMPING
    for j in range(lo, n - 1):
        g = 0.0
        if ti.static(rotation):
            g = grad[s, j]
        else:
            _, gb, hb = edge_bend_theta_terms(s, j, n, first, theta[s, j], bishop_u, bishop_v, kb,
                                              rest_kappa, voronoi, k)
            gt, ht = twist_terms(s, j, n, first, theta, rest_twist, voronoi, k.z)
            if clamp_bending:
                hb = ti.max(hb, 0.0)
            g = gb + gt
            grad[s, j] = g
            diag[s, j] = hb + ht
            if j < first:  # a free root's edge 0
                diag[s, j] += GAUGE_DAMPING * ht
            upper[s, j] = -k.z / voronoi[s, j + 1]  # couples j and j+1 (unused for the last edge)
        span = 0.5 * voronoi[s, j + 1]
        if j >= first:
            span += 0.5 * voronoi[s, j]
        if edge_twist_held(s, j, clips, clip):
            grad[s, j] = 0.0
            diag[s, j] = 1.0
            upper[s, j] = 0.0
            if j > lo:
                upper[s, j - 1] = 0.0
        else:
            res = ti.max(res, ti.abs(g) * span / scale)
    return res


@ti.func
def ldl_solve(s, lo, hi, diag: ti.template(), upper: ti.template(), rhs: ti.template()):
    """Solve strand s's symmetric tridiagonal system on rows lo..hi in place (rhs <- H^-1 rhs,
    diag <- the pivots D of H = L D L^T). Returns (1 if every pivot is positive, else 0;
    rhs . H^-1 rhs = sum y_j^2 / D_j, the Newton decrement squared)."""
    positive = 1
    decrement = 0.0
    for j in range(lo, hi + 1):
        if j > lo:
            w = upper[s, j - 1] / diag[s, j - 1]
            diag[s, j] -= w * upper[s, j - 1]
            rhs[s, j] -= w * rhs[s, j - 1]
        if not (diag[s, j] > 0.0):
            positive = 0
            break
        decrement += rhs[s, j] * rhs[s, j] / diag[s, j]
    if positive:
        back_substitute(s, lo, hi, diag, upper, rhs)
    return positive, decrement


# An exact Newton step (positive definite Hessian) that turns no angle by more than this [rad] is
# taken whole, without the line search's energies: the energy is a trigonometric polynomial in
# the angles, so its quadratic model's error over the step is of order step^3 (relative to the
# curvature, below 1e-6 here) and Armijo's test, which asks for 1e-4 of the predicted decrease,
# would pass at alpha = 1. A quasi-static twist moves by far less than this per time step.
WHOLE_NEWTON_STEP = 1e-2


@ti.func
def newton_step_within(s, lo, hi, st: ti.template()):
    """theta <- theta - step (st.diag, solved by ldl_solve) if no angle moves by more than
    WHOLE_NEWTON_STEP; returns the largest |step| [rad] taken, 0 if none (theta unchanged)."""
    largest = 0.0
    for j in range(lo, hi + 1):
        largest = ti.max(largest, ti.abs(st.diag[s, j]))
    moved = 0.0
    if largest <= WHOLE_NEWTON_STEP:
        for j in range(lo, hi + 1):
            st.theta[s, j] -= st.diag[s, j]
        moved = largest
    return moved


@ti.func
def line_search(s, first, lo, hi, e0, decrement, rotation: ti.template(), md: ti.template(), st: ti.template(), k):
    """theta <- theta - alpha step with the largest alpha = a0 2^-m (a0 caps every angle's move
    at pi/2) that decreases the energy by ARMIJO alpha decrement, or that changes it by less than
    its rounding when the predicted decrease is below it. Returns the accepted alpha times the
    largest |step| [rad] (0: no step found, theta unchanged). The step is in st.diag (assemble_newton's
    gradient row, solved in place by ldl_solve)."""
    theta, step = ti.static(st.theta, st.diag)
    n = hi + 2
    largest = 0.0
    for j in range(lo, hi + 1):
        largest = ti.max(largest, ti.abs(step[s, j]))
    alpha = 1.0
    if largest > 0.5 * PI:
        alpha = 0.5 * PI / largest
    applied = 0.0
    moved = 0.0
    slack = 64.0 * ti.static(rounding_epsilon()) * ti.abs(e0)
    for _ in range(MAX_HALVINGS):
        for j in range(lo, hi + 1):
            theta[s, j] -= (alpha - applied) * step[s, j]
        applied = alpha
        e1 = theta_energy(s, n, first, rotation, md, st, k)
        predicted = alpha * decrement
        if e1 <= e0 - ARMIJO * predicted or (predicted <= slack and e1 <= e0 + slack):
            moved = alpha * largest
            break
        alpha *= 0.5
    if moved == 0.0:
        for j in range(lo, hi + 1):
            theta[s, j] += applied * step[s, j]
    return moved


@ti.func
def strand_twist_quasistatic(s, clamp: ti.template(), free_root: ti.template(), rotation: ti.template(),
                             md: ti.template(), st: ti.template(), tol, max_iterations, clips: ti.template(),
                             clip: ti.template()):
    """Newton with line search on strand s's free angles (see the module doc; free_root: edge 0
    is free too; clips: edges held by twist-holding clips keep their angles). md, st: the rods'
    model and state arrays (arrays.ModelArgs, arrays.StateArgs); the state's three edge scratch
    rows hold the Newton system. Returns (iterations, scaled residual when it stopped, CONVERGED /
    STALLED / CAPPED)."""
    theta, grad, diag, upper = ti.static(st.theta, st.diag, st.upper, st.rhs)
    n = md.node_count[s]
    k = md.stiffness[s]
    first = ti.static(first_node(clamp))
    lo = ti.static(0 if free_root else first_node(clamp))
    it = 0
    res = 0.0
    status = CONVERGED
    while True:
        res = assemble_newton(s, n, first, lo, 0, rotation, md, st, k, clips, clip)
        if res < tol:
            break
        if it >= max_iterations:
            status = CAPPED
            break
        positive, decrement = ldl_solve(s, lo, n - 2, diag, upper, grad)
        exact = positive
        # indefinite: the exact Hessian shifted by SHIFT_START x its largest diagonal entry, ten
        # times more each try, until it is positive definite (Levenberg-Marquardt); the last try
        # clamps the bending diagonal instead, which always is
        attempt = 0
        while not positive:
            clamped = 1 if attempt == SHIFT_TRIES else 0
            assemble_newton(s, n, first, lo, clamped, rotation, md, st, k, clips, clip)
            if not clamped:
                largest = 0.0
                for j in range(lo, n - 1):
                    largest = ti.max(largest, ti.abs(diag[s, j]))
                shift = SHIFT_START * largest * 10.0 ** attempt
                for j in range(lo, n - 1):
                    diag[s, j] += shift
            positive, decrement = ldl_solve(s, lo, n - 2, diag, upper, grad)
            if clamped:
                break
            attempt += 1
        moved = 0.0
        if exact:
            moved = newton_step_within(s, lo, n - 2, st)
        if moved == 0.0:
            moved = line_search(s, first, lo, n - 2, theta_energy(s, n, first, rotation, md, st, k), decrement,
                                rotation, md, st, k)
        it += 1
        largest_angle = 0.0
        for j in range(lo, n - 1):
            largest_angle = ti.max(largest_angle, ti.abs(theta[s, j]))
        if moved <= 4.0 * ti.static(rounding_epsilon()) * (1.0 + largest_angle):
            # nothing representable is left to gain: the rounding floor of this precision
            res = assemble_newton(s, n, first, lo, 0, rotation, md, st, k, clips, clip)
            if res >= tol:
                status = STALLED
            break
    return it, res, status


@ti.func
def kmoch_edge_angle(s, j, n, first, md: ti.template(), st: ti.template(), k):
    """Kmoch's new angle for free edge j of strand s, neighbours' angles as they are (md, st: the
    rods' model and state arrays)."""
    bishop_u, bishop_v, kb, theta = ti.static(st.bishop_u, st.bishop_v, st.kb, st.theta)
    rest_kappa, rest_twist, voronoi = ti.static(md.rest_kappa, md.rest_twist, md.voronoi)
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
    switched = 0
    if doubled.norm() > MIN_CURVATURE_SQ:
        eta = 0.5 * ti.atan2(doubled.y, doubled.x)
        base = eta + PI * ti.round((theta[s, j] - eta) / PI)
        best_energy = 0.0
        for c in ti.static(range(3)):
            angle = base + (c - 1) * PI
            e, _, _ = edge_bend_theta_terms(s, j, n, first, angle, bishop_u, bishop_v, kb, rest_kappa,
                                            voronoi, k)
            e += local_twist_energy(s, j, n, first, angle, theta, rest_twist, voronoi, k.z)
            if c == 0 or e < best_energy:
                best = angle
                best_energy = e
                switched = 1 if c != 1 else 0  # c = 1 is the branch nearest the old angle
    return best, switched


@ti.func
def strand_twist_kmoch(s, clamp: ti.template(), md: ti.template(), st: ti.template(), theta_new: ti.template()):
    """Kmoch's rule on every free edge of strand s at once (Jacobi: all from the old angles into
    theta_new, then copied). md, st: the rods' model and state arrays. Returns how many edges
    switched branch (theta +- pi from the branch nearest the old angle)."""
    theta = ti.static(st.theta)
    n = md.node_count[s]
    first = ti.static(first_node(clamp))
    switches = 0
    for j in range(first, n - 1):
        angle, switched = kmoch_edge_angle(s, j, n, first, md, st, md.stiffness[s])
        theta_new[s, j] = angle
        switches += switched
    for j in range(first, n - 1):
        theta[s, j] = theta_new[s, j]
    return switches


@ti.func
def local_twist_energy(s, j, n, first, angle, theta: ti.template(), rest_twist: ti.template(),
                       voronoi: ti.template(), gj):
    """Twist energy of nodes j and j+1 with theta^j = angle and the neighbours' angles as they are."""
    energy = 0.0
    if j >= first:
        m = angle - theta[s, j] + node_twist(s, j, theta, rest_twist)
        energy += gj * m * m * 0.5 / voronoi[s, j]
    if j + 1 <= n - 2:
        m = theta[s, j + 1] - angle - rest_twist[s, j + 1]
        energy += gj * m * m * 0.5 / voronoi[s, j + 1]
    return energy
