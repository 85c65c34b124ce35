"""Contact stage: push nodes out of colliders and hands, with friction. Runs inside the fast
projection (see step.strand_project), alternating with the inextensibility solve; a pass queries
only the nodes that can have reached a collider since their last query."""

import taichi as ti

from ..rods.arrays import mat_block, point, step_displacement, vec3, vec_block
from ..rods.state import CONTACT_CLEARANCE, CONTACT_NORMAL, CONTACT_QUERY, FRICTION_PUSH, FRICTION_SHIFT
from ..rods.linalg import rotate_rows, unrotate_rows
from ..world.colliders import GRID_META_ROWS, analytic_distance, grid_distance, sphere_distance
from ..world.forces import HAND


@ti.func
def head_rotate(head: ti.template(), k, p):
    """R p: vector p turned by head pose k's rotation (head[k, 0..2] its rows, head[k, 3] t)."""
    return rotate_rows(head[k, 0], head[k, 1], head[k, 2], p)


@ti.func
def to_head(head: ti.template(), k, p):
    """R^T (p - t): world point p [m] in head coordinates at head pose k."""
    return unrotate_rows(head[k, 0], head[k, 1], head[k, 2], p - head[k, 3])


@ti.func
def head_poses(k, fl: ti.template(), stride=1):
    """(now, prev): the head pose indices ending and starting a step from launch step k over
    `stride` launch steps (the step package's doc)."""
    now = 1
    prev = 0
    if ti.static(fl.moving_head):
        now = k + stride
        prev = k
    elif k > 0:
        prev = 1
    return now, prev


@ti.func
def from_head(head: ti.template(), k, p):
    """R p + t: head-coordinate point p [m] in the world at head pose k."""
    return head_rotate(head, k, p) + head[k, 3]


@ti.func
def resolve_contact(p, p_prev, d, n, margin, friction, shift, pushed):
    """Move p (distance d [m], outward normal n, both in the collider's frame) out to the margin,
    with Coulomb friction on the step's totals: shift [m] is the friction displacement applied
    to the node so far this step, pushed [m] its pushes so far. The node's slip along the
    surface since p_prev, less that shift, is cancelled by a new shift of at most friction x
    (pushed + this push): static friction while the slip fits in the cone, else it is
    shortened by the cone's length. Returns (moved, new shift, new pushed, grip): grip is the
    friction coefficient where static friction holds (the whole slip cancelled), else 0."""
    push = margin - d
    total = pushed + push
    # only the shift's part along this surface is taken back: its normal part, left by an
    # earlier iteration's normal, keeps p out of the surface like a push
    moved = p + push * n - (shift - shift.dot(n) * n)
    slip = moved - p_prev
    tangential = slip - slip.dot(n) * n
    length = tangential.norm()
    new_shift = vec3(0.0)
    grip = 0.0
    if friction > 0.0 and friction * total >= length:
        grip = friction
    if length > 1e-12:
        new_shift = -ti.min(1.0, friction * total / length) * tangential
    return moved + new_shift, new_shift, total, grip


# Distances change at most DISTANCE_SLOPE times as fast as a node moves (1 for exact distances;
# the distance grid's trilinear values and the ellipsoid's estimate may run a little faster): a
# node whose clearance at its last query exceeds DISTANCE_SLOPE x its move since then cannot have
# reached a margin, and a contact pass skips it
DISTANCE_SLOPE = 2.0
UNQUERIED = -1.0  # a clearance that makes the next pass query the node
# Clearances are kept for two groups of colliders (CONTACT_CLEARANCE.x and .z) so that a node near
# one is not queried against the other: the first distance grid (GRID: the head's, where most hair
# rests), and everything else (SHAPES: the analytic shapes, the hands and any further grid, such
# as the default head's bust); a pass's queries are flagged by bit in .y
SHAPES, GRID = 1, 2


