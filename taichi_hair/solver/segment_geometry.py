"""Segment geometry of strand-strand contact (taichi_hair.solver.strand_contact), as Taichi
functions: the closest points of two segments, the contact normal between them, and the curve
through a strand's nodes around a segment's chord (node curvature, the arc's offset from the
chord and a bound on it). Positions x [S, N] vec3 [m], node_count [S]."""

import taichi as ti

from ..rods.arrays import edge, vec3


@ti.func
def segment_closest(a0, a1, b0, b1):
    """(s, t) in [0, 1]^2: parameters of the closest points a0 + s (a1 - a0), b0 + t (b1 - b0)
    between segments a0-a1 and b0-b1 (Ericson, Real-Time Collision Detection 5.1.9). Zero-length
    segments reduce to point-segment or point-point; parallel segments take s = 0 first (any
    point of an overlap is closest). The line-line numerator and denominator are evaluated as
    cross products, (d1 x d2).(d2 x r) and |d1 x d2|^2, the same quantities as Ericson's
    b f - c e and a e - b^2 without their cancellation at small angles."""
    d1 = a1 - a0
    d2 = b1 - b0
    r = a0 - b0
    a = d1.dot(d1)
    e = d2.dot(d2)
    f = d2.dot(r)
    s = 0.0
    t = 0.0
    if a > 0.0 and e > 0.0:
        c = d1.dot(r)
        b = d1.dot(d2)
        normal = d1.cross(d2)
        denom = normal.dot(normal)
        if denom > 0.0:
            s = ti.math.clamp(normal.dot(d2.cross(r)) / denom, 0.0, 1.0)
        t = (b * s + f) / e
        if t < 0.0:
            t = 0.0
            s = ti.math.clamp(-c / a, 0.0, 1.0)
        elif t > 1.0:
            t = 1.0
            s = ti.math.clamp((b - c) / a, 0.0, 1.0)
    elif a > 0.0:  # b is a point
        s = ti.math.clamp(-d1.dot(r) / a, 0.0, 1.0)
    elif e > 0.0:  # a is a point
        t = ti.math.clamp(f / e, 0.0, 1.0)
    return s, t


@ti.func
def perpendicular(v):
    """A unit vector perpendicular to v (the x axis if v is zero): v crossed with the axis it is
    least aligned with."""
    axis = vec3(1.0, 0.0, 0.0)
    if ti.abs(v[1]) <= ti.abs(v[0]) and ti.abs(v[1]) <= ti.abs(v[2]):
        axis = vec3(0.0, 1.0, 0.0)
    elif ti.abs(v[2]) <= ti.abs(v[0]) and ti.abs(v[2]) <= ti.abs(v[1]):
        axis = vec3(0.0, 0.0, 1.0)
    n = v.cross(axis)
    length = n.norm()
    out = vec3(1.0, 0.0, 0.0)
    if length > 0.0:
        out = n / length
    return out


@ti.func
def contact_normal(pa, pb, da, db, d, rsum):
    """Unit normal from segment b to segment a at closest points pa, pb (distance d [m]). When
    the segments (nearly) intersect, (pa - pb) / d has no direction left: take da x db (normal
    to both) or, for parallel segments, any perpendicular of their direction."""
    n = vec3(0.0)
    if d > 1e-12 * rsum:
        n = (pa - pb) / d
    else:
        c = da.cross(db)
        c2 = c.dot(c)
        if c2 > 1e-12 * da.dot(da) * db.dot(db) and c2 > 0.0:
            n = c / ti.sqrt(c2)
        elif da.dot(da) > 0.0:
            n = perpendicular(da)
        else:
            n = perpendicular(db)
    return n


@ti.func
def node_curvature(x: ti.template(), node_count: ti.template(), s, i):
    """Curvature vector [1/m] at node i of strand s, pointing to the centre of curvature:
    (t_i - t_{i-1}) / ((l_{i-1} + l_i) / 2), of magnitude 2 sin(phi / 2) / l at turning angle
    phi, the curvature of the circle through the three nodes when the edges are equal. Zero at
    a strand's end nodes (and next to a zero-length edge)."""
    k = vec3(0.0)
    if i > 0 and i + 1 < node_count[s]:
        e0 = edge(x, s, i - 1, i)
        e1 = edge(x, s, i, i + 1)
        l0 = e0.norm()
        l1 = e1.norm()
        if l0 > 0.0 and l1 > 0.0:
            k = (e1 / l1 - e0 / l0) / (0.5 * (l0 + l1))
    return k


@ti.func
def arc_offset(x: ti.template(), node_count: ti.template(), s, j, u, cap):
    """From the chord of segment j of strand s to the curve through its nodes, at parameter u
    in [0, 1] [m]: -(l^2 / 2) u (1 - u) kappa(u), kappa interpolated linearly between the
    nodes' curvature vectors (node_curvature), shortened to at most `cap` [m] (the strand's
    contact radius). The parabola through both nodes with that curvature: on a circle of
    curvature kappa it is l^2 kappa / 8 at the middle, the arc's sag to second order. Zero on
    a straight strand and at the nodes. Why the cap: a segment whose curve leaves its chord by
    more than a radius turns by over 8 r / l, too coarse a polyline to say where its surface
    is, and an uncapped bulge would grow every cell of the pair search (a single kink in a
    scene would)."""
    l2 = edge(x, s, j, j + 1).norm_sqr()
    k = (1.0 - u) * node_curvature(x, node_count, s, j) + u * node_curvature(x, node_count, s, j + 1)
    offset = -(0.5 * l2 * u * (1.0 - u)) * k
    size = offset.norm()
    if size > cap:
        offset *= cap / size
    return offset


@ti.func
def bulge(x: ti.template(), node_count: ti.template(), s, j, cap):
    """A bound on |arc_offset| over segment j of strand s [m]: l^2 / 8 max(|kappa_j|, |kappa_j+1|),
    at most `cap`."""
    k = ti.max(node_curvature(x, node_count, s, j).norm(), node_curvature(x, node_count, s, j + 1).norm())
    return ti.min(0.125 * edge(x, s, j, j + 1).norm_sqr() * k, cap)
