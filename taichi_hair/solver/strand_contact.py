"""Strand-strand contact (rod-rod), position based, with Coulomb friction.

Every segment (the tube of its strand's contact radius around the curve through nodes j and
j + 1: the chord bent by the nodes' curvature, `arc_offset`) is kept at
least r_a + r_b away from every other segment it may touch: segments of other strands, and with
`self_contact` segments of its own strand further apart along it than the neighbour gap. One
`ContactGrid.resolve` call is one Jacobi pass: it finds all overlapping segment pairs on a
spatial hash grid (O(segments) on average) and moves their nodes apart, the PBD edge-edge
response (its push shared between a segment's nodes by `push_shares`), with position-based
Coulomb friction on the step's relative slip. The step loop alternates it with the length
projection (see step.strand_project), which is what turns the per-pair linearised pushes into
a consistent configuration.

Shapes: S strands, N = max nodes per strand (arrays padded), G = S (N - 1) segment slots; the
segment slot of (strand s, segment j) is g = s (N - 1) + j, joining nodes j and j + 1. SI units
throughout (positions and radii in metres).

Stages, one function each: `_count` (clear, cell size, bin segments, count per hash bucket),
`_prefix` (serial exclusive scan), `_fill` (counting sort), `_pair_pass` (pair search and the
response, or measuring/recording only), `_apply` (averaged corrections into x and dx). One kernel,
`_contact_pass`, runs them in order as its top-level loops: a pass is one launch, since launch
overhead, not the work, dominates scenes of a few strands. It takes ndarrays, so it compiles once
per process (per mode) and serves every simulator.
"""

import math

import numpy as np
import taichi as ti

from ..rods import arrays
from ..rods.arrays import Ints1, Ints2, Points2, Scalars1, Scalars2, Vec3s2, edge, point, vec3

ivec3 = ti.types.vector(3, ti.i32)
IVec3s1 = ti.types.ndarray(dtype=ivec3, ndim=1)  # [G] cell coordinates
# a grid's arrays as one kernel argument (the fused contact step's: Taichi caps a kernel's arguments
# at 64 elements on x64, counting each argpack and each of its members, so this one has room for
# 12 and no scalars:
# params[STEP_VALUES:] carries them; member names must differ from every other bundle's, which
# Taichi 1.7 confuses: co.params, st.counters)
ContactGridArgs = ti.types.argpack(
    radius=Scalars1, gap=Ints1, seg_cell=IVec3s1, seg_bucket=Ints1, bucket_count=Ints1,
    bucket_start=Ints1, cursor=Ints1, sorted_seg=Ints1, grid_params=Scalars1, grid_counters=Ints1,
    delta=Vec3s2, hits=Ints2)

# what a pair pass does with the pairs it finds
MEASURE, RESOLVE, RECORD = 0, 1, 2
# slots of the float parameter array
# (PAIR_COUNT repeats counters[PAIRS] as a float, so a pass reads back one small array; DONE,
# and DEPTH_MAX belong to the fused step, step.advance_with_strand_contact)
# (MAX_BULGE: the largest distance from a segment's chord to its curve, arc_offset's bound)
MAX_LENGTH, MAX_RADIUS, CELL, MAX_PENETRATION, PAIR_COUNT, DONE, DEPTH_MAX, MAX_BULGE = range(8)
STEP_VALUES = 8  # params[8:]: the fused contact step's values by name (step/contact.py SLOT)
CONTACT_GRID_VALUES = 17  # how many: the launch's 11 scalars and the contact step's 6
# slots of the integer counter array
PAIRS, CANDIDATES, RECORDED = 0, 1, 2


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


