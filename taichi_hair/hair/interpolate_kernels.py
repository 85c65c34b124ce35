"""The per-frame Taichi kernels of dense hair (taichi_hair.hair.interpolate, whose docstring
lists the stages): the guides' Bishop frames, the dense nodes from the guides (by the modes, or
from rest edges for an imported style) and the push out of an ellipsoid head. They take
ndarrays, so each compiles once per process; the head pose travels as a [4] vec3 ndarray, rows
of R then t. Positions are metres; arrays are [strand, node, xyz]; node 0 is the root.
"""

import taichi as ti

from ..rods.frames import parallel_transport
from ..rods.linalg import rotate_rows, unrotate_rows
from ..solver.segment_geometry import perpendicular
from ..runtime import precision

vec2 = ti.math.vec2
vec3 = ti.math.vec3
ivec5 = ti.types.vector(5, ti.i32)  # integer element types do not depend on the float precision
Vec3s1 = ti.types.ndarray(dtype=vec3, ndim=1)
Vec3s2 = ti.types.ndarray(dtype=vec3, ndim=2)
vec4 = ti.math.vec4
Quats2 = ti.types.ndarray(dtype=vec4, ndim=2)
Scalars2 = ti.types.ndarray(dtype=float, ndim=2)  # `float` resolves when the kernel compiles


@ti.func
def _rotate(head: ti.template(), v):
    """R v for the head pose head[0..2] = rows of R (head[3] = t is not used)."""
    return rotate_rows(head[0], head[1], head[2], v)


@ti.func
def _unrotate(head: ti.template(), v):
    """R^T v for the head pose head[0..2] = rows of R."""
    return unrotate_rows(head[0], head[1], head[2], v)


@ti.kernel
def guide_frames(x: Vec3s2, normal: Vec3s1, u_rest: Vec3s1, head: Vec3s1, t_out: Vec3s2, u_out: Vec3s2):
    """Bishop frame (t^j, u^j) of every guide edge j: u^0 is the rest reference u (carried by the
    head rotation, head [4] = rows of R then t) transported from the root normal to t^0, then
    edge to edge. One thread per guide; the transport is serial along its strand."""
    for g in range(x.shape[0]):
        t_prev, u = _rotate(head, normal[g]), _rotate(head, u_rest[g])
        for j in range(x.shape[1] - 1):
            e = x[g, j + 1] - x[g, j]
            t = t_prev
            if e.norm() > 1e-12:  # a zero-length edge keeps the previous tangent
                t = e.normalized()
            u = parallel_transport(u, t_prev, t)
            u = (u - u.dot(t) * t).normalized()  # round-off drift off the normal plane
            t_out[g, j], u_out[g, j] = t, u
            t_prev = t


@ti.kernel
def director_frames(x: Vec3s2, m1: Vec3s2, t_out: Vec3s2, u_out: Vec3s2):
    """Material frame (t^j, u^j) of every guide edge j: t the unit edge of positions x [m], u the
    director m1 made normal to it (the simulator computes m1 normal to the edges of its own
    positions; the two can part by round-off). One thread per guide, serial along it: a
    zero-length edge keeps the previous tangent, a director along its edge the previous u."""
    for g in range(x.shape[0]):
        t_prev = (x[g, 1] - x[g, 0]).normalized()
        u_prev = vec3(0.0)
        for j in range(x.shape[1] - 1):
            e = x[g, j + 1] - x[g, j]
            t = t_prev
            if e.norm() > 1e-12:
                t = e.normalized()
            u = m1[g, j] - m1[g, j].dot(t) * t
            if u.norm() > 1e-6:
                u = u.normalized()
            elif j > 0:
                u = parallel_transport(u_prev, t_prev, t)
            else:  # no director to go by at the root: any normal
                u = perpendicular(t)
            t_out[g, j], u_out[g, j] = t, u
            t_prev, u_prev = t, u


@ti.func
def _at(x: ti.template(), g, q):
    """Position on guide g at fractional node index q (linear between nodes)."""
    k = ti.min(ti.cast(ti.floor(q), ti.i32), x.shape[1] - 2)
    f = q - k
    return (1.0 - f) * x[g, k] + f * x[g, k + 1]


@ti.func
def _edge(q, n_nodes):
    """Edge whose frame carries node position q: the edge arriving at q (edge 0 at the root)."""
    return ti.math.clamp(ti.cast(ti.ceil(q), ti.i32) - 1, 0, n_nodes - 2)


@ti.func
def _hash01(key, i):
    """Two uniform numbers in [-1, 1) from (strand key, node), fixed across frames."""
    h = ti.cast(key, ti.u32) * ti.u32(0x9E3779B1) + ti.cast(i, ti.u32)
    out = vec2(0.0)
    for k in ti.static(range(2)):
        h = (h ^ (h >> 16)) * ti.u32(0x7FEB352D)
        h = (h ^ (h >> 15)) * ti.u32(0x846CA68B)
        h = h ^ (h >> 16)
        out[k] = ti.cast(ti.cast(h >> 8, ti.i32), float) / 8388608.0 - 1.0
    return out


