"""The implicit step (integrator="implicit", docs/model.md "The implicit step"): linearised
BDF2 with the edge lengths as constraints inside one block-banded solve per strand, a Newton
step back onto the lengths and out of the colliders in the same metric, then the fast
projection as in the explicit step; velocities from BDF2's difference formula.

Per strand, with hh = 2h/3 and the history x_{n-1} = x_n - dx_prev, v_{n-1}:

    [ M + hh D + hh^2 (K + K_t)   G^T ] [ v_{n+1} ]   [ M vhat + hh (f_n + r_n + D v_n - (K + K_t) dx_prev / 3) ]
    [ G                           0   ] [ lambda  ] = [ -(|e| - l + G dx_prev / 3) / hh                         ]

    vhat = (4 v_n - v_{n-1}) / 3,   x_{n+1} = xhat + hh v_{n+1},   xhat = x_n + dx_prev / 3,

K the Gauss-Newton Hessian of the elastic energy over the positions and the free edges'
material angles (implicit_jacobians.node_strain_jacobians), whose angle rows say the twist
stays at equilibrium, so the solve condenses them out; K_t the constraints' geometric
stiffness from the last step's tensions (K + K_t also holds the grab springs' stiffness K_g when a scene has grab
tools), r_n the part of the last step's elastic force change that the condensed K did not
predict, D the air drag's diagonal, G the edges' unit tangents (t . (v_i - v_{i-1}) per edge,
rows scaled by the node mass), lambda the edges' impulses. A bending or twist stencil couples
nodes i-1..i+1: with each edge's multiplier and angle stored with its far node the matrix is
block-pentadiagonal in 5x5 node blocks, symmetric and indefinite, and factored by block LDL^T
without pivoting in O(n) per strand (one thread per strand), in float64 in both precisions.
Held nodes (the root, pins) keep identity rows: the root placement and pins set them after.
"""

import taichi as ti

from ..rods.arrays import edge, mat_block, point, step_displacement, vec3, vec3d, vec_block
from ..rods.linalg import product, thomas_solve
from ..rods.modes import Root
from ..rods.state import HIST_CHANGE, HIST_DX, HIST_ELASTIC, HIST_V
from ..rods.rod import first_node
from ..world.forces import grab_force, grab_stiffness
from .collisions import head_poses, strand_collide, strand_reset_friction
from .implicit_jacobians import node_strain_jacobians
from .pins import HELD_DAMPING

ROOT_CLAMPED = Root.CLAMPED.code


@ti.func
def theta_free(i, clamp: ti.template(), twist_free: ti.template()):
    """1 if node i's angle unknown (edge i-1's) is solved for, else 0 (node 0's is the clamp's
    or none; a hinge root's edge 0 keeps its angle; twist="none" solves none)."""
    free = 0
    if ti.static(twist_free):
        if i - 1 >= ti.static(first_node(clamp)):
            free = 1
    return free


@ti.func
def assemble_stiffness(s, clamp: ti.template(), twist_free: ti.template(), rotation: ti.template(), scale,
                       md: ti.template(), st: ti.template(), load_history=1):
    """blocks += scale K, K the Gauss-Newton Hessian sum_i J_i^T W_i J_i of the energy over the
    free nodes' positions and the free edges' angles (node_strain_jacobians; blocks as in
    block_pentadiagonal_solve). With load_history, st.dx += K_xx dx_prev [N] on every node
    and block_rhs[., 4] += K_theta,x dx_prev [J/rad] (held nodes' displacements included: a
    moving root's last displacement loads its neighbours); condense_history then turns st.dx
    into the condensed K dx_prev."""
    n = md.node_count[s]
    for i in range(ti.static(first_node(clamp)), n - 1):
        jac0, jac1, jac2, weight = node_strain_jacobians(s, i, clamp, twist_free, rotation, md, st)
        if load_history:
            strain = vec_block(0.0)
            for a in ti.static(range(3)):
                d = ti.cast(st.history[s, ti.max(i - 1 + a, 0), HIST_DX], ti.f64)  # J0 = 0 at node 0
                strain += (jac0, jac1, jac2)[a] @ vec_block(d.x, d.y, d.z, 0.0, 0.0)
            y = weight * strain
            for a in ti.static(range(3)):
                na = i - 1 + a
                if na >= 0:
                    back = (jac0, jac1, jac2)[a].transpose() @ y
                    st.dx[s, na] += ti.cast(vec3d(back[0], back[1], back[2]), float)
                    st.block_rhs[s, na][4] += back[4]
        for a in ti.static(range(3)):  # held nodes' positions are not unknowns
            if i - 1 + a >= 0:
                if md.inv_mass[s, i - 1 + a] == 0.0:
                    for r in ti.static(range(5)):
                        for c in ti.static(range(3)):
                            (jac0, jac1, jac2)[a][r, c] = 0.0
        jac = (jac0, jac1, jac2)
        for a in ti.static(range(3)):
            weighted = scale * (weight.outer_product(vec_block(1.0)) * jac[a])  # W J_a, row-scaled
            for b in ti.static(range(a + 1)):
                nb = i - 1 + b
                if nb >= 0:
                    st.blocks[s, i - 1 + a, a - b] += product(weighted, jac[b], True, False)


