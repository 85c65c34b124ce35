"""Discrete elastic rod energy (bending + twist) and the elastic force with its holonomy term.

Notation of docs/model.md: interior node i lies between edges i-1 and i; its material curvature
seen from edge j in {i-1, i} is w_i^j = (kb_i . m2^j, -kb_i . m1^j), its rest value wbar_i^j
is stored in rest_kappa[s, i] = (wbar_i^{i-1}, wbar_i^i) as a vec4, and l_i is its Voronoi
length [m]. stiffness[s] = (EI1, EI2, GJ, EA) [N m^2, N m^2, N m^2, N].

    E_bend  = sum_i 1/(4 l_i) sum_{j in {i-1,i}} (w - wbar)^T diag(EI1, EI2) (w - wbar)
    E_twist = sum_i GJ (theta^i - theta^{i-1} - mbar_i)^2 / (2 l_i)

Two strain measures (docs/model.md, "Strains from rotations"), a compile-time switch `rotation`
(ti.template) of every function below that sums the energy:
- DER (rotation False): the bending and twist terms above, Bergou et al. 2008.
- rotation (True): node i stores 1/(2 l_i) (w - wbar)^T diag(EI2, EI1, GJ) (w - wbar), w the
  rotation vector of the turn from edge i-1's material frame to edge i's (its components along
  m1, m2 and t; the clamp before node 0), wbar = rest_kappa[s, i].xyz. A Cosserat rod measures its
  strains this way; on a discrete helix they are exact, where 2 tan(phi / 2) and the split into
  bending and twist are not (measured: a curled rod's tip 4x closer to the continuum at 50 segments).

Clamped root (docs/model.md, "The clamp at the root"): node 0 is a bending and twisting node
too. Its previous "edge" is the clamp, the head-carried root frame (root_t, root_u) with
material angle 0, and its Voronoi length is half the first edge (the part of its cell inside
the hair), so the strand bends from the groomed root node. Every function taking `clamp`
(ti.template) sums over nodes first_node(clamp)..n-2; a pinned root (clamp False) is a hinge
and starts at node 1 as in plain DER.
"""

import taichi as ti

from .arrays import Ints1, ModelArgs, Scalars1, Scalars2, StateArgs, Vec3s1, Vec3s2, Vec4s1, Vec4s2, edge, vec2, vec3
from .frames import material_directors
from ..runtime import precision

# The rotation measure's scalar functions of x = rho / c (rho = |q_v|, c = cos(m/2), see
# rotation_scalars) lose digits to cancellation as x -> 0; below this x they come from their
# series (8 terms: truncation below 1e-15 at x = 0.1 and 5e-9 at 0.3, under each precision's
# rounding there)
SERIES_BELOW = {"float64": 0.1, "float32": 0.3}
# series coefficients in x^2 (Horner order: highest first) of
#   P c^2 = (1 - G c / 2) c^2 / rho^2 = sum_n (-1)^n x^2n / (2n + 3)
#   Q c^3 = (c / (rho^2 + c^2) - G / 2) c^3 / rho^2 = sum_{n>=1} (-1)^n 2n x^(2n-2) / (2n + 1)
#   Z c^3 = (G / 4 - 3 P c / 2) c^3 / rho^2 = sum_{n>=1} (-1)^(n+1) 2n x^(2n-2) / ((2n + 1)(2n + 3))
# as exact (numerator, denominator) integer pairs: horner divides them in its argument's float
# type (a float literal in a kernel takes the default type: float32 in a float32 build)
P_SERIES = tuple(((-1) ** n, 2 * n + 3) for n in reversed(range(8)))
Q_SERIES = tuple(((-1) ** n * 2 * n, 2 * n + 1) for n in reversed(range(1, 9)))
Z_SERIES = tuple(((-1) ** (n + 1) * 2 * n, (2 * n + 1) * (2 * n + 3)) for n in reversed(range(1, 9)))


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
def horner(coefficients: ti.template(), x2):
    """sum_k (num_k / den_k) x2^(K-1-k) for coefficients ((num_k, den_k), ...) integer pairs,
    highest power first, in x2's float type (float64 inside the implicit step of a float32 build,
    where float literals, 0.0 or 1/3, would be float32 and round the sum)."""
    one = 1 + 0 * x2  # x2's type
    total = 0 * x2
    for num, den in ti.static(coefficients):
        total = total * x2 + num / (den * one)
    return total