@ti.func
def cell_hash(c, mask):
    """Bucket in [0, mask] of integer cell c (mask = table size - 1, a power of two minus one):
    the usual three-prime hash, then murmur3's finaliser so the low bits the mask keeps are
    mixed. Collisions cost time only: the pair search checks every candidate's exact cell."""
    h = ((ti.cast(c[0], ti.u32) * ti.u32(73856093)) ^ (ti.cast(c[1], ti.u32) * ti.u32(19349663))
         ^ (ti.cast(c[2], ti.u32) * ti.u32(83492791)))
    h ^= ti.bit_shr(h, 16)
    h *= ti.u32(0x85EBCA6B)
    h ^= ti.bit_shr(h, 13)
    return ti.cast(h & ti.cast(mask, ti.u32), ti.i32)


@ti.func
def _count(node_count: ti.template(), x: ti.template(), params: ti.template(), seg_cell: ti.template(),
           seg_bucket: ti.template(), bucket_count: ti.template(), mask):
    """Bin every segment by its midpoint into a cubic cell of side L + 2 (R_max + B_max) (L the
    longest current segment, R_max the largest radius, B_max <= R_max the largest bulge of a
    segment's curve from its chord, `bulge`; params[CELL] [m]) and count segments per hash bucket. Two
    segments whose curves are within r_a + r_b of each other have midpoints less than
    l_a / 2 + l_b / 2 + r_a + r_b + b_a + b_b <= cell apart, so in the same or adjacent cells: the pair search
    visits the 27 cells around a segment's own. The current (not rest) lengths keep that true for
    stretched segments. Padding slots get bucket -1."""
    n_seg = x.shape[1] - 1
    params[MAX_LENGTH] = 0.0
    params[MAX_BULGE] = 0.0
    for h in range(bucket_count.shape[0]):
        bucket_count[h] = 0
    for s, j in ti.ndrange(x.shape[0], n_seg):
        if j + 1 < node_count[s]:
            ti.atomic_max(params[MAX_LENGTH], edge(x, s, j, j + 1).norm())
            ti.atomic_max(params[MAX_BULGE], bulge(x, node_count, s, j, params[MAX_RADIUS]))
    # two segments whose curves touch have midpoints at most a cell apart
    params[CELL] = params[MAX_LENGTH] + 2.0 * (params[MAX_RADIUS] + params[MAX_BULGE])
    for s, j in ti.ndrange(x.shape[0], n_seg):
        g = s * n_seg + j
        seg_bucket[g] = -1
        if j + 1 < node_count[s]:
            c = ti.cast(ti.floor(0.5 * (point(x, s, j) + point(x, s, j + 1)) / params[CELL]), ti.i32)
            h = cell_hash(c, mask)
            seg_cell[g] = c
            seg_bucket[g] = h
            ti.atomic_add(bucket_count[h], 1)


@ti.func
def _prefix(bucket_count: ti.template(), bucket_start: ti.template(), cursor: ti.template()):
    """bucket_start[h] = segments in buckets before h (exclusive scan, [T + 1]); cursor = a copy
    for _fill. Serial: T is a few times the segment count and the loop is trivial."""
    bucket_start[0] = 0
    ti.loop_config(serialize=True)
    for h in range(bucket_count.shape[0]):
        bucket_start[h + 1] = bucket_start[h] + bucket_count[h]
    for h in range(bucket_count.shape[0]):
        cursor[h] = bucket_start[h]


@ti.func
def _fill(seg_bucket: ti.template(), cursor: ti.template(), sorted_seg: ti.template()):
    """Counting sort: sorted_seg[bucket_start[h] ...] lists the segments of bucket h (in no
    particular order)."""
    for g in range(seg_bucket.shape[0]):
        h = seg_bucket[g]
        if h >= 0:
            sorted_seg[ti.atomic_add(cursor[h], 1)] = g