@ti.func
def strand_reset_friction(s, st: ti.template(), travel=-1.0):
    """A new step's contact state for strand s: no friction shift, no push nor contact normal
    yet. The clearances found by earlier queries (plan_queries) stand, less DISTANCE_SLOPE x
    travel [m], a bound on how far the colliders have moved since (collider_travel); travel < 0
    (the default) has every node queried afresh."""
    for i in range(st.history.shape[1]):
        st.history[s, i, FRICTION_SHIFT] = vec3(0.0)
        st.history[s, i, FRICTION_PUSH] = vec3(0.0)
        st.history[s, i, CONTACT_NORMAL] = vec3(0.0)
        clearance = vec3(UNQUERIED, 0.0, UNQUERIED)
        if travel >= 0.0:
            clearance = st.history[s, i, CONTACT_CLEARANCE] - vec3(DISTANCE_SLOPE * travel, 0.0, DISTANCE_SLOPE * travel)
            clearance.y = 0.0
        st.history[s, i, CONTACT_CLEARANCE] = clearance


@ti.func
def collider_travel(s, k, stride, fl: ti.template(), md: ti.template(), st: ti.template(), dr: ti.template()):
    """A bound [m] on how far any collider surface near strand s moves during step k, relative to
    the world: the head's move |t' - t| + |R' - R|_F r at the strand's nodes (r: the farthest
    node's distance from the head's origin at the step's start; the projection's moves within the
    step change r by far less than a clearance) and every hand's move. 0 for a still head and no
    hands. The step runs from launch step k over `stride` of them."""
    now, prev = head_poses(k, fl, stride)
    head = ti.static(dr.head)
    turn = 0.0
    for r in ti.static(range(3)):
        turn += (head[now, r] - head[prev, r]).norm_sqr()
    reach = 0.0
    for i in range(md.node_count[s]):
        reach = ti.max(reach, (point(st.x, s, i) - head[prev, 3]).norm_sqr())
    travel = (head[now, 3] - head[prev, 3]).norm() + ti.sqrt(turn * reach)
    if ti.static(fl.touch):
        for t in range(dr.tools.shape[0]):
            if ti.cast(dr.tools[t][0], ti.i32) == HAND:
                travel = ti.max(travel, (dr.tool_points[k + 1, t] - dr.tool_points[k, t]).norm())
    return travel


@ti.func
def plan_queries(s, n, n_analytic, st: ti.template()):
    """Which nodes of strand s this contact pass queries, per group of colliders (SHAPES, GRID;
    bits of CONTACT_CLEARANCE.y): those that may have reached a margin of that group since their
    last query (DISTANCE_SLOPE), measured from the position then (CONTACT_QUERY), which holds
    across steps and any move of the node (a rollback, set_positions); and a node held on a
    surface (in_contact), in that surface's group, in every pass. A queried node's query position
    moves to where it is, its other group's clearance lowered to stay valid from there; the
    queried group's clearance starts afresh and each query lowers it (note_clearance)."""
    for i in range(n):
        c = st.history[s, i, CONTACT_CLEARANCE]
        reach = DISTANCE_SLOPE * (point(st.x, s, i) - st.history[s, i, CONTACT_QUERY]).norm()
        holder = held_by(s, i, st)
        on_grid = holder == n_analytic + 1
        shapes = not (c.x > reach) or (holder != 0 and not on_grid)  # written so that NaN queries
        grid = not (c.z > reach) or on_grid
        if shapes or grid:
            c = vec3(c.x - reach, 0.0, c.z - reach)
            if shapes:
                c.x = ti.math.inf
                c.y += SHAPES
            if grid:
                c.z = ti.math.inf
                c.y += GRID
            st.history[s, i, CONTACT_QUERY] = point(st.x, s, i)
        else:
            c.y = 0.0
        st.history[s, i, CONTACT_CLEARANCE] = c


@ti.func
def queried(s, i, group, springs: ti.template(), st: ti.template()):
    """Whether this contact pass queries node i against the colliders of `group` (SHAPES or GRID;
    always in the implicit correction's springs mode)."""
    result = True
    if ti.static(not springs):
        result = (ti.cast(st.history[s, i, CONTACT_CLEARANCE].y, ti.i32) & group) != 0
    return result