@ti.func
def rotation_scalars(a2, sn, c, series_below: ti.template()):
    """The turn's rotation vector is w = G (k1/2, k2/2, sn) (rotation_node_terms) with
    rho^2 = a2 + sn^2 = |q_v|^2, psi = 2 atan2(rho, c) its angle and G = psi / rho. Returns
    (G, P, Q, Z): P = (1 - G c/2) / rho^2 (so dG/dm = sn P), Q = dG/d(rho^2) at fixed c (so
    dG/dk = Q k / 2), Z = (G/4 - 3 P c/2) / rho^2 (so dP/dm = sn Z); series below x = series_below, the
    SERIES_BELOW entry of the arguments' float type (the implicit step calls this in float64 in
    both precisions)."""
    rho2 = a2 + sn * sn
    G = 0.0 * rho2  # of the arguments' type (the implicit step calls this in float64)
    P = 0.0 * rho2
    Q = 0.0 * rho2
    Z = 0.0 * rho2
    limit = ti.static(series_below)
    if c > 0.0 and rho2 < limit * limit * c * c:
        x2 = rho2 / (c * c)
        P = horner(P_SERIES, x2) / (c * c)
        G = 2.0 * (1.0 - rho2 * P) / c
        Q = horner(Q_SERIES, x2) / (c * c * c)
        Z = horner(Z_SERIES, x2) / (c * c * c)
    else:
        rho = ti.sqrt(rho2)
        G = 2.0 * ti.atan2(rho, c) / rho
        P = (1.0 - 0.5 * G * c) / rho2
        Q = (c / (rho2 + c * c) - 0.5 * G) / rho2
        Z = (0.25 * G - 1.5 * P * c) / rho2
    return G, P, Q, Z


@ti.func
def rotation_node_terms(kbi, mid1, mid2, turn, wbar, k, inv_l):
    """Node i of the rotation measure. kbi its curvature binormal [1]; (mid1, mid2) the material
    directors halfway between edges i-1 and i (edge i's frame turned back by turn/2 about its
    tangent, or edge i-1's turned on by turn/2: kb is normal to both tangents, so its components
    agree); turn = theta^i - theta^{i-1} [rad] (the clamp's angle is 0); wbar the rest rotation
    vector (about m1, m2, t) [rad]; k = (EI1, EI2, GJ, .) [N m^2]; inv_l = 1 / l_i [1/m].

    The turn from edge i-1's frame to edge i's is the transport about kb by phi, then the twist
    about t by `turn`: its quaternion, scaled by 1 / cos(phi/2), is (c, k1/2, k2/2, sn) with
    c, sn = cos, sin(turn/2) and k = (kb . mid1, kb . mid2) (|kb| = 2 tan(phi/2)); the rotation
    vector is G (k1/2, k2/2, sn) in the material axes (rotation_scalars). beta, the mean angle
    (theta^{i-1} + theta^i) / 2, turns the mid frame and so k; dtheta^{i-1} = dbeta/2 - dturn,
    dtheta^i = dbeta/2 + dturn.

    Returns (w, energy [J], (dE/dbeta, dE/dturn) [J/rad], (d2E/dbeta2, d2E/dbeta dturn,
    d2E/dturn2) [J/rad^2], the same three of the Gauss-Newton Hessian (w's second derivatives
    dropped: positive semi-definite), dE/dkb [J] with the mid frame held)."""
    c = ti.cos(0.5 * turn)
    sn = ti.sin(0.5 * turn)
    kv = vec2(kbi.dot(mid1), kbi.dot(mid2))
    G, P, Q, Z = rotation_scalars(0.25 * kv.dot(kv), sn, c, ti.static(SERIES_BELOW[precision()]))
    u = vec3(0.5 * kv.x, 0.5 * kv.y, sn)
    w = G * u
    stiff = inv_l * vec3(k.y, k.x, k.z)  # about m1 the soft EI2, about m2 the stiff EI1, GJ
    g = stiff * (w - wbar)
    energy = 0.5 * (w - wbar).dot(g)
    dG = sn * P  # dG/dturn
    ddG = 0.5 * c * P + sn * sn * Z
    dH = sn * sn * P + 0.5 * G * c  # H = G sn
    ddH = 1.5 * sn * c * P + sn * sn * sn * Z - 0.25 * G * sn
    w_b = G * vec3(0.5 * kv.y, -0.5 * kv.x, 0.0)
    w_t = vec3(dG * 0.5 * kv.x, dG * 0.5 * kv.y, dH)
    w_bb = -G * vec3(0.5 * kv.x, 0.5 * kv.y, 0.0)
    w_bt = dG * vec3(0.5 * kv.y, -0.5 * kv.x, 0.0)
    w_tt = vec3(ddG * 0.5 * kv.x, ddG * 0.5 * kv.y, ddH)
    grad = vec2(w_b.dot(g), w_t.dot(g))
    gauss_newton = vec3((stiff * w_b).dot(w_b), (stiff * w_b).dot(w_t), (stiff * w_t).dot(w_t))
    hess = gauss_newton + vec3(w_bb.dot(g), w_bt.dot(g), w_tt.dot(g))
    d_kv = 0.5 * G * vec2(g.x, g.y) + 0.5 * Q * u.dot(g) * kv
    return w, energy, grad, hess, gauss_newton, d_kv.x * mid1 + d_kv.y * mid2