@ti.func
def condense_history(s, n, clamp: ti.template(), scale, md: ti.template(), st: ti.template()):
    """st.dx -= K_x,theta K_theta,theta^-1 K_theta,x dx_prev [N] on free nodes, after
    assemble_stiffness(load_history) has left scale K in the blocks and K_theta,x dx_prev in
    block_rhs[., 4]: st.dx then holds the condensed stiffness (the angles at equilibrium)
    times dx_prev, what the step's system predicted for the last step's displacement. One
    tridiagonal solve over the free angles (st.diag, st.upper, st.rhs as scratch)."""
    lo = ti.static(first_node(clamp))
    for j in range(lo, n - 1):  # edge j's angle lives with node j + 1
        st.diag[s, j] = ti.cast(st.blocks[s, j + 1, 0][4, 4] / scale, float)
        st.rhs[s, j] = ti.cast(st.block_rhs[s, j + 1][4], float)
        if j + 2 < n:
            st.upper[s, j] = ti.cast(st.blocks[s, j + 2, 1][4, 4] / scale, float)
    thomas_solve(s, lo, n - 2, st.diag, st.upper, st.rhs)
    for r in range(n):
        if md.inv_mass[s, r] > 0.0:
            coupled = vec3d(0.0)
            for k in ti.static(range(-2, 3)):
                c = r + k  # node c's angle: edge c-1's
                if c - 1 >= lo and c < n:
                    z = ti.cast(st.rhs[s, c - 1], ti.f64)
                    if ti.static(k <= 0):
                        block = st.blocks[s, r, -k]
                        coupled += z * vec3d(block[0, 4], block[1, 4], block[2, 4])
                    else:
                        block = st.blocks[s, c, k]
                        coupled += z * vec3d(block[4, 0], block[4, 1], block[4, 2])
            st.dx[s, r] -= ti.cast(coupled / scale, float)


@ti.func
def assemble_tension(s, n, scale, load_history, md: ti.template(), st: ti.template()):
    """The constraints' geometric stiffness with the last step's tensions tau_j [N] (tension
    only: max(tau, 0)): tau_j / |e_j| (I - t_j t_j^T) couples the edge's nodes (+ on each
    node, - between them). blocks += scale times it (free-free couplings); with load_history,
    st.dx += it times dx_prev [N]. Without it the step linearises the constraint forces as if
    they did not turn with the edges, a first-order error: a swinging chain gained energy at
    O(h)."""
    for j in range(n - 1):
        tau = st.tension[s, j]
        if tau > 0.0:
            e = st.x[s, j + 1] - st.x[s, j]  # float64 positions (arrays.Points2)
            length = e.norm()
            t = e / length
            k = (ti.cast(tau, ti.f64) / length) * (ti.Matrix.identity(ti.f64, 3) - t.outer_product(t))
            if load_history:
                pull = ti.cast(k @ ti.cast(st.history[s, j + 1, HIST_DX] - st.history[s, j, HIST_DX], ti.f64), float)
                st.dx[s, j + 1] += pull
                st.dx[s, j] -= pull
            w0 = md.inv_mass[s, j]
            w1 = md.inv_mass[s, j + 1]
            if w0 > 0.0:
                st.blocks[s, j, 0] += embed(scale * k)
            if w1 > 0.0:
                st.blocks[s, j + 1, 0] += embed(scale * k)
            if w0 > 0.0 and w1 > 0.0:
                st.blocks[s, j + 1, 1] -= embed(scale * k)