@ti.kernel
def dense_nodes(x: Vec3s2, t: Vec3s2, u: Vec3s2, idx: ti.types.ndarray(dtype=ivec5, ndim=1),
                 w: Vec3s1, rel: Vec3s2, local: Vec3s1, par: Scalars2, head: Vec3s1, out: Vec3s2):
    """Dense nodes out[d, i] [m]. idx[d] = (3 triangle guides, clump guide, frizz key); w[d] the
    triangle weights; rel[d, k] = rest dense root - rest root of guide k (triangle, then clump);
    local[d] the clump offset in the clump guide's rest root frame (u, v, normal);
    par[d, :] = (blend, start node, node step, frizz amplitude [m], clump offset scale at the
    tip); head [4] the head pose (rows of R, then t).
    One thread per dense strand: the terms shared by its nodes are computed once, then the
    nodes (independent of each other) in a loop."""
    n = x.shape[1]
    for d in range(out.shape[0]):
        blend, q0, step, frizz, tip = par[d, 0], par[d, 1], par[d, 2], par[d, 3], par[d, 4]
        k0, k1, k2, g, key = idx[d][0], idx[d][1], idx[d][2], idx[d][3], idx[d][4]
        wd, off = w[d], local[d]
        # each guide carries the dense root rigidly with the head from its own root
        base_b = (wd[0] * (x[k0, 0] + _rotate(head, rel[d, 0]) - _at(x, k0, q0))
                  + wd[1] * (x[k1, 0] + _rotate(head, rel[d, 1]) - _at(x, k1, q0))
                  + wd[2] * (x[k2, 0] + _rotate(head, rel[d, 2]) - _at(x, k2, q0)))
        j0 = _edge(q0, n)
        # the root offset is subtracted as carried by the start frame, so node 0 is the root
        base_c = (x[g, 0] + _rotate(head, rel[d, 3]) - _at(x, g, q0)
                  - (off[0] * u[g, j0] + off[1] * t[g, j0].cross(u[g, j0]) + off[2] * t[g, j0]))
        for i in range(n):
            q = q0 + i * step
            s = i / (n - 1.0)
            xb = base_b + wd[0] * _at(x, k0, q) + wd[1] * _at(x, k1, q) + wd[2] * _at(x, k2, q)
            j = _edge(q, n)
            uj, tj = u[g, j], t[g, j]
            vj = tj.cross(uj)
            xc = base_c + _at(x, g, q) + (1.0 + (tip - 1.0) * s) * (off[0] * uj + off[1] * vj + off[2] * tj)
            fz = vec3(0.0)
            if frizz > 0.0:
                noise = _hash01(key, i)
                fz = frizz * s * s * (noise[0] * uj + noise[1] * vj)
            out[d, i] = (1.0 - blend) * xb + blend * xc + fz


@ti.func
def _nearest_on_ellipsoid(p, r):
    """Nearest point of the axis-aligned ellipsoid with semi-axes r to p (both in its frame):
    x = p r^2 / (r^2 + s) with s the root of sum (p r / (r^2 + s))^2 = 1, by bisection."""
    rmin = ti.min(r[0], r[1], r[2])
    lo, hi = -rmin * rmin, 0.0
    if ((p / r) ** 2).sum() > 1.0:
        lo, hi = 0.0, ti.max(r[0], r[1], r[2]) * p.norm()
    # each halving gains a bit: 30 take the bracket (at most the head's size squared) below
    # float32's resolution of the root, float64 needs 60
    for _ in range(ti.static(30 if precision() == "float32" else 60)):
        mid = 0.5 * (lo + hi)
        if ((p * r / (r * r + mid)) ** 2).sum() > 1.0:
            lo = mid
        else:
            hi = mid
    y = p * r * r / (r * r + 0.5 * (lo + hi))
    # on the medial axis the root escapes the bracket: scale back onto the surface
    return y / ti.sqrt(((y / r) ** 2).sum())


@ti.kernel
def push_out_of_ellipsoid(out: Vec3s2, head: Vec3s1, shape: Vec3s1):
    """Move non-root nodes closer than the margin to the ellipsoid to its surface point + margin
    along the normal. shape [3] = (rest centre [m], semi-axes [m] along the rest axes, (margin
    [m], 0, 0)); the head pose head [4] (rows of R, then t) carries centre and axes.
    One thread per (strand, node)."""
    radii, margin = shape[1], shape[2][0]
    centre = _rotate(head, shape[0]) + head[3]
    reach = ti.max(radii[0], radii[1], radii[2]) + margin
    # the ellipsoid grown by the margin lies inside the ellipsoid scaled by 1 + margin / (its
    # least semi-axis) (support functions: h(u) + margin <= h(u) (1 + margin / r_min)), so a
    # node outside that one (with room for rounding) needs no nearest-point search
    grown = (1.0 + margin / ti.min(radii[0], radii[1], radii[2])) * radii
    for d, i in ti.ndrange(out.shape[0], out.shape[1]):
        rel = out[d, i] - centre
        if i > 0 and rel.norm() < reach:
            p = _unrotate(head, rel)
            if ((p / grown) ** 2).sum() > 1.0 + 1e-3:
                continue
            if p.norm() < 1e-9 * reach:  # the centre itself: leave along the shortest axis
                rmin = ti.min(radii[0], radii[1], radii[2])
                p = 1e-6 * reach * ti.cast(radii == rmin, float).normalized()
            y = p * radii[0] / p.norm()  # sphere: closed form
            if radii[0] != radii[1] or radii[1] != radii[2]:
                y = _nearest_on_ellipsoid(p, radii)
            inside = ((p / radii) ** 2).sum() < 1.0
            dist = (p - y).norm() * ti.select(inside, -1.0, 1.0)
            if dist < margin:
                out[d, i] = centre + _rotate(head, y + margin * (y / (radii * radii)).normalized())


