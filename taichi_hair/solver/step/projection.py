"""The projection stage: inextensibility (Goldenthal et al.'s fast projection, or SHAKE) alternating
with the collider pushes and their friction, per strand."""

import taichi as ti

from ...rods.arrays import edge, vec3
from ...rods.linalg import thomas_solve
from ...rods.state import CONTACT_NORMAL, FRICTION_PUSH
from ..collisions import collider_travel, head_poses, strand_collide, strand_reset_friction
from ..pins import HELD_DAMPING
from .plan import PROJ_CAP, PROJ_COUNT, PROJ_IT, PROJ_IT_SUM, PROJ_STALL, STALL_BELOW


# Friction is settled for the step once the lengths are within FRICTION_SETTLED (relative, as
# projection_tol): later contact passes only push nodes out, keeping each node's friction shift,
# and nodes static friction held then stay nearly in place (STUCK_MOBILITY), so the remaining
# Gauss-Newton steps converge as without friction. Re-deciding friction in every pass converged
# linearly. The slip friction no longer sees is the rest of the correction: about
# FRICTION_SETTLED / 2 of an edge on a sliding node, STUCK_MOBILITY of that on a stuck one
# (docs/model.md, "Collisions")
FRICTION_SETTLED = 5e-4


LENGTHS_AFTER_CONTACT = 3  # length-only iterations after a projection with contacts ends unsatisfied


# SHAKE follows the start-of-step constraint gradient while each iteration at least halves the
# residual; slower than that (a head jump, a contact push) it switches to the current gradient
SHAKE_RATE = 0.5


# ... and while every edge stays within acos(SHAKE_TURN_COS) = 8 degrees of its start-of-step
# direction: SHAKE's chord matrix G0 M^-1 G0^T misjudges C's slope along G0 by cos(turn), and an
# edge a contact turned across (a rope piling onto itself) made it overshoot without bound
SHAKE_TURN_COS = 0.99


# ... and while no node has left its prediction x_prev + h v by more than SHAKE_MOVE x its
# predicted displacement h |v| + SHAKE_MOVE_FLOOR x its edge: a strand held taut (straight
# between two held nodes) has a SHAKE solution only far off, long moves along the nearly parallel
# edges that undo a small sag. There the step starts again from the prediction with the current
# gradient, i.e. it is the fast projection's step (docs/model.md "Time step", SHAKE)
SHAKE_MOVE = 2.0


SHAKE_MOVE_FLOOR = 1e-3


@ti.func
def slider_vector(s, n, fl: ti.template(), dr: ti.template()):
    """b = a / sqrt(m_pair) of strand s's slider (its last edge), zero without one: the pair's
    inverse mass is b b^T (pins.py)."""
    b = vec3(0.0)
    if ti.static(fl.clips):
        b = dr.clip[s, n - 2, 2]
    return b


# A contact is held on its surface in the projection (inverse_mass_times) only while its edges
# can still change length tangentially: where holding it would leave an edge's row of
# G M^-1 G^T under HOLD_BELOW of its free value (an edge along the normal, its other node held),
# the node goes free again and the collider pushes it as before
HOLD_BELOW = 0.05


@ti.func
def contact_normal(s, i, fl: ti.template(), st: ti.template()):
    """The outward normal of the surface node i of strand s is held on (collisions.place_contact),
    zero if none."""
    n = vec3(0.0)
    if ti.static(fl.contacts):
        n = st.history[s, i, CONTACT_NORMAL]
    return n


# Once friction has settled, a node static friction held (contact_grip) moves in the projection
# as if 1 / STUCK_MOBILITY times as heavy: nearly held, while the system stays regular where a
# node sits between two held ones on a taut line (with held nodes immovable it is singular)
STUCK_MOBILITY = 0.01


@ti.func
def contact_grip(s, i, fl: ti.template(), st: ti.template()):
    """The friction coefficient of the surface on which static friction held node i of strand s
    when the step's friction settled (settle_friction), 0 if it slid, is free, or friction has
    not settled yet."""
    grip = 0.0
    if ti.static(fl.contacts):
        if st.history[s, i, CONTACT_NORMAL].norm_sqr() > 0.0:
            grip = ti.max(0.0, st.history[s, i, FRICTION_PUSH].z)
    return grip