@ti.func
def assemble_grab_stiffness(s, k, scale, load_history, md: ti.template(), st: ti.template(), dr: ti.template()):
    """The grab springs' stiffness K_g (forces.grab_stiffness, at step k's grab points) on the
    free nodes' diagonal blocks, times scale. With load_history (the predictor) also st.dx +=
    K_g dx_prev [N], as for K, and st.force takes the grab points at the step's end, k + 1:
    lagging a step behind a stiff grab is an O(h) error the stiffness then pulls back hard.
    Outside the matrix a stiff grab is an explicit spring, unstable past h ~ 2/sqrt(k/m) (a
    100 N/m grab on a 6.5e-9 kg node: 16 us)."""
    for i in range(md.node_count[s]):
        if md.inv_mass[s, i] > 0.0:
            p = point(st.x, s, i)
            kg = grab_stiffness(dr.tools, dr.tool_points, k, p)
            if load_history:
                st.dx[s, i] += ti.cast(kg @ ti.cast(st.history[s, i, HIST_DX], ti.f64), float)
                st.force[s, i] += (grab_force(dr.tools, dr.tool_points, k + 1, p)
                                   - grab_force(dr.tools, dr.tool_points, k, p))
            st.blocks[s, i, 0] += embed(scale * kg)


@ti.func
def record_elastic_change(s, md: ti.template(), st: ti.template()):
    """elastic_change = force - elastic_prev, elastic_prev = force, with force holding only the
    elastic forces (called between them and the external ones); NaN where no earlier force is
    known (the first step after seed_history)."""
    for i in range(md.node_count[s]):
        f = st.force[s, i]
        st.history[s, i, HIST_CHANGE] = f - st.history[s, i, HIST_ELASTIC]
        st.history[s, i, HIST_ELASTIC] = f


@ti.func
def embed(m):
    """The 3x3 matrix m as the upper-left block of a node block (the node's velocity rows)."""
    out = mat_block(0.0)
    for r in ti.static(range(3)):
        for c in ti.static(range(3)):
            out[r, c] = m[r, c]
    return out


@ti.func
def velocity_row(t, value):
    """A node block whose only nonzero row is the multiplier's: (t, value, 0) (a constraint's row)."""
    out = mat_block(0.0)
    for c in ti.static(range(3)):
        out[3, c] = t[c]
    out[3, 3] = value
    return out


@ti.func
def assemble_constraints(s, n, history, inv_step, md: ti.template(), st: ti.template()):
    """The length rows: node i's fourth unknown is the multiplier of edge i-1 (so the leading
    blocks stay invertible with a held root), its row c t . (v_i - v_{i-1}) hh = -c ((|e| - l)
    + t . (dx_prev_i - dx_prev_{i-1}) / 3), t the edge's unit tangent, c = m_i the node's mass:
    the scale that keeps the rows' entries near the velocity blocks' (hair nodes weigh ~1e-11
    kg; unscaled, float32 pivots lose every digit). Held nodes' velocities are not unknowns;
    an edge held at both ends gets an identity row."""
    for i in range(1, n):
        e = edge(st.x, s, i - 1, i)
        length = e.norm()
        c = md.mass[s, i]
        t = c * e / length
        w_prev = md.inv_mass[s, i - 1]
        w_next = md.inv_mass[s, i]
        rhs = st.block_rhs[s, i]
        if w_prev + w_next > 0.0:
            gap = c * (length - md.rest_length[s, i - 1]) + history * t.dot(st.history[s, i, HIST_DX] - st.history[s, i - 1, HIST_DX])
            rhs[3] = -gap * inv_step
            # a taut stretch held at both ends (pins) is singular: damped as the projection is
            d = velocity_row(vec3(0.0), -HELD_DAMPING * (w_prev + w_next) * c * c)
            if w_next > 0.0:
                d += velocity_row(t, 0.0)
                d += velocity_row(t, 0.0).transpose()
            st.blocks[s, i, 0] += d
            if w_prev > 0.0:
                st.blocks[s, i, 1] += velocity_row(-t, 0.0)
        else:
            st.blocks[s, i, 0] += velocity_row(vec3(0.0), c)
        st.block_rhs[s, i] = rhs
    st.blocks[s, 0, 0] += velocity_row(vec3(0.0), md.mass[s, 0])  # node 0 has no edge before it