@ti.func
def node_turn(s, i, theta: ti.template()):
    """theta^i - theta^{i-1} [rad], the clamp's angle (edge -1) 0."""
    previous = 0.0
    if i >= 1:
        previous = theta[s, i - 1]
    return theta[s, i] - previous


@ti.func
def rotation_node(s, i, kb: ti.template(), m1: ti.template(), m2: ti.template(), theta: ti.template(),
                  rest_kappa: ti.template(), voronoi: ti.template(), k):
    """rotation_node_terms of node i with the mid frame from edge i's material frame."""
    turn = node_turn(s, i, theta)
    mid1, mid2 = material_directors(m1[s, i], m2[s, i], -0.5 * turn)
    return rotation_node_terms(kb[s, i], mid1, mid2, turn, rest_kappa[s, i].xyz, k, 1.0 / voronoi[s, i])


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
def strand_energy(s, clamp: ti.template(), rotation: ti.template(), md: ti.template(), st: ti.template()):
    """E_bend + E_twist of strand s [J] with the material frames (m1, m2) and angles as they are
    (rotation: the rotation measure's node energies). md, st: the rods' model and state arrays
    (arrays.ModelArgs, arrays.StateArgs)."""
    kb, m1, m2, theta, root_t, root_u = ti.static(st.kb, st.m1, st.m2, st.theta, st.root_t, st.root_u)
    rest_kappa, rest_twist, voronoi = ti.static(md.rest_kappa, md.rest_twist, md.voronoi)
    n = md.node_count[s]
    k = md.stiffness[s]
    total = 0.0
    for i in range(ti.static(first_node(clamp)), n - 1):
        if ti.static(rotation):
            _w, e, _d, _h, _gn, _g_kb = rotation_node(s, i, kb, m1, m2, theta, rest_kappa, voronoi, k)
            total += e
        else:
            e_prev, _, _, _ = node_bend_terms(s, i, i - 1, kb, m1, m2, root_t, root_u, rest_kappa, voronoi, k)
            e_next, _, _, _ = node_bend_terms(s, i, i, kb, m1, m2, root_t, root_u, rest_kappa, voronoi, k)
            twist = node_twist(s, i, theta, rest_twist)
            total += e_prev + e_next + k.z * twist * twist * 0.5 / voronoi[s, i]
    return total