@ti.func
def settle_friction(s, n, fl: ti.template(), st: ti.template()):
    """The step's friction has settled for strand s (n nodes): the nodes static friction holds
    (collisions.contact_with_friction marks them with -friction) become stuck (contact_grip)."""
    if ti.static(fl.contacts):
        for i in range(n):
            st.history[s, i, FRICTION_PUSH].z = -st.history[s, i, FRICTION_PUSH].z


@ti.func
def sliding_inverse_mass_times(s, i, v, fl: ti.template(), md: ti.template(), st: ti.template()):
    """M_i^-1 v: node i's inverse mass [1/kg] times v, with a node in contact (a collider pushed
    it this step) unable to move along the contact normal n: w_i (I - n n^T) v. So the projection
    slides contacts along their surfaces and its Gauss-Newton steps converge with contacts inside
    (docs/model.md, "Collisions"), where alternating pushes with free-node steps converged
    linearly."""
    n = contact_normal(s, i, fl, st)
    return md.inv_mass[s, i] * (v - v.dot(n) * n)


@ti.func
def contact_mobility(s, i, fl: ti.template(), st: ti.template()):
    """STUCK_MOBILITY for a stuck node (contact_grip), else 1: the factor on its inverse mass."""
    mobility = 1.0
    if contact_grip(s, i, fl, st) > 0.0:
        mobility = STUCK_MOBILITY
    return mobility


@ti.func
def inverse_mass_times(s, i, v, fl: ti.template(), md: ti.template(), st: ti.template()):
    """sliding_inverse_mass_times scaled by contact_mobility."""
    return contact_mobility(s, i, fl, st) * sliding_inverse_mass_times(s, i, v, fl, md, st)


@ti.func
def held_reaction(s, i, pull, fl: ti.template(), md: ti.template(), st: ti.template()):
    """The normal move the hold takes out of node i's correction 2 M_i^-1 pull [m] is its
    surface's reaction, accounted as an accumulated impulse: into the surface it adds to the
    step's pushes P (friction's budget, collisions.resolve_contact); out of it, it takes back
    from P, and past P (a contact pushes, never pulls) the node goes free and moves out by the
    excess. A stuck node (contact_grip) lets go without that move: its multipliers were solved
    with it nearly held, so its pull overstates what it would move free; the next iteration
    moves it as a free node. Returns the move [m] to add to 2 inverse_mass_times(pull)."""
    move = vec3(0.0)
    n_i = contact_normal(s, i, fl, st)
    if n_i.norm_sqr() > 0.0:
        pushed = st.history[s, i, FRICTION_PUSH].x - 2.0 * md.inv_mass[s, i] * pull.dot(n_i)
        if pushed < 0.0:
            if contact_grip(s, i, fl, st) == 0.0:
                move -= pushed * n_i
            st.history[s, i, CONTACT_NORMAL] = vec3(0.0)
            pushed = 0.0
        st.history[s, i, FRICTION_PUSH].x = pushed
    return move


@ti.func
def constraint_edge(s, j, e, shake, fl: ti.template(), st: ti.template()):
    """Edge j's direction in the constraint gradient G, given its current vector e: its
    start-of-step vector under SHAKE while that converges (fl.shake and shake = 1), else e (the
    fast projection)."""
    g = e
    if ti.static(fl.shake):
        if shake:
            g = edge(st.x_prev, s, j, j + 1)
    return g