@ti.func
def clear_system(s, n, clear_dx, st: ti.template()):
    """Zero strand s's blocks and right-hand side (and with clear_dx its dx, the K dx_prev
    accumulator)."""
    for i in range(n):
        if clear_dx:
            st.dx[s, i] = vec3(0.0)
        st.block_rhs[s, i] = vec_block(0.0)
        for b in ti.static(range(3)):
            st.blocks[s, i, b] = mat_block(0.0)


@ti.func
def strand_implicit_assemble(s, k, correction: ti.template(), h, drag, twist_free: ti.template(),
                             fl: ti.template(), sc, md: ti.template(), st: ti.template(), dr: ti.template(),
                             co: ti.template()):
    """The system of one of the step's solves (module doc) in st.blocks, st.block_rhs, for
    linalg.block_pentadiagonal_solve and then strand_implicit_finish: the predictor, or a length
    correction (repeated while an edge is off by more than CORRECTION_TOL), chosen at compile
    time. Assembly, solve and finish each run in kernels of their own (step/implicit_launches.py, the implicit
    driver): they dominate the step's compile time, and a kernel's compile time grows faster
    than its size.

    correction 0, the BDF2 predictor: solves for v_{n+1} with the edge lengths linearised
    inside the solve, records the tensions, sets x_prev = x_n, v_{n-1} = v_n, dx = x_{n+1} - x_n
    and x = x_{n+1} on free nodes (held nodes: dx = 0, placed after).
    correction 1, after the root and pins are placed: one Newton step back onto the edge
    lengths (and the contacts' targets, below) in the step's own metric, the smallest move in
    (M + hh^2 (K + K_t)) (the angles following at equilibrium) with
    t_j . (move_{j+1} - move_j) = -(|e_j| - l_j), added to x and dx. The predictor holds the
    lengths only to first order; the fast projection that follows removes the rest in the
    metric M, which for stiff hair over a large step is a kink (a falling hair gained 27 % of
    the energy in play in 0.2 s at 20 ms without this).
    The correction also takes the deep contacts (fl.contacts): each node the fast projection
    would push by more than collisions.SPRING_PUSH of its edge (friction included) gets a stiff
    spring to where it would be pushed, so the strand follows the push in the same metric
    instead of the projection kinking it (5 mm curls resting on a head gained 0.74 of the
    energy in play in 0.2 s without this). Shallow pushes stay with the projection: as springs
    they made resting contact sticky (collisions.SPRING_PUSH)."""
    clamp, touch = ti.static(fl.root_mode == ROOT_CLAMPED, fl.touch)
    n = md.node_count[s]
    hh = 2.0 * h / 3.0
    predict = ti.static(correction == 0)
    clear_system(s, n, predict, st)
    assemble_stiffness(s, clamp, twist_free, fl.rotation, hh * hh, md, st, predict)
    if ti.static(predict):
        if ti.static(twist_free):
            condense_history(s, n, clamp, hh * hh, md, st)
        # the part of the last step's elastic force change that K missed (module doc), carried
        # into this step: r = f_n - f_{n-1} + K dx_prev (st.dx holds K dx_prev here, the angles
        # at equilibrium)
        for i in range(n):
            r = st.history[s, i, HIST_CHANGE] + st.dx[s, i]
            if not (r.dot(r) >= 0.0):  # NaN: no earlier force yet
                r = vec3(0.0)
            st.history[s, i, HIST_CHANGE] = r
    assemble_tension(s, n, hh * hh, predict, md, st)
    if ti.static(touch):
        assemble_grab_stiffness(s, k, hh * hh, predict, md, st, dr)
    for i in range(n):
        rhs = vec3(0.0)
        diagonal = 1.0
        if md.inv_mass[s, i] > 0.0:
            diagonal = md.mass[s, i]
            if ti.static(predict):
                damping = drag * md.voronoi[s, i]
                vhat = (4.0 * st.v[s, i] - st.history[s, i, HIST_V]) / 3.0
                rhs = md.mass[s, i] * vhat + hh * (st.force[s, i] + st.history[s, i, HIST_CHANGE]
                                                   + damping * st.v[s, i] - st.dx[s, i] / 3.0)
                diagonal += hh * damping
        block = embed(diagonal * ti.Matrix.identity(float, 3))
        if not theta_free(i, clamp, twist_free):
            block[4, 4] = 1.0
        st.blocks[s, i, 0] += block
        # the angles' rows: 0 = K_theta,x (x_{n+1} - xhat) + K_theta,theta (theta_{n+1} - theta_n)
        # (the twist at equilibrium at x_n; st.dx's condensed K takes in xhat - x_n)
        st.block_rhs[s, i] = vec_block(rhs.x, rhs.y, rhs.z, 0.0, 0.0)
    # the predictor's rows hold the history and are in velocities, the correction's in moves
    assemble_constraints(s, n, 1.0 / 3.0 if ti.static(predict) else 0.0, 1.0 / hh if ti.static(predict) else 1.0,
                         md, st)
    if ti.static(not predict):
        if ti.static(fl.contacts):
            now, prev = head_poses(k, fl)
            strand_reset_friction(s, st)  # each correction's springs take one pass's friction
            strand_collide(s, now, prev, k + 1, k, sc.n_analytic, fl, md, st, dr, co, True)