@ti.func
def note_clearance(s, i, d, margin, group, springs: ti.template(), st: ti.template()):
    """Node i was found d [m] from a collider of `group` with this margin [m]: the group's
    clearance is the least."""
    if ti.static(not springs):
        c = st.history[s, i, CONTACT_CLEARANCE]
        if group == SHAPES:
            c.x = ti.min(c.x, d - margin)
        else:
            c.z = ti.min(c.z, d - margin)
        st.history[s, i, CONTACT_CLEARANCE] = c


# A collider's surface as contact_with_friction takes it: its margin [m], friction coefficient,
# and whether friction has settled for the step (nonzero: pushes only, projection.FRICTION_SETTLED)
ContactSurface = ti.types.struct(margin=float, friction=float, settled=ti.i32)


@ti.func
def contact_with_friction(s, i, on_head, head: ti.template(), now, local, local_prev, d, n, surface, contact,
                          st: ti.template()):
    """resolve_contact for node i of strand s, d [m] from a collider's surface (ContactSurface)
    along its normal n, in the collider's frame (head coordinates at pose now when on_head), its
    step totals (st.history's FRICTION_SHIFT in world axes and FRICTION_PUSH) read and written
    back, so a node touching a head and a world collider in one step keeps one budget; `contact`
    names the collider (held_by). Once friction has settled (surface.settled) the node is only
    pushed out, its shift and grip kept. Returns the moved point in the world."""
    push = st.history[s, i, FRICTION_PUSH]
    moved = local + (surface.margin - d) * n
    if surface.settled:
        st.history[s, i, FRICTION_PUSH] = vec3(push.x + surface.margin - d, contact, push.z)
    else:
        shift = st.history[s, i, FRICTION_SHIFT]
        if on_head:
            shift = unrotate_rows(head[now, 0], head[now, 1], head[now, 2], shift)
        moved, shift, total, grip = resolve_contact(local, local_prev, d, n, surface.margin, surface.friction, shift,
                                                    push.x)
        if on_head:
            shift = head_rotate(head, now, shift)
        st.history[s, i, FRICTION_SHIFT] = shift
        # -grip: held by static friction, stuck once friction settles (projection.settle_friction)
        st.history[s, i, FRICTION_PUSH] = vec3(total, contact, -grip)
    if on_head:
        moved = from_head(head, now, moved)
    return moved


# A node the projection holds on a surface (CONTACT_NORMAL) may end its slide along the tangent
# up to this fraction of its edge off a curved surface (of order slide^2 / radius); within it the
# contact stays, taken back to the surface with its friction, and beyond it the node goes free
HOLD_REACH = 0.1


@ti.func
def in_contact(s, i, contact, d, margin, springs: ti.template(), md: ti.template(), st: ti.template()):
    """Whether node i of strand s, d [m] from collider `contact` (held_by's numbering), is in
    contact with it: inside the margin, or held on it by the projection (projection.py) and
    within HOLD_REACH of its edge beyond the margin. A held node beyond that goes free."""
    touching = d < margin
    if ti.static(not springs):
        if not touching and held_by(s, i, st) == contact:
            if d < margin + HOLD_REACH * md.rest_length[s, ti.max(i - 1, 0)]:
                touching = True
            else:
                st.history[s, i, CONTACT_NORMAL] = vec3(0.0)
    return touching


@ti.func
def held_by(s, i, st: ti.template()):
    """The collider holding node i of strand s in this step's projection: c + 1 for collider c
    (the analytic ones, then the distance grids), -1 - k for hand k, 0 if none."""
    contact = 0
    if st.history[s, i, CONTACT_NORMAL].norm_sqr() > 0.0:
        contact = ti.cast(st.history[s, i, FRICTION_PUSH].y, ti.i32)
    return contact


@ti.func
def collider_frame(on_head, head: ti.template(), k, p):
    """Point p [m] in the collider's frame: head coordinates at head pose k, or the world."""
    local = p
    if on_head:
        local = to_head(head, k, p)
    return local