@ti.func
def push_shares(s):
    """(p0, p1): how a push at parameter s in [0, 1] of a segment is shared by its two nodes:
    p1 = s + sin(2 pi s) / (2 pi), flat around the middle (p1' = 0 at s = 1/2) and all of it on
    a node a contact sits at (p1(0) = 0, p1(1) = 1), increasing, continuous. Why not the
    closest-point weights (1 - s, s), the usual PBD choice: with them a push off the middle of a
    straight segment tilts it, towards the side the contact already sits on, so a segment
    resting on a point is a seesaw the polyline invents. Two ropes crossing at the middles of
    their segments (cosseratbench's crossing) slid off that balance with the asymmetry growing
    e-fold every 0.16 s, from rounding to 8 mm, which was most of their 4.3e-3 shape error;
    shares flat at the middle hold it (asymmetry at rounding after 8 s, shape error 8.4e-4).
    Lumped shares (1/2, 1/2) hold it too, but push a node the contact is not near: a rope
    piling on itself then heaped to 0.5 diameters instead of 1.5 (docs/model.md, "Strand
    contact")."""
    p1 = s + ti.sin(2.0 * math.pi * s) / (2.0 * math.pi)
    return 1.0 - p1, p1


@ti.func
def _push(s, i, w, inv_mass: ti.template(), correction, delta: ti.template(), hits: ti.template()):
    """Add node (s, i)'s share w M_i^-1 correction of one pair, and count it, if it moves."""
    share = w * inv_mass[s, i]
    if share > 0.0:
        delta[s, i] += share * correction
        hits[s, i] += 1