@ti.kernel
def strand_elastic_energy(clamp: ti.template(), rotation: ti.template(), md: ModelArgs, st: StateArgs,
                          energy: Scalars1):
    """energy[s] = E_bend + E_twist of strand s [J], material angles as they are. One thread per strand."""
    for s in range(md.node_count.shape[0]):
        energy[s] = strand_energy(s, clamp, rotation, md, st)


@ti.func
def edge_gradient(s, j, n, first, rotation: ti.template(), md: ti.template(), st: ti.template(), k):
    """dE/dtheta^j [J/rad] of edge j < n - 1 with the material frames (m1, m2) and angles as
    they are (md, st as in strand_energy; k = stiffness[s])."""
    kb, m1, m2, theta, root_t, root_u = ti.static(st.kb, st.m1, st.m2, st.theta, st.root_t, st.root_u)
    rest_kappa, rest_twist, voronoi = ti.static(md.rest_kappa, md.rest_twist, md.voronoi)
    g = 0.0
    if ti.static(rotation):
        if j >= first:  # node j: theta^j is its theta^i
            _w, _e, d, _h, _gn, _g_kb = rotation_node(s, j, kb, m1, m2, theta, rest_kappa, voronoi, k)
            g += 0.5 * d.x + d.y
        if j + 1 <= n - 2:  # node j+1: theta^j is its theta^{i-1}
            _w, _e, d, _h, _gn, _g_kb = rotation_node(s, j + 1, kb, m1, m2, theta, rest_kappa, voronoi, k)
            g += 0.5 * d.x - d.y
    else:
        g, _ = twist_terms(s, j, n, first, theta, rest_twist, voronoi, k.z)
        if j >= first:
            _, d, _, _ = node_bend_terms(s, j, j, kb, m1, m2, root_t, root_u, rest_kappa, voronoi, k)
            g += d
        if j + 1 <= n - 2:
            _, d, _, _ = node_bend_terms(s, j + 1, j, kb, m1, m2, root_t, root_u, rest_kappa, voronoi, k)
            g += d
    return g


@ti.kernel
def theta_gradient(clamp: ti.template(), rotation: ti.template(), md: ModelArgs, st: StateArgs, grad: Scalars2):
    """grad[s, j] = dE/dtheta^j [J/rad] for every edge. One thread per edge."""
    for s, j in ti.ndrange(st.theta.shape[0], st.theta.shape[1]):
        n = md.node_count[s]
        if j < n - 1:
            grad[s, j] = edge_gradient(s, j, n, ti.static(first_node(clamp)), rotation, md, st, md.stiffness[s])


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
def kb_gradient_to_nodes(g, kbi, e0, e1):
    """((d kb_i / d x_{i-1})^T g, (d kb_i / d x_{i+1})^T g) for kb_i of edges e0 = e^{i-1},
    e1 = e^i at their current lengths (docs/model.md, "Forces"); x_i takes minus their sum."""
    l0 = e0.norm()
    l1 = e1.norm()
    denom = l0 * l1 + e0.dot(e1)
    gk = g.dot(kbi)
    d_prev = (2.0 * g.cross(e1) + gk * (e1 + (l1 / l0) * e0)) / denom
    d_next = (2.0 * g.cross(e0) - gk * (e0 + (l0 / l1) * e1)) / denom
    return d_prev, d_next


@ti.func
def add_kb_gradient(s, i, e0, e1, kbi, g, grad: ti.template()):
    """grad[x_{i-1..i+1}] += (d kb_i / d x)^T g, current-length kb (docs/model.md)."""
    d_prev, d_next = kb_gradient_to_nodes(g, kbi, e0, e1)
    add_node_gradient(s, i, d_prev, d_next, grad)


@ti.func
def add_holonomy_gradient(s, i, e0, e1, kbi, coeff, grad: ti.template()):
    """grad[x_{i-1..i+1}] += coeff * grad psi_i, psi_i the holonomy of node i."""
    add_node_gradient(s, i, coeff * kbi / (2.0 * e0.norm()), -coeff * kbi / (2.0 * e1.norm()), grad)