def root_keeps_collider(root_distance, margin):
    """The rule strand_collide applies on the device, for host-side checks: a strand collides
    with a collider unless its root lies inside it by more than the collider's margin [m]."""
    return root_distance >= -margin


CONTACT_SPRING = 1e4  # contact spring / the node's largest diagonal entry (contact_spring)
# Pushes deeper than this fraction of the node's edge go into the implicit step's correction as
# springs (place_contact). A spring holds the node in all three directions through the
# correction, so resting contact stuck where the projection lets it slide: at dt = 1 ms the
# curly scene's tips sat 1.2e-2 of L from the reference with every push a spring, 1.2e-3 with
# none; deep pushes left to the projection kink stiff curls (docs/model.md, "The implicit step").
SPRING_PUSH = 0.05


@ti.func
def contact_spring(s, i, target, st: ti.template()):
    """Inside the implicit step's length correction (springs mode of strand_collide): a spring
    w (target - x_i) on node i's rows of the correction's system, w = CONTACT_SPRING x the
    node's largest diagonal entry, so the solve moves the node to its contact target to ~1e-4
    of the push and the rest of the strand follows in the step's metric."""
    block = st.blocks[s, i, 0]
    w = CONTACT_SPRING * ti.max(block[0, 0], block[1, 1], block[2, 2])
    spring = mat_block(0.0)
    for r in ti.static(range(3)):
        spring[r, r] = w
    st.blocks[s, i, 0] = block + spring
    push = ti.cast(target - point(st.x, s, i), ti.f64) * w
    st.block_rhs[s, i] += vec_block(push.x, push.y, push.z, 0.0, 0.0)


@ti.func
def place_contact(s, i, target, normal, springs: ti.template(), md: ti.template(), st: ti.template()):
    """Node i of strand s to its contact target [m] (world) on a surface of outward normal
    `normal` (world axes): placed (dx = x - x_prev) and the normal noted for the projection
    (CONTACT_NORMAL), or with springs pulled there by the implicit correction's solve
    (contact_spring) if the push is deeper than SPRING_PUSH of the node's edge (shallower ones
    are left to the fast projection after the solve)."""
    if ti.static(springs):
        if (target - point(st.x, s, i)).norm() > SPRING_PUSH * md.rest_length[s, ti.max(i - 1, 0)]:
            contact_spring(s, i, target, st)
    else:
        st.x[s, i] = target
        st.dx[s, i] = step_displacement(st.x, st.x_prev, s, i)  # placed, not moved by: see strand_velocities
        st.history[s, i, CONTACT_NORMAL] = normal