@ti.func
def strand_implicit_finish(s, correction: ti.template(), h, md: ti.template(), st: ti.template()):
    """Take the solution of strand_implicit_assemble's system (solved in place by
    linalg.block_pentadiagonal_solve):
    the predictor (correction 0) records the tensions, sets x_prev = x_n, v_{n-1} = v_n, v =
    v_{n+1}, dx = x_{n+1} - x_n and x = x_{n+1} on free nodes (held nodes: dx = 0, placed
    after); a correction adds its move to x and dx."""
    predict = ti.static(correction == 0)
    n = md.node_count[s]
    hh = 2.0 * h / 3.0
    if ti.static(predict):
        for i in range(1, n):  # the multiplier of edge i-1, scaled by m_i (assemble_constraints)
            st.tension[s, i - 1] = ti.cast(st.block_rhs[s, i][3], float) * md.mass[s, i] / hh
    for i in range(n):
        if ti.static(predict):
            st.x_prev[s, i] = st.x[s, i]
            st.history[s, i, HIST_V] = st.v[s, i]
        if md.inv_mass[s, i] > 0.0:
            y = st.block_rhs[s, i]
            solved = ti.cast(vec3d(y[0], y[1], y[2]), float)
            if ti.static(predict):
                st.v[s, i] = solved
                st.dx[s, i] = st.history[s, i, HIST_DX] / 3.0 + hh * solved
                st.x[s, i] += st.dx[s, i]
            else:
                st.x[s, i] += solved
                st.dx[s, i] += solved


CORRECTION_TOL = 1e-4  # relative length error a length correction must leave, else it repeats
MAX_CORRECTIONS = 4


@ti.func
def length_residual(s, node_count: ti.template(), inv_mass: ti.template(), rest_length: ti.template(),
                    x: ti.template()):
    """max_j | |e_j| - l_j | / l_j over strand s's edges with a free node (relative)."""
    worst = 0.0
    for j in range(node_count[s] - 1):
        if inv_mass[s, j] + inv_mass[s, j + 1] > 0.0:
            rest = rest_length[s, j]
            worst = ti.max(worst, ti.abs(edge(x, s, j, j + 1).norm() - rest) / rest)
    return worst


@ti.func
def strand_implicit_velocities(s, sc, md: ti.template(), st: ti.template()):
    """v_{n+1} = (3 (x_{n+1} - x_n) - (x_n - x_{n-1})) / 2h, BDF2's velocity of the projected
    positions, from the displacements (dx on free nodes, x - x_prev on held ones: see
    step.strand_velocities on why not from x); dx_prev takes this step's displacement.
    Returns 1 if a node is non-finite or faster than max_speed, else 0."""
    bad = 0
    inv_2h = 0.5 / sc.h
    for i in range(md.node_count[s]):
        disp = st.dx[s, i]
        if md.inv_mass[s, i] == 0.0:
            disp = step_displacement(st.x, st.x_prev, s, i)
        vel = (3.0 * disp - st.history[s, i, HIST_DX]) * inv_2h
        st.v[s, i] = vel
        st.history[s, i, HIST_DX] = disp
        if not (vel.dot(vel) <= sc.max_speed * sc.max_speed):
            bad = 1
    return bad