@ti.func
def solve_inextensibility(s, n, shake, h, fl: ti.template(), md: ti.template(), st: ti.template(),
                          dr: ti.template()):
    """One projection iteration: (G M^-1 G^T) dlambda = C(x) (tridiagonal, assembled in
    diag/upper/rhs by assemble_projection), x -= M^-1 G^T dlambda, G along constraint_edge;
    the correction is added to the step's displacement dx too (see strand_velocities). A
    slider's pair moves by -2 dlambda b (b . e) through the edge before it, along its axis only.
    An extensible edge's tension grows by the force 2 |e| dlambda / h^2 of this iteration."""
    thomas_solve(s, 0, n - 2, st.diag, st.upper, st.rhs)
    if ti.static(fl.stretch):
        for j in range(n - 1):
            st.tension[s, j] += 2.0 * edge(st.x, s, j, j + 1).norm() * st.rhs[s, j] / (h * h)
    slide = vec3(0.0)
    if ti.static(fl.clips):
        b = slider_vector(s, n, fl, dr)
        if b.dot(b) > 0.0 and n >= 3:
            slide = -2.0 * st.rhs[s, n - 3] * b * b.dot(
                constraint_edge(s, n - 3, edge(st.x, s, n - 3, n - 2), shake, fl, st))
    # node i moves by 2 M_i^-1 (lambda_i e^i - lambda_{i-1} e^{i-1}), the edges taken before the
    # move: e^i still reads the old x_i and x_{i+1}, e^{i-1} is kept from the last pass
    e_before = vec3(0.0)
    for i in range(n):
        pull = vec3(0.0)
        e = vec3(0.0)
        if i + 1 < n:
            e = constraint_edge(s, i, edge(st.x, s, i, i + 1), shake, fl, st)
            pull += st.rhs[s, i] * e
        if i > 0:
            pull -= st.rhs[s, i - 1] * e_before
        move = 2.0 * inverse_mass_times(s, i, pull, fl, md, st)
        if ti.static(fl.contacts):
            # what a held contact does not move by is its surface's reaction (friction's budget)
            move += held_reaction(s, i, pull, fl, md, st)
        st.x[s, i] += move
        st.dx[s, i] += move
        e_before = e
    if ti.static(fl.clips):
        for i in ti.static(range(2)):
            st.x[s, n - 2 + i] += slide
            st.dx[s, n - 2 + i] += slide


@ti.func
def assemble_projection(s, n, shake, h, fl: ti.template(), md: ti.template(), st: ti.template(),
                        dr: ti.template(), restart=0):
    """The projection's tridiagonal system G M^-1 G^T (diag, upper) and right-hand side C(x)
    (rhs), G along constraint_edge. An edge with both nodes held (a clip) is prescribed: its row
    is the identity with a zero right-hand side, outside the residual; with pins the diagonal is
    damped (HELD_DAMPING). An extensible strand (fl.stretch) makes each edge a compliant
    constraint (XPBD): diag + alpha_j / h^2 and C_j - alpha_j / h^2 Lambda_j, with Lambda_j =
    h^2 T_j / (2 |e|) the multiplier of the tension T_j [N] the step has applied so far
    (st.tension) and alpha_j = 2 |ebar| |e| (|e| + |ebar|) / EA, so that at convergence
    T_j = EA (|e| - |ebar|) / |ebar| exactly (docs/model.md, "Extensible strands"). Returns
    (max_j of that residual / |ebar^j|^2 over the free edges, 1 if an edge has turned past
    SHAKE_TURN_COS from its G direction, 2 if (under SHAKE, with restart) a node has left its
    prediction by more than SHAKE_MOVE, else 0)."""
    res = 0.0
    turned = 0
    b = slider_vector(s, n, fl, dr)
    for j in range(n - 1):
        e = edge(st.x, s, j, j + 1)
        g = constraint_edge(s, j, e, shake, fl, st)
        w = md.inv_mass[s, j] + md.inv_mass[s, j + 1]
        slide = 0.0  # the slider's share (b . g)^2 of the edge before it
        if ti.static(fl.clips):
            if j == n - 3:
                slide = b.dot(g) * b.dot(g)
        st.rhs[s, j] = 0.0
        st.diag[s, j] = 1.0
        if w > 0.0 or slide > 0.0:
            l2 = md.rest_length[s, j] * md.rest_length[s, j]
            c = e.dot(e) - l2
            st.diag[s, j] = 4.0 * (g.dot(g) * w + slide)
            if ti.static(fl.contacts):
                # whether the edge can change length with its nodes held on their surfaces
                sliding_j = g.dot(sliding_inverse_mass_times(s, j, g, fl, md, st))
                sliding_next = g.dot(sliding_inverse_mass_times(s, j + 1, g, fl, md, st))
                if 4.0 * (sliding_j + sliding_next + slide) >= HOLD_BELOW * st.diag[s, j]:
                    st.diag[s, j] = 4.0 * (contact_mobility(s, j, fl, st) * sliding_j
                                           + contact_mobility(s, j + 1, fl, st) * sliding_next + slide)
                else:  # this edge cannot change length with its contacts held: they go free
                    st.history[s, j, CONTACT_NORMAL] = vec3(0.0)
                    st.history[s, j + 1, CONTACT_NORMAL] = vec3(0.0)
            if ti.static(fl.stretch):
                length = ti.sqrt(e.dot(e))
                rest = md.rest_length[s, j]
                stretch = rest * (length + rest) / md.stiffness[s].w  # alpha / (2 |e|) [m^2/N]
                c -= stretch * st.tension[s, j]
                st.diag[s, j] += 2.0 * length * stretch / (h * h)
            scaled = ti.abs(c) / l2
            if not scaled <= res:  # so that a NaN residual stays NaN and fails the tolerance
                res = scaled
            st.rhs[s, j] = c
            if ti.static(fl.shake):
                if e.dot(g) < SHAKE_TURN_COS * ti.sqrt(e.dot(e) * g.dot(g)):
                    turned = ti.max(turned, 1)
                if restart and md.inv_mass[s, j + 1] > 0.0:
                    predicted = h * st.v[s, j + 1]
                    moved = (st.dx[s, j + 1] - predicted).norm()
                    if not moved <= SHAKE_MOVE * predicted.norm() + SHAKE_MOVE_FLOOR * md.rest_length[s, j]:
                        turned = 2
            if ti.static(fl.pins):
                st.diag[s, j] *= 1.0 + HELD_DAMPING
        if j + 1 < n - 1:
            g_next = constraint_edge(s, j + 1, edge(st.x, s, j + 1, j + 2), shake, fl, st)
            st.upper[s, j] = -4.0 * g.dot(inverse_mass_times(s, j + 1, g_next, fl, md, st))
    return res, turned