@ti.func
def strand_collide(s, now, prev, tool_now, tool_prev, n_analytic, fl: ti.template(), md: ti.template(),
                   st: ti.template(), dr: ti.template(), co: ti.template(), springs: ti.template() = False,
                   settled=0):
    """Resolve every free node of strand s against the colliders (co: analytic table, optional
    distance grid; fl.mesh), and the hands (fl.touch). Head-attached shapes are handled in head
    coordinates so their friction sees the motion relative to the moving head (head poses now /
    prev); hands sit at tool_points[tool_now] (tool_prev before the step). A collider that holds
    the strand's own root deeper than its margin (signed distance < -margin) is skipped for
    that strand: pushing its nodes out would fight the held root every step (a groom rooted
    inside a neck capsule, say). A root on the surface or within the margin keeps the collider;
    the Simulator warns about every skipped (strand, collider) pair at construction. A pushed
    node's step displacement dx becomes x - x_prev. With springs (the implicit step's length
    correction) nothing moves: each push deeper than SPRING_PUSH of the node's edge becomes a
    spring to its target in the correction's system (contact_spring; place_contact). Once
    friction has settled for the step (settled nonzero) nodes are only pushed out
    (contact_with_friction). Returns the number of pushes."""
    pushes = 0
    x, x_prev, head = ti.static(st.x, st.x_prev, dr.head)  # aliases
    # Node 0 is the root: its distance, taken first in each collider's node loop, decides whether
    # the strand keeps that collider (see root_keeps_collider). One distance query per node and
    # collider, the root's included: a separate root query doubled the contact code that every
    # kernel using it compiles (twice in the implicit step's).
    # The analytic colliders c < n_analytic, then the distance grids (fl.mesh) as c = n_analytic + g,
    # in one loop: the contact and its friction (contact_with_friction, place_contact) are
    # inlined once, not once per kind of collider. Each copy of them was a large share of the
    # implicit step's compile time (its kernel holds this function twice).
    if ti.static(not springs):
        plan_queries(s, md.node_count[s], n_analytic, st)
    n_grids = 0
    if ti.static(fl.mesh):
        n_grids = co.sdf_meta.shape[0] // GRID_META_ROWS
    for c in range(n_analytic + n_grids):
        on_head = 0
        margin = 0.0
        friction = 0.0
        if c < n_analytic:
            on_head = ti.cast(co.params[c][3] > 0.5, ti.i32)
            margin = co.params[c][1]
            friction = co.params[c][2]
        else:  # sdf_meta (colliders.GRID_META_ROWS): (spacing, margin, friction), (on head 1/0, ...)
            row = GRID_META_ROWS * (c - n_analytic)
            on_head = ti.cast(co.sdf_meta[row + 2][0] > 0.5, ti.i32)
            margin = co.sdf_meta[row + 1][1]
            friction = co.sdf_meta[row + 1][2]
        group = SHAPES
        if c == n_analytic:
            group = GRID
        for i in range(md.node_count[s]):
            if not queried(s, i, group, springs, st):
                continue
            local = collider_frame(on_head, head, now, point(x, s, i))
            d = 0.0
            n = vec3(0.0, 0.0, 1.0)
            if c < n_analytic:
                d, n = analytic_distance(co.kinds[c], co.geometry[c, 0], co.geometry[c, 1], co.params[c][0], local)
            else:
                if ti.static(fl.mesh):
                    d, n = grid_distance(co.sdf, co.sdf_meta, c - n_analytic, local)
            note_clearance(s, i, d, margin, group, springs, st)  # a root held inside stays queried
            if i == 0 and d < -margin:
                break
            if md.inv_mass[s, i] > 0.0 and in_contact(s, i, c + 1, d, margin, springs, md, st):
                normal = n
                if on_head:
                    normal = head_rotate(head, now, n)
                local_prev = collider_frame(on_head, head, prev, point(x_prev, s, i))
                surface = ContactSurface(margin=margin, friction=friction, settled=settled)
                place_contact(s, i, contact_with_friction(s, i, on_head, head, now, local, local_prev, d, n,
                                                          surface, c + 1, st), normal, springs, md, st)
                pushes += 1
    if ti.static(fl.touch):
        for k in range(dr.tools.shape[0]):
            if ti.cast(dr.tools[k][0], ti.i32) == HAND:
                # in the hand's frame: its own motion over the step does not count as slip
                centre = dr.tool_points[tool_now, k]
                for i in range(md.node_count[s]):
                    if md.inv_mass[s, i] > 0.0 and queried(s, i, SHAPES, springs, st):
                        local = point(x, s, i) - centre
                        local_prev = point(x_prev, s, i) - dr.tool_points[tool_prev, k]
                        d, n = sphere_distance(local, dr.tools[k][1])
                        note_clearance(s, i, d, dr.tools[k][2], SHAPES, springs, st)
                        if in_contact(s, i, -1 - k, d, dr.tools[k][2], springs, md, st):
                            # in the hand's frame, which does not turn: shift in world axes
                            surface = ContactSurface(margin=dr.tools[k][2], friction=dr.tools[k][3], settled=settled)
                            moved = contact_with_friction(s, i, False, head, now, local, local_prev, d, n,
                                                          surface, -1 - k, st)
                            place_contact(s, i, centre + moved, n, springs, md, st)
                            pushes += 1
    return pushes