@ti.kernel
def guide_rotations(t: Vec3s2, u: Vec3s2, t_rest: Vec3s2, u_rest: Vec3s2, q_out: Quats2):
    """Unit quaternion q_out[g, j] = (w, x, y, z) of the rotation taking guide g's rest frame of
    edge j (u, t x u, t at rest: Bishop or material, `guide_frames` or `director_frames`) to
    its frame now (Shepperd's method: the largest of
    w, x, y, z is computed from the diagonal, so no division is by a small number). One thread
    per guide edge."""
    for g, j in t:
        u0, t0, u1, t1 = u_rest[g, j], t_rest[g, j], u[g, j], t[g, j]
        v0, v1 = t0.cross(u0), t1.cross(u1)
        r = u1.outer_product(u0) + v1.outer_product(v0) + t1.outer_product(t0)
        trace = r[0, 0] + r[1, 1] + r[2, 2]
        q = vec4(0.0)
        if trace > 0.0:
            s = 2.0 * ti.sqrt(trace + 1.0)
            q = vec4(0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
        elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
            s = 2.0 * ti.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
            q = vec4((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
        elif r[1, 1] > r[2, 2]:
            s = 2.0 * ti.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
            q = vec4((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
        else:
            s = 2.0 * ti.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
            q = vec4((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
        q_out[g, j] = q.normalized()


@ti.func
def _quat_rotate(rotation, e):
    """e turned by the unit quaternion rotation = (w, x, y, z)."""
    r = vec3(rotation[1], rotation[2], rotation[3])
    c = r.cross(e)
    return e + 2.0 * rotation[0] * c + 2.0 * r.cross(c)


AGREE_FULL = 0.8660254  # |q_a . q_b| = cos(half the angle between two rotations): 60 degrees
AGREE_NONE = 0.7071068  # 90 degrees


@ti.kernel
def dense_from_edges(x: Vec3s2, q: Quats2, idx: ti.types.ndarray(dtype=ivec5, ndim=1), w: Vec3s1,
                      rel: Vec3s2, par: Scalars2, head: Vec3s1, edges: Vec3s2, out: Vec3s2):
    """Dense nodes out[d, i] [m] of strands with rest shapes: the root as in `dense_nodes`, then
    each rest edge edges[d, j] [m] turned by the blend of the rotations q[m, j] of edge j of its
    guides (`guide_rotations`) with weights (1 - blend) w[d] (triangle) and blend (clump
    guide), and laid end to end. The blend is the normalised weighted sum of the quaternions
    on the clump guide's side of the sphere, each guide's weight faded from 1 to 0 as its
    rotation parts from the clump guide's by 60 to 90 degrees: a rotation, so every edge
    keeps its rest length exactly, and the rotation of edge j changes along the strand only as
    the guides' own do (a blend of the turned edges instead shrinks the edges the guides turn
    apart, and rescaling them to length kinks the strand). Exact at rest, rigid under a rigid
    head motion. One thread per dense strand, serial along it."""
    for d in range(out.shape[0]):
        blend, wd = par[d, 0], w[d]
        weight = ti.Vector([(1.0 - blend) * wd[0], (1.0 - blend) * wd[1], (1.0 - blend) * wd[2], blend])
        root = vec3(0.0)
        for k in ti.static(range(4)):
            root += weight[k] * (x[idx[d][k], 0] + _rotate(head, rel[d, k]))
        out[d, 0] = root
        g = idx[d][3]
        for j in range(out.shape[1] - 1):
            ref = q[g, j]
            mean = vec4(0.0)
            for k in ti.static(range(4)):
                qk = q[idx[d][k], j]
                agree = qk.dot(ref)
                # a guide turned far from the clump guide (more than 60 degrees apart, nothing
                # at 90) fades out of the blend: a mean of rotations that far apart is a turn
                # none of them made, and near the crown it stood strands on end
                trust = ti.math.clamp((ti.abs(agree) - AGREE_NONE) / (AGREE_FULL - AGREE_NONE), 0.0, 1.0)
                mean += weight[k] * trust * ti.select(agree < 0.0, -1.0, 1.0) * qk
            # guides turned half a turn apart from each other can cancel: follow the clump guide
            turn = ref
            if mean.norm() > 1e-6:
                turn = mean.normalized()
            out[d, j + 1] = out[d, j] + _quat_rotate(turn, edges[d, j])
