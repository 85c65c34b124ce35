"""The stages of one strand-strand contact pass (taichi_hair.solver.strand_contact, whose
docstring describes the pass), as Taichi functions a kernel runs as its top-level loops: bin the
segments on a spatial hash grid, sort them by bucket, find the overlapping pairs and push them
apart with friction, and apply the averaged corrections. The grid's arrays travel as one
argument (ContactGridArgs); its parameter and counter arrays are read by the slots named here.

Shapes: S strands, N = max nodes per strand (arrays padded), G = S (N - 1) segment slots; the
segment slot of (strand s, segment j) is g = s (N - 1) + j, joining nodes j and j + 1. SI units
throughout (positions and radii in metres).
"""

import math

import taichi as ti

from ..rods.arrays import Ints1, Ints2, Scalars1, Vec3s2, edge, point, vec3
from .segment_geometry import arc_offset, bulge, contact_normal, segment_closest

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
