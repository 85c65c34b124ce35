"""Contact stage: push nodes out of colliders and hands, with friction. Runs inside the fast
projection (see step.strand_project), alternating with the inextensibility solve: every pass
pushes nodes out along the normal and adds the push to the node's normal correction of the step
so far (kept in v[s, i].x, scratch until the velocity stage); once the projection has
converged, one friction pass shrinks each touching node's slip since the step began by friction
x that whole correction (Coulomb over the step: docs/model.md, "Collisions")."""

import taichi as ti

from ..rods.arrays import vec3
from ..rods.linalg import rotate_rows, unrotate_rows
from ..world.colliders import analytic_distance, grid_distance, sphere_distance
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
def from_head(head: ti.template(), k, p):
    """R p + t: head-coordinate point p [m] in the world at head pose k."""
    return head_rotate(head, k, p) + head[k, 3]


PUSH, FRICTION = 0, 1  # what a contact pass does (strand_collide's mode)
TOUCHING = 1e-6  # relative to the margin: a node this close to it after the pushes is in contact


@ti.func
def resolve_contact(p, p_prev, d, n, margin, friction, budget, mode: ti.template()):
    """mode PUSH: move p (distance d [m], outward normal n, both in the collider's frame) out to
    the margin; returns (p, the push [m]). mode FRICTION, for a node at the margin: shrink its
    slip along the surface since p_prev by friction x budget (the step's normal correction,
    Coulomb), all of it if shorter; returns (p, 0)."""
    moved = p
    push = 0.0
    if ti.static(mode == PUSH):
        push = margin - d
        moved = p + push * n
    else:
        slip = p - p_prev
        tangential = slip - slip.dot(n) * n
        length = tangential.norm()
        if length > 1e-12:
            moved -= ti.min(1.0, friction * budget / length) * tangential
    return moved, push


@ti.func
def collider_frame(on_head, head: ti.template(), now, prev, p, p_prev):
    """(p, p_prev) in the collider's frame: head coordinates at poses now / prev, or the world."""
    local = p
    local_prev = p_prev
    if on_head:
        local = to_head(head, now, p)
        local_prev = to_head(head, prev, p_prev)
    return local, local_prev


@ti.func
def in_contact(d, margin, mode: ti.template()):
    """PUSH: inside the margin; FRICTION: at it (after the pushes), within TOUCHING."""
    inside = d < margin
    if ti.static(mode == FRICTION):
        inside = d < margin * (1.0 + TOUCHING)
    return inside


def root_keeps_collider(root_distance, margin):
    """The rule strand_collide applies on the device, for host-side checks: a strand collides
    with a collider unless its root lies inside it by more than the collider's margin [m]."""
    return root_distance >= -margin


@ti.func
def strand_collide(s, now, prev, tool_now, tool_prev, n_analytic, fl: ti.template(), md: ti.template(),
                   st: ti.template(), dr: ti.template(), co: ti.template(), mode: ti.template()):
    """Resolve every free node of strand s against the colliders (co: analytic table, optional
    distance grid; fl.mesh), and the hands (fl.touch). Head-attached shapes are handled in head
    coordinates so their friction sees the motion relative to the moving head (head poses now /
    prev); hands sit at tool_points[tool_now] (tool_prev before the step). A collider that holds
    the strand's own root deeper than its margin (signed distance < -margin) is skipped for
    that strand: pushing its nodes out would fight the held root every step (a groom rooted
    inside a neck capsule, say). A root on the surface or within the margin keeps the collider;
    the Simulator warns about every skipped (strand, collider) pair at construction. A pushed
    node's step displacement dx becomes x - x_prev. mode PUSH pushes nodes inside a margin out
    and adds the push to v[s, i].x; mode FRICTION applies friction to the nodes at a margin
    (resolve_contact). Returns the number of nodes acted on."""
    pushes = 0
    x, x_prev, dx, head = ti.static(st.x, st.x_prev, st.dx, dr.head)  # aliases
    root = x[s, 0]
    for c in range(n_analytic):
        on_head = co.params[c][3] > 0.5
        root_local, _ = collider_frame(on_head, head, now, prev, root, root)
        d_root, _ = analytic_distance(co.kinds[c], co.geometry[c, 0], co.geometry[c, 1], co.params[c][0],
                                      root_local)
        if d_root >= -co.params[c][1]:  # see root_keeps_collider
            for i in range(md.node_count[s]):
                if md.inv_mass[s, i] > 0.0:
                    local, local_prev = collider_frame(on_head, head, now, prev, x[s, i], x_prev[s, i])
                    d, n = analytic_distance(co.kinds[c], co.geometry[c, 0], co.geometry[c, 1],
                                             co.params[c][0], local)
                    if in_contact(d, co.params[c][1], mode):
                        local, push = resolve_contact(local, local_prev, d, n, co.params[c][1], co.params[c][2],
                                                      st.v[s, i].x, mode)
                        st.v[s, i] += vec3(push, 0.0, 0.0)
                        x[s, i] = local
                        if on_head:
                            x[s, i] = from_head(head, now, local)
                        dx[s, i] = x[s, i] - x_prev[s, i]  # placed, not moved by: see strand_velocities
                        pushes += 1
    if ti.static(fl.mesh):
        # sdf_meta: origin [m], (spacing [m], margin [m], friction), (on head 1/0, 0, 0)
        on_head = co.sdf_meta[2][0] > 0.5
        root_local, _ = collider_frame(on_head, head, now, prev, root, root)
        d_root, _ = grid_distance(co.sdf, co.sdf_meta[0], co.sdf_meta[1][0], root_local)
        if d_root >= -co.sdf_meta[1][1]:  # see root_keeps_collider
            for i in range(md.node_count[s]):
                if md.inv_mass[s, i] > 0.0:
                    local, local_prev = collider_frame(on_head, head, now, prev, x[s, i], x_prev[s, i])
                    d, n = grid_distance(co.sdf, co.sdf_meta[0], co.sdf_meta[1][0], local)
                    if in_contact(d, co.sdf_meta[1][1], mode):
                        local, push = resolve_contact(local, local_prev, d, n, co.sdf_meta[1][1], co.sdf_meta[1][2],
                                                      st.v[s, i].x, mode)
                        st.v[s, i] += vec3(push, 0.0, 0.0)
                        x[s, i] = local
                        if on_head:
                            x[s, i] = from_head(head, now, local)
                        dx[s, i] = x[s, i] - x_prev[s, i]
                        pushes += 1
    if ti.static(fl.touch):
        for k in range(dr.tools.shape[0]):
            if ti.cast(dr.tools[k][0], ti.i32) == HAND:
                # in the hand's frame: its own motion over the step does not count as slip
                centre = dr.tool_points[tool_now, k]
                for i in range(md.node_count[s]):
                    if md.inv_mass[s, i] > 0.0:
                        local = x[s, i] - centre
                        local_prev = x_prev[s, i] - dr.tool_points[tool_prev, k]
                        d, n = sphere_distance(local, dr.tools[k][1])
                        if in_contact(d, dr.tools[k][2], mode):
                            moved, push = resolve_contact(local, local_prev, d, n, dr.tools[k][2], dr.tools[k][3],
                                                          st.v[s, i].x, mode)
                            st.v[s, i] += vec3(push, 0.0, 0.0)
                            x[s, i] = centre + moved
                            dx[s, i] = x[s, i] - x_prev[s, i]
                            pushes += 1
    return pushes