@ti.func
def untouched_prediction(s, n, h, md: ti.template(), st: ti.template()):
    """1 if every free node still sits at the step's prediction (dx = h v exactly, as
    strand_symplectic_euler left it), i.e. nothing has moved it since: this is the step's
    first projection (SHAKE may start again from there) and no collider has pushed it yet; 0
    after a strand contact pass or a collider has moved nodes."""
    untouched = 1
    for i in range(n):
        if md.inv_mass[s, i] > 0.0:
            if (st.dx[s, i] - h * st.v[s, i]).norm() > 0.0:
                untouched = 0
    return untouched


@ti.func
def restart_from_prediction(s, n, h, md: ti.template(), st: ti.template()):
    """Free nodes back at the step's prediction x_prev + h v (strand_symplectic_euler) with
    their displacement dx = h v: SHAKE's moves so far are undone."""
    for i in range(n):
        if md.inv_mass[s, i] > 0.0:
            st.dx[s, i] = h * st.v[s, i]
            st.x[s, i] = st.x_prev[s, i] + st.dx[s, i]


@ti.func
def strand_project(s, k, fl: ti.template(), sc, md: ti.template(), st: ti.template(),
                   dr: ti.template(), co: ti.template()):
    """Projection of C_j = |e^j|^2 - |ebar^j|^2 = 0 on every free edge, alternating with the
    contact pushes (Gauss-Seidel): Gauss-Newton steps along the current gradient (the fast
    projection of Goldenthal et al. 2007), or with fl.shake along the start-of-step gradient
    (SHAKE) while each iteration at least halves the residual (SHAKE_RATE) and no edge has turned
    past SHAKE_TURN_COS from its start (else, a head jump or a contact, it switches to the
    current gradient), and while no node has left its prediction by more than SHAKE_MOVE (a
    taut stretch: the step then starts again from the prediction with the current gradient;
    only in a step's first projection of a scene without colliders, untouched_prediction);
    a strand that a collider pushes at the start of its step's first projection takes the fast
    projection for that step. Friction is decided in every contact pass until the residual is
    below FRICTION_SETTLED, and then settles for the step (settle_friction).
    Ends when max_j |C_j| / |ebar^j|^2 < projection_tol after contacts, at
    projection_iterations, or at a stall (an iteration removing less than 10 % of a residual
    already below STALL_BELOW: the precision's rounding floor; far from satisfied, slow progress
    is the nonlinear start of Gauss-Newton and it keeps going). Held nodes (the root, pins) have
    infinite mass (inv_mass 0). Returns (iterations, final residual)."""
    n = md.node_count[s]
    now, prev = head_poses(k, fl, sc.stride)
    it = 0
    res = 0.0
    previous = 0.0
    shake = 0
    restart = 0
    first = 0  # still at the prediction: the step's first projection
    if ti.static(fl.shake):
        shake = 1
        first = untouched_prediction(s, n, sc.h, md, st)
        if ti.static(not fl.contacts):
            restart = first
    settled = 0  # 1: friction settles at the next contact pass, 2: it has (FRICTION_SETTLED)
    just_settled = 0
    if ti.static(fl.contacts):
        # friction's cone holds on the step's totals; the clearances, less the colliders' moves
        strand_reset_friction(s, st, collider_travel(s, k, sc.stride, fl, md, st, dr))
    while True:
        if ti.static(fl.contacts):
            just_settled = 0
            if settled == 1:
                settle_friction(s, n, fl, st)
                settled = 2
                just_settled = 1
            strand_collide(s, now, prev, k + 1, k, sc.n_analytic, fl, md, st, dr, co, False, settled)
            if ti.static(fl.shake):
                if first:
                    # a collider pushed the strand at the step's start: this step is the fast
                    # projection's (SHAKE with the pushes gained energy on curls resting on a
                    # head)
                    if not untouched_prediction(s, n, sc.h, md, st):
                        shake = 0
                    first = 0
        previous = res
        res, turned = assemble_projection(s, n, shake, sc.h, fl, md, st, dr, restart * shake)
        switched = 0
        if ti.static(fl.shake):
            if shake and (turned or (it >= 1 and not res <= SHAKE_RATE * previous)):  # NaN too
                # slow progress here is SHAKE's, not the rounding floor: no stall
                shake = 0
                switched = 1
                if turned == 2:
                    restart_from_prediction(s, n, sc.h, md, st)
                res, _ = assemble_projection(s, n, shake, sc.h, fl, md, st, dr)
        if ti.static(fl.contacts):
            if res < FRICTION_SETTLED and settled == 0:
                settled = 1
        if (res < sc.projection_tol or it >= sc.projection_iterations
                or (it >= 1 and not switched and not just_settled and res < STALL_BELOW and res > 0.9 * previous)):
            break
        solve_inextensibility(s, n, shake, sc.h, fl, md, st, dr)
        it += 1
    if ti.static(fl.contacts):
        # friction that holds puts its nodes back in every iteration, so the alternation can
        # stall with edges up to STALL_BELOW off; a few iterations of the lengths alone finish
        # them, moving held nodes by about that residual x their edge (docs/model.md,
        # "Collisions"). Not further off: that would pull nodes into the colliders.
        extra = 0
        while res >= sc.projection_tol and res < STALL_BELOW and extra < LENGTHS_AFTER_CONTACT:
            solve_inextensibility(s, n, shake, sc.h, fl, md, st, dr)
            res, _ = assemble_projection(s, n, shake, sc.h, fl, md, st, dr)
            extra += 1
            it += 1
    return it, res


@ti.func
def record_projection(s, st: ti.template(), it, res, tol, max_iterations):
    """Running maxima of iterations and final residual, the iterations' sum and the number of
    projections (their mean); counts of steps that ended above tol at the iteration cap, or
    stalled at the rounding floor."""
    st.counters[s, PROJ_IT] = ti.max(st.counters[s, PROJ_IT], it)
    st.counters[s, PROJ_IT_SUM] += it
    st.counters[s, PROJ_COUNT] += 1
    st.residuals[s, 0] = ti.max(st.residuals[s, 0], res)
    if res >= tol:
        if it >= max_iterations:
            st.counters[s, PROJ_CAP] += 1
        else:
            st.counters[s, PROJ_STALL] += 1
