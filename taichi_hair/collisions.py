"""Contact stage: push nodes out of colliders and hands, with friction. Runs inside the fast
projection (see step.strand_project), alternating with the inextensibility solve."""

import taichi as ti

from .arrays import vec3
from .colliders import analytic_distance, grid_distance, sphere_distance
from .forces import HAND


@ti.func
def to_head(head: ti.template(), k, p):
    """R^T (p - t): world point p [m] in head coordinates at head pose k."""
    q = p - head[k, 3]
    return q[0] * head[k, 0] + q[1] * head[k, 1] + q[2] * head[k, 2]


@ti.func
def from_head(head: ti.template(), k, p):
    """R p + t: head-coordinate point p [m] in the world at head pose k."""
    return vec3(head[k, 0].dot(p), head[k, 1].dot(p), head[k, 2].dot(p)) + head[k, 3]


@ti.func
def resolve_contact(p, p_prev, d, n, margin, friction):
    """Move p (distance d [m], outward normal n, both in the collider's frame) out to the margin
    and shrink its slip along the surface since p_prev by friction x push depth (Coulomb)."""
    push = margin - d
    moved = p + push * n
    slip = moved - p_prev
    tangential = slip - slip.dot(n) * n
    length = tangential.norm()
    if length > 1e-12:
        moved -= ti.min(1.0, friction * push / length) * tangential
    return moved


@ti.func
def collider_frame(on_head, head: ti.template(), now, prev, p, p_prev):
    """(p, p_prev) in the collider's frame: head coordinates at poses now / prev, or the world."""
    local = p
    local_prev = p_prev
    if on_head:
        local = to_head(head, now, p)
        local_prev = to_head(head, prev, p_prev)
    return local, local_prev


def root_keeps_collider(root_distance, margin):
    """The rule strand_collide applies on the device, for host-side checks: a strand collides
    with a collider unless its root lies inside it by more than the collider's margin [m]."""
    return root_distance >= -margin


@ti.func
def strand_collide(s, node_count: ti.template(), inv_mass: ti.template(), x: ti.template(),
                   x_prev: ti.template(), dx: ti.template(), head: ti.template(), now, prev,
                   n_analytic, kinds: ti.template(), geometry: ti.template(), params: ti.template(),
                   use_mesh: ti.template(), sdf: ti.template(), sdf_meta: ti.template(),
                   use_touch: ti.template(), tools: ti.template(), tool_points: ti.template(),
                   tool_now, tool_prev):
    """Resolve every free node of strand s against the colliders (analytic table, optional
    distance grid, optional hands). Head-attached shapes are handled in head coordinates so
    their friction sees the motion relative to the moving head (head poses now / prev); hands
    sit at tool_points[tool_now] (tool_prev before the step). A collider that holds the strand's
    own root deeper than its margin (signed distance < -margin) is skipped for that strand:
    pushing its nodes out would fight the held root every step (a groom rooted inside a neck
    capsule, say). A root on the surface or within the margin keeps the collider; the Simulator
    warns about every skipped (strand, collider) pair at construction. A pushed node's step
    displacement dx becomes x - x_prev. Returns the number of pushes."""
    pushes = 0
    root = x[s, 0]
    for c in range(n_analytic):
        on_head = params[c][3] > 0.5
        root_local, _ = collider_frame(on_head, head, now, prev, root, root)
        d_root, _ = analytic_distance(kinds[c], geometry[c, 0], geometry[c, 1], params[c][0], root_local)
        if d_root >= -params[c][1]:  # see root_keeps_collider
            for i in range(node_count[s]):
                if inv_mass[s, i] > 0.0:
                    local, local_prev = collider_frame(on_head, head, now, prev, x[s, i], x_prev[s, i])
                    d, n = analytic_distance(kinds[c], geometry[c, 0], geometry[c, 1], params[c][0], local)
                    if d < params[c][1]:
                        local = resolve_contact(local, local_prev, d, n, params[c][1], params[c][2])
                        x[s, i] = local
                        if on_head:
                            x[s, i] = from_head(head, now, local)
                        dx[s, i] = x[s, i] - x_prev[s, i]  # placed, not moved by: see strand_velocities
                        pushes += 1
    if ti.static(use_mesh):
        # sdf_meta: origin [m], (spacing [m], margin [m], friction), (on head 1/0, 0, 0)
        on_head = sdf_meta[2][0] > 0.5
        root_local, _ = collider_frame(on_head, head, now, prev, root, root)
        d_root, _ = grid_distance(sdf, sdf_meta[0], sdf_meta[1][0], root_local)
        if d_root >= -sdf_meta[1][1]:  # see root_keeps_collider
            for i in range(node_count[s]):
                if inv_mass[s, i] > 0.0:
                    local, local_prev = collider_frame(on_head, head, now, prev, x[s, i], x_prev[s, i])
                    d, n = grid_distance(sdf, sdf_meta[0], sdf_meta[1][0], local)
                    if d < sdf_meta[1][1]:
                        local = resolve_contact(local, local_prev, d, n, sdf_meta[1][1], sdf_meta[1][2])
                        x[s, i] = local
                        if on_head:
                            x[s, i] = from_head(head, now, local)
                        dx[s, i] = x[s, i] - x_prev[s, i]  # placed, not moved by: see strand_velocities
                        pushes += 1
    if ti.static(use_touch):
        for k in range(tools.shape[0]):
            if ti.cast(tools[k][0], ti.i32) == HAND:
                # in the hand's frame: its own motion over the step does not count as slip
                centre = tool_points[tool_now, k]
                for i in range(node_count[s]):
                    if inv_mass[s, i] > 0.0:
                        local = x[s, i] - centre
                        local_prev = x_prev[s, i] - tool_points[tool_prev, k]
                        d, n = sphere_distance(local, tools[k][1])
                        if d < tools[k][2]:
                            x[s, i] = centre + resolve_contact(local, local_prev, d, n, tools[k][2],
                                                               tools[k][3])
                            dx[s, i] = x[s, i] - x_prev[s, i]  # placed, not moved by: see strand_velocities
                        pushes += 1
    return pushes