@ti.func
def strand_elastic_forces(s, clamp: ti.template(), rotation: ti.template(), md: ti.template(), st: ti.template()):
    """st.force[s, :] = -dE/dx for strand s (see elastic_forces; md, st as in strand_energy)."""
    x, kb, m1, m2, theta, root_t, root_u = ti.static(st.x, st.kb, st.m1, st.m2, st.theta, st.root_t, st.root_u)
    rest_kappa, voronoi, force = ti.static(md.rest_kappa, md.voronoi, st.force)
    n = md.node_count[s]
    k = md.stiffness[s]
    first = ti.static(first_node(clamp))
    for i in range(n):
        force[s, i] = vec3(0.0)
    suffix = 0.0
    for r in range(n - 1 - first):
        i = n - 2 - r
        kbi = kb[s, i]
        e0, e1 = node_edges(s, i, x, root_t)
        if ti.static(rotation):
            # node i is written in edge i's frame (its mid frame turned back from it), so its
            # frame term belongs to edge i and turns with Psi^i, which psi_i is part of
            _w, _e, d, _h, _gn, g_kb = rotation_node(s, i, kb, m1, m2, theta, rest_kappa, voronoi, k)
            suffix += d.x
            add_kb_gradient(s, i, e0, e1, kbi, g_kb, force)
            add_holonomy_gradient(s, i, e0, e1, kbi, suffix, force)
        else:
            _, dth_prev, _, g_prev = node_bend_terms(s, i, i - 1, kb, m1, m2, root_t, root_u,
                                                     rest_kappa, voronoi, k)
            _, dth_next, _, g_next = node_bend_terms(s, i, i, kb, m1, m2, root_t, root_u, rest_kappa,
                                                     voronoi, k)
            suffix += dth_next  # now the sum over edges j >= i is complete
            add_kb_gradient(s, i, e0, e1, kbi, g_prev + g_next, force)
            add_holonomy_gradient(s, i, e0, e1, kbi, suffix, force)
            suffix += dth_prev  # the clamp's angle (i = 0) is not a variable: its term is never used
    for i in range(n):
        force[s, i] = -force[s, i]


@ti.kernel
def elastic_forces(clamp: ti.template(), rotation: ti.template(), md: ModelArgs, st: StateArgs):
    """st.force[s, i] = -dE/dx_i [N] with the material angles held fixed (holonomy term included).

    Twist energy does not depend on x at fixed theta in a Bishop frame. The bending energy does
    through kb and through the material frames, which turn with the reference frame's holonomy:
    dE/dx = sum_i (dkb_i/dx)^T dE/dkb_i + sum_j dE_bend/dtheta^j grad Psi^j, Psi^j = sum_{k<=j} psi_k
    (k from first_node(clamp): with a clamp, psi_0 turns the clamp frame onto edge 0). One
    thread per strand; the suffix sum C_k = sum_{j>=k} dE_bend/dtheta^j runs from tip to root.
    rotation: the rotation measure, whose node i depends on the frames only through the mid
    frame carried by edge i (dE/dbeta is its frame term)."""
    for s in range(st.x.shape[0]):
        strand_elastic_forces(s, clamp, rotation, md, st)


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


@ti.kernel
def rotation_strains(clamp: ti.template(), node_count: Ints1, kb: Vec3s2, m1: Vec3s2, m2: Vec3s2,
                     theta: Scalars2, stiffness: Vec4s1, voronoi: Scalars2, kappa: Vec4s2):
    """kappa[s, i] = (w, 0): the rotation measure's rotation vector [rad] (about m1, m2, t) of
    every bending node, zero elsewhere: the rest strains, measured with the kernels' own
    rotation_node. One thread per node."""
    for s, i in ti.ndrange(kappa.shape[0], kappa.shape[1]):
        n = node_count[s]
        value = ti.math.vec4(0.0)
        if ti.static(first_node(clamp)) <= i <= n - 2:
            w, _e, _d, _h, _gn, _g_kb = rotation_node(s, i, kb, m1, m2, theta, kappa, voronoi, stiffness[s])
            value = ti.math.vec4(w, 0.0)
        kappa[s, i] = value