@ti.func
def _pair_pass(mode: ti.template(), with_friction: ti.template(), cg: ti.template(), node_count: ti.template(),
               x: ti.template(), x_prev: ti.template(), inv_mass: ti.template(), self_contact, mask, friction,
               record: ti.template()):
    """Every segment a examines the segments b > a in the 27 cells around its own; a pair of
    non-excluded segments closer than r_a + r_b with at least one free node is a contact.
    counters = (contacts, candidates examined, contacts recorded); params[MAX_PENETRATION] = the
    largest r_a + r_b - d [m] among contacts.

    mode RESOLVE: each contact adds its nodes' corrections to delta and counts them in hits
    (cleared first): with closest-point weights w = (1 - s, s) on a and (1 - t, t) on b, push
    shares p = push_shares(s) on a and push_shares(t) on b, and W = sum p_k w_k M_k^-1, node k
    moves by +-p_k M_k^-1 (lambda n + f / W), lambda = depth / W, which moves the contact points
    apart by exactly depth along n (the linearised constraint) and changes their relative
    displacement by f; f is the friction correction (with_friction), minus the tangential slip
    since x_prev if shorter than friction x depth (static), else minus friction x depth along it
    (kinetic). The corrections sum to zero momentum (the shares on a and on b each sum to 1).
    MEASURE: counters and penetration only. RECORD: also write
    (g_a, g_b) of the first record.shape[0] contacts to record. cg: the grid's arrays
    (a ContactGridArgs)."""
    radius, gap, seg_cell, seg_bucket = ti.static(cg.radius, cg.gap, cg.seg_cell, cg.seg_bucket)
    bucket_start, sorted_seg, params, counters = ti.static(cg.bucket_start, cg.sorted_seg, cg.grid_params,
                                                           cg.grid_counters)
    delta, hits = ti.static(cg.delta, cg.hits)
    n_seg = x.shape[1] - 1
    counters[PAIRS] = 0
    counters[CANDIDATES] = 0
    counters[RECORDED] = 0
    params[MAX_PENETRATION] = 0.0
    if ti.static(mode == RESOLVE):
        for s, i in ti.ndrange(x.shape[0], x.shape[1]):
            delta[s, i] = vec3(0.0)
            hits[s, i] = 0
    for sa, ja in ti.ndrange(x.shape[0], n_seg):
        ga = sa * n_seg + ja
        if seg_bucket[ga] >= 0:
            a0 = point(x, sa, ja)
            a1 = point(x, sa, ja + 1)
            ra = radius[sa]
            length_a = (a1 - a0).norm()
            bulge_a = bulge(x, node_count, sa, ja, ra)
            mid_a = 0.5 * (a0 + a1)
            home = seg_cell[ga]
            examined = 0
            found = 0
            deepest = 0.0
            for o in range(27):  # a runtime loop: unrolling 27 copies of the body bloats compile
                c = home + ivec3(o % 3 - 1, (o // 3) % 3 - 1, o // 9 - 1)
                h = cell_hash(c, mask)
                for k in range(bucket_start[h], bucket_start[h + 1]):
                    gb = sorted_seg[k]
                    examined += 1
                    # each pair once (from its lower slot), each b once (only from its own cell,
                    # not from other cells hashed into the same bucket)
                    cb = seg_cell[gb]
                    if gb > ga and cb[0] == c[0] and cb[1] == c[1] and cb[2] == c[2]:
                        sb = gb // n_seg
                        jb = gb - sb * n_seg
                        allowed = 1
                        if sb == sa:
                            allowed = 0
                            if self_contact != 0 and jb - ja >= gap[sa]:  # jb > ja here
                                allowed = 1
                        b0 = point(x, sb, jb)
                        b1 = point(x, sb, jb + 1)
                        rsum = ra + radius[sb]
                        a0p = point(x_prev, sa, ja)
                        a1p = point(x_prev, sa, ja + 1)
                        b0p = point(x_prev, sb, jb)
                        b1p = point(x_prev, sb, jb + 1)
                        # how far the pair moved this step: a pair that passed through each
                        # other within it may now be up to that far apart
                        motion = (ti.max((a0 - a0p).norm(), (a1 - a1p).norm())
                                  + ti.max((b0 - b0p).norm(), (b1 - b1p).norm()))
                        # bounding spheres about the midpoints: a cheap exact reject before the
                        # closest points (most candidates in the 27 cells are not near), grown
                        # by how far the curves through the nodes bulge from the chords
                        reach = (0.5 * (length_a + (b1 - b0).norm()) + rsum + motion + bulge_a
                                 + params[MAX_BULGE])
                        gap_mid = mid_a - 0.5 * (b0 + b1)
                        if allowed and gap_mid.dot(gap_mid) < reach * reach:
                            s, t = segment_closest(a0, a1, b0, b1)
                            # the contact points on the curves the nodes sample, not on their
                            # chords: a chord cuts a bent strand's corner by l^2 kappa / 8
                            rb = radius[sb]
                            pa = a0 + s * (a1 - a0) + arc_offset(x, node_count, sa, ja, s, ra)
                            pb = b0 + t * (b1 - b0) + arc_offset(x, node_count, sb, jb, t, rb)
                            d = (pa - pb).norm()
                            # the side b was on at the step's start, at the same material points:
                            # a pair that crossed within the step is pushed back to it, not on
                            # through (discrete contact would let fast strands tunnel)
                            before = ((a0p + s * (a1p - a0p) + arc_offset(x_prev, node_count, sa, ja, s, ra))
                                      - (b0p + t * (b1p - b0p) + arc_offset(x_prev, node_count, sb, jb, t, rb)))
                            crossed = 0
                            if (pa - pb).dot(before) < 0.0 and before.dot(before) > 0.0:
                                crossed = 1
                                d = -(pa - pb).dot(before.normalized())  # > 0: how far through
                            w_a0 = 1.0 - s
                            w_b0 = 1.0 - t
                            p_a0, p_a1 = push_shares(s)
                            p_b0, p_b1 = push_shares(t)
                            W = (p_a0 * w_a0 * inv_mass[sa, ja] + p_a1 * s * inv_mass[sa, ja + 1]
                                 + p_b0 * w_b0 * inv_mass[sb, jb] + p_b1 * t * inv_mass[sb, jb + 1])
                            # W == 0: no free node takes a share (all four held, e.g. two
                            # clipped root segments side by side, or the closest point exactly
                            # on a held node of a segment touching a held one): nothing can
                            # move, so not a contact this pass can act on
                            if (crossed == 1 or d < rsum) and W > 0.0:
                                depth = rsum - d
                                if crossed == 1:
                                    depth = rsum + d
                                found += 1
                                deepest = ti.max(deepest, depth)
                                if ti.static(mode == RESOLVE):
                                    n = contact_normal(pa, pb, a1 - a0, b1 - b0, d, rsum)
                                    if crossed == 1:
                                        n = before.normalized()
                                    correction = (depth / W) * n
                                    if ti.static(with_friction):
                                        slip = ((w_a0 * (a0 - a0p) + s * (a1 - a1p))
                                                - (w_b0 * (b0 - b0p) + t * (b1 - b1p)))
                                        tangential = slip - slip.dot(n) * n
                                        length = tangential.norm()
                                        limit = friction * depth
                                        if length <= limit:
                                            correction -= tangential / W
                                        else:  # length > limit >= 0, so no division by zero
                                            correction -= (limit / length / W) * tangential
                                    _push(sa, ja, p_a0, inv_mass, correction, delta, hits)
                                    _push(sa, ja + 1, p_a1, inv_mass, correction, delta, hits)
                                    _push(sb, jb, p_b0, inv_mass, -correction, delta, hits)
                                    _push(sb, jb + 1, p_b1, inv_mass, -correction, delta, hits)
                                if ti.static(mode == RECORD):
                                    slot = ti.atomic_add(counters[RECORDED], 1)
                                    if slot < record.shape[0]:
                                        record[slot, 0] = ga
                                        record[slot, 1] = gb
            # one atomic per segment, not per candidate
            ti.atomic_add(counters[CANDIDATES], examined)
            ti.atomic_add(counters[PAIRS], found)
            ti.atomic_max(params[MAX_PENETRATION], deepest)


@ti.func
def _apply(node_count: ti.template(), inv_mass: ti.template(), delta: ti.template(), hits: ti.template(),
           x: ti.template(), dx: ti.template()):
    """x += delta / hits, dx += the same, on free nodes with contacts: the Jacobi average of the
    corrections a node received (their sum would overshoot where several pairs push a node)."""
    for s, i in ti.ndrange(x.shape[0], x.shape[1]):
        if i < node_count[s] and hits[s, i] > 0 and inv_mass[s, i] > 0.0:
            move = delta[s, i] / hits[s, i]
            x[s, i] += move
            dx[s, i] += move


@ti.kernel
def _contact_pass(mode: ti.template(), with_friction: ti.template(), cg: ContactGridArgs, node_count: Ints1,
                  x: Points2, x_prev: Points2, inv_mass: Scalars2, dx: Vec3s2, self_contact: ti.i32, mask: ti.i32,
                  friction: float, record: Ints2):
    """One contact pass in one launch (launch overhead, not the work, dominates small scenes):
    the stages _count, _prefix, _fill, _pair_pass and, resolving, _apply, each a top-level
    loop (Taichi runs a kernel's top-level loops one after another)."""
    contact_pass(mode, with_friction, cg, node_count, x, x_prev, inv_mass, dx, self_contact, mask, friction, record)


@ti.func
def contact_pass(mode: ti.template(), with_friction: ti.template(), cg: ti.template(), node_count: ti.template(),
                 x: ti.template(), x_prev: ti.template(), inv_mass: ti.template(), dx: ti.template(), self_contact,
                 mask, friction, record: ti.template()):
    """The stages of one pass as top-level loops of the calling kernel (or, in a serial kernel,
    loops in turn: step.advance_small_with_strand_contact); cg: the grid's arrays (ContactGridArgs),
    node_count, x, x_prev, inv_mass, dx: the rods'; record: RECORD mode's [P, 2] pairs (any int
    array otherwise: resolving, the fused step passes cg.hits)."""
    _count(node_count, x, cg.grid_params, cg.seg_cell, cg.seg_bucket, cg.bucket_count, mask)
    _prefix(cg.bucket_count, cg.bucket_start, cg.cursor)
    _fill(cg.seg_bucket, cg.cursor, cg.sorted_seg)
    _pair_pass(mode, with_friction, cg, node_count, x, x_prev, inv_mass, self_contact, mask, friction, record)
    if ti.static(mode == RESOLVE):
        _apply(node_count, inv_mass, cg.delta, cg.hits, x, dx)
    cg.grid_params[PAIR_COUNT] = ti.cast(cg.grid_counters[PAIRS], float)


def neighbour_gap(radius, mean_length):
    """Segments i, j of one strand are never in contact if |i - j| < gap [S], gap = 1 +
    ceil(0.8 pi r / l) (r the strand's contact radius [m], l its mean rest segment length [m]):
    segments closer along the strand than about the arc of a U-turn of bend radius r (pi r, its
    legs 2 r apart) come within 2 r of each other by bending alone, which contact must not fight
    (it would stiffen every bend). At least 2, so segments sharing a node never count; 2 for a
    strand without length."""
    radius = np.asarray(radius, dtype=np.float64)
    mean_length = np.asarray(mean_length, dtype=np.float64)
    gap = np.full(radius.shape, 2, dtype=np.int64)
    ok = mean_length > 0
    gap[ok] = 1 + np.ceil(0.8 * np.pi * radius[ok] / mean_length[ok])
    return np.maximum(gap, 2).astype(np.int32)


class ContactGrid:
    """Strand-strand contact of one simulator: the spatial hash grid and scratch arrays, sized
    once for the scene (S strands of at most `max_nodes` nodes).

    node_counts [S] int: nodes of each strand (arrays [S, max_nodes] are padded beyond).
    radius [S] float (or a scalar) [m]: each strand's contact radius; two segments touch at
    distance r_a + r_b.
    friction: Coulomb coefficient (>= 0; 0 compiles the friction code out).
    self_contact: whether a strand's segments collide with its own (beyond the neighbour gap).
    max_nodes: N, the padded node count of the state arrays.
    rest_length [S, N - 1] (numpy, or a Taichi ndarray) [m], optional: the rest segment lengths,
    whose per-strand mean sets the neighbour gap (see `neighbour_gap`). Without it the gap is set
    from the mean segment lengths of the first positions passed to any method.

    Attributes after each call: last_pairs (contacts found), last_candidates (segment pairs
    examined: the grid's cost), last_max_penetration [m] (largest r_a + r_b - d found, before
    correction), cell_size [m]; neighbour_gap [S] once set.
    """

    def __init__(self, node_counts, radius, friction, self_contact, max_nodes, rest_length=None):
        node_counts = np.asarray(node_counts, dtype=np.int32).reshape(-1)
        self.S = len(node_counts)
        self.N = int(max_nodes)
        if self.S == 0 or self.N < 1:
            raise ValueError(f"ContactGrid needs strands and max_nodes >= 1, got {self.S} strands, "
                             f"max_nodes {max_nodes!r}")
        if node_counts.min() < 0 or node_counts.max() > self.N:
            raise ValueError(f"node_counts must be in [0, max_nodes={self.N}]")
        radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (self.S,)).copy()
        if not np.all(np.isfinite(radius)) or np.any(radius <= 0):
            raise ValueError("contact radii must be finite and > 0 m")
        if not (np.isfinite(friction) and friction >= 0):
            raise ValueError(f"friction must be >= 0, got {friction!r}")
        self.node_counts = node_counts
        self.radius_values = radius
        self.friction = float(friction)
        self.self_contact = bool(self_contact)
        n_seg = max(self.N - 1, 1)  # a slot even for point strands: Taichi arrays need a size
        self.G = self.S * n_seg
        # 2-4x the segments, a power of two so the bucket is a mask of the hash
        self.T = 1 << max(6, int(math.ceil(math.log2(2 * self.G))))

        self.node_count = arrays.ints((self.S,), node_counts)
        self.radius = arrays.scalars((self.S,), radius)
        self.gap = arrays.ints((self.S,), 2)
        self.params = arrays.scalars((STEP_VALUES + CONTACT_GRID_VALUES,))
        self.params.from_numpy(np.array([0.0, radius.max()] + [0.0] * (STEP_VALUES + CONTACT_GRID_VALUES - 2),
                                        dtype=arrays.np_float()))
        self.counters = arrays.ints((3,), 0)
        self.seg_cell = ti.Vector.ndarray(3, ti.i32, (self.G,))
        self.seg_bucket = arrays.ints((self.G,), -1)
        self.sorted_seg = arrays.ints((self.G,), 0)
        self.bucket_count = arrays.ints((self.T,), 0)
        self.bucket_start = arrays.ints((self.T + 1,), 0)
        self.cursor = arrays.ints((self.T,), 0)
        self.delta = arrays.vectors(3, (self.S, self.N))
        self.hits = arrays.ints((self.S, self.N), 0)
        self.record = arrays.ints((1, 2), 0)  # grown by contact_pairs when needed
        self._ones = None  # inv_mass of 1 everywhere, for calls without masses
        self._args = None

        self.neighbour_gap = None
        if rest_length is not None:
            rest = rest_length.to_numpy() if hasattr(rest_length, "to_numpy") else np.asarray(rest_length)
            self._set_gap(np.asarray(rest, dtype=np.float64).reshape(self.S, -1))

        self.last_pairs = 0
        self.last_max_penetration = 0.0
        self.cell_size = 0.0

    def _set_gap(self, lengths):
        """Neighbour gap from per-segment lengths [S, >= N - 1] (padding ignored)."""
        mean = np.zeros(self.S)
        for s, n in enumerate(self.node_counts):
            if n >= 2:
                mean[s] = lengths[s, :n - 1].mean()
        self.neighbour_gap = neighbour_gap(self.radius_values, mean)
        self.gap.from_numpy(self.neighbour_gap)

    def _check(self, x, *others):
        """Shapes [S, N]; the neighbour gap from positions x if no rest lengths were given."""
        for a in (x,) + others:
            if tuple(a.shape) != (self.S, self.N):
                raise ValueError(f"ContactGrid expects arrays of shape ({self.S}, {self.N}), got {tuple(a.shape)}")
        if self.neighbour_gap is None:
            self._set_gap(np.linalg.norm(np.diff(x.to_numpy(), axis=1), axis=2))

    def _masses(self, x, inv_mass):
        if inv_mass is not None:
            self._check(x, inv_mass)
            return inv_mass
        if self._ones is None:
            self._ones = arrays.scalars((self.S, self.N), 1.0)
        return self._ones

    def _pass(self, mode, with_friction, x, x_prev, inv_mass, dx=None):
        """One pass (grid rebuilt from x); resolving, the corrections go into x and dx (measuring,
        dx is unused: a scratch array of the process's float, as positions are float64)."""
        if dx is None:
            if getattr(self, "_unused_dx", None) is None:
                self._unused_dx = arrays.vectors(3, (self.S, self.N))
            dx = self._unused_dx
        _contact_pass(mode, with_friction, self.args(), self.node_count, x, x_prev, inv_mass, dx,
                      int(self.self_contact), self.T - 1, self.friction, self.record)
        params = self.params.to_numpy()
        self.last_pairs = int(round(float(params[PAIR_COUNT])))
        self.last_max_penetration = float(params[MAX_PENETRATION])
        self.cell_size = float(params[CELL])

    def args(self):
        """The grid's arrays as a ContactGridArgs bundle (built once)."""
        if getattr(self, "_args", None) is None:
            self._args = ContactGridArgs(
                radius=self.radius, gap=self.gap, seg_cell=self.seg_cell, seg_bucket=self.seg_bucket,
                bucket_count=self.bucket_count, bucket_start=self.bucket_start, cursor=self.cursor,
                sorted_seg=self.sorted_seg, grid_params=self.params, grid_counters=self.counters, delta=self.delta,
                hits=self.hits)
        return self._args

    def allowed_depth(self, tolerance: float) -> float:
        """The overlap [m] a step may leave: tolerance (relative) of the smallest radius sum."""
        return tolerance * 2.0 * float(self.radius_values.min())

    def deepest_since_reset(self, reset: bool = False) -> float:
        """The largest depth [m] the last contact pass of a fused step found, over the steps since
        the last reset (step.advance_with_strand_contact)."""
        params = self.params.to_numpy()
        if reset:
            params[DEPTH_MAX] = 0.0
            self.params.from_numpy(params)
        return float(params[DEPTH_MAX])

    @property
    def last_candidates(self) -> int:
        """Segment pairs the last pass examined (the grid's cost), read on demand."""
        return int(self.counters.to_numpy()[CANDIDATES])

    def resolve(self, x, dx, x_prev, inv_mass) -> int:
        """One contact pass on positions x [S, N] vec3 [m]: rebuild the grid, find the contacts,
        push their segments apart to r_a + r_b (with friction on the slip x - x_prev), and add the
        averaged corrections to x and to the step's displacement dx [S, N] vec3 [m]. Nodes with
        inv_mass [S, N] [1/kg] == 0 never move. Returns the contacts found (pairs with at least
        one free node); last_max_penetration holds their largest depth before the pass [m]."""
        self._check(x, dx, x_prev, inv_mass)
        self._pass(RESOLVE, self.friction > 0.0, x, x_prev, inv_mass, dx)
        return self.last_pairs

    def max_penetration(self, x, inv_mass=None) -> float:
        """The largest r_a + r_b - d [m] over non-excluded segment pairs at positions x [S, N] (0
        if none touch). With inv_mass [S, N], pairs whose four nodes are all held are left out,
        as resolve leaves them out."""
        self._check(x)
        self._pass(MEASURE, False, x, x, self._masses(x, inv_mass))
        return self.last_max_penetration

    def contact_pairs(self, x, inv_mass=None) -> np.ndarray:
        """The contacts at positions x [S, N], for tests and diagnostics: [P, 4] int rows
        (strand a, segment a, strand b, segment b), slot a < slot b, sorted."""
        self._check(x)
        masses = self._masses(x, inv_mass)
        self._pass(RECORD, False, x, x, masses)
        counters = self.counters.to_numpy()
        if counters[RECORDED] > self.record.shape[0]:
            self.record = arrays.ints((int(counters[RECORDED]), 2), 0)
            self._pass(RECORD, False, x, x, masses)
            counters = self.counters.to_numpy()
        found = self.record.to_numpy()[:int(counters[RECORDED])]
        n_seg = max(self.N - 1, 1)
        rows = np.stack([found[:, 0] // n_seg, found[:, 0] % n_seg, found[:, 1] // n_seg, found[:, 1] % n_seg], axis=1)
        return rows[np.lexsort(rows.T[::-1])] if len(rows) else rows.reshape(0, 4)


def contact_grid(settings, model) -> ContactGrid:
    """The ContactGrid of a simulator's `settings` (a world.forces.StrandContact) for `model`
    (rods.state.RodModel): each strand's contact radius is settings.radius, or its material's
    radius; the neighbour gap from the rest lengths."""
    radius = (np.full(model.groom.n_strands, settings.radius) if settings.radius is not None
              else np.array([m.radius for m in model.materials]))
    return ContactGrid(np.asarray(model.groom.node_counts), radius, settings.friction,
                       settings.self_contact, model.groom.max_nodes, rest_length=model.rest_length)


def resolve_strand_contacts(grid: ContactGrid, settings, model, state, project, passes=None) -> float:
    """The strand-contact stage of one step, after the projection stage: up to `passes`
    (default settings.iterations) contact passes, each followed by `project()` (the length
    projection with the head contacts again), stopping after the pass whose contacts were all
    within settings.tolerance of the radius sum before it. model, state: objects with the
    arrays x, dx, x_prev (state) and inv_mass (model). Returns the largest depth [m] the last
    pass found (before correcting it)."""
    allowed = grid.allowed_depth(settings.tolerance)
    depth = 0.0
    for _ in range(settings.iterations if passes is None else passes):
        if grid.resolve(state.x, state.dx, state.x_prev, model.inv_mass) == 0:
            return 0.0
        depth = grid.last_max_penetration
        project()
        if depth <= allowed:
            break
    return depth
