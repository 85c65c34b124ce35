"""Strand-strand contact (solver/strand_contact.py) against independent numpy references: closest
points by golden-section search, pair sets by an O(n^2) search, and hand-built crossings."""

import numpy as np
import pytest
import taichi as ti
from taichi_hair.rods.references import curve_points

from taichi_hair.rods import arrays
from taichi_hair.rods.arrays import Vec3s1
from taichi_hair.solver.strand_contact import ContactGrid, segment_closest

Vec2s1 = ti.types.ndarray(dtype=ti.math.vec2, ndim=1)


@ti.kernel
def closest_kernel(a0: Vec3s1, a1: Vec3s1, b0: Vec3s1, b1: Vec3s1, st: Vec2s1):
    for i in range(a0.shape[0]):
        s, t = segment_closest(a0[i], a1[i], b0[i], b1[i])
        st[i] = ti.math.vec2(s, t)


def run_closest(a0, a1, b0, b1):
    n = len(a0)
    args = [arrays.vectors(3, (n,), v) for v in (a0, a1, b0, b1)]
    st = ti.Vector.ndarray(2, float, (n,))
    closest_kernel(*args, st)
    return st.to_numpy()


# ---------------------------------------------------------------- numpy references


def point_segment_distance(p, q0, q1):
    """|p - closest point of segment q0-q1| (vectorised over leading axes)."""
    d = q1 - q0
    dd = (d * d).sum(-1)
    safe = np.where(dd > 0, dd, 1.0)
    t = np.clip(np.where(dd > 0, ((p - q0) * d).sum(-1) / safe, 0.0), 0.0, 1.0)
    return np.linalg.norm(p - (q0 + t[..., None] * d), axis=-1)


def segment_distance(a0, a1, b0, b1, iterations=100):
    """min over s of dist(a0 + s (a1 - a0), segment b), by golden-section search: that function
    of s is convex (the distance to a convex set along a line), so the search converges to its
    minimum; 100 iterations shrink the bracket by 0.618^100 ~ 1e-21."""
    g = lambda s: point_segment_distance(a0 + s[..., None] * (a1 - a0), b0, b1)  # noqa: E731
    lo = np.zeros(a0.shape[:-1])
    hi = np.ones(a0.shape[:-1])
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(iterations):
        c = hi - ratio * (hi - lo)
        d = lo + ratio * (hi - lo)
        left = g(c) <= g(d)
        hi = np.where(left, d, hi)
        lo = np.where(left, lo, c)
    candidates = [g(lo), g(hi), g(np.zeros_like(lo)), g(np.ones_like(lo))]
    return np.min(candidates, axis=0)


def reference_gap(radius, mean_length):
    return np.maximum(2, 1 + np.ceil(0.8 * np.pi * radius / mean_length)).astype(int)


def brute_pairs(x, counts, radius, gap, self_contact, held_strands=()):
    """All allowed segment pairs closer than r_a + r_b, by examining every pair: {(sa, ja, sb, jb):
    r_a + r_b - d} with slot a < slot b; d between the curve points (curve_points) at the
    chords' closest parameters."""
    segs = [(s, j) for s in range(len(counts)) for j in range(counts[s] - 1)]
    a_idx, b_idx = np.triu_indices(len(segs), k=1)
    seg = np.array(segs)
    sa, ja = seg[a_idx, 0], seg[a_idx, 1]
    sb, jb = seg[b_idx, 0], seg[b_idx, 1]
    allowed = np.where(sa == sb, self_contact & (np.abs(ja - jb) >= gap[sa]), True)
    if held_strands:
        held = np.isin(sa, held_strands) & np.isin(sb, held_strands)
        allowed &= ~held
    a0, a1, b0, b1 = x[sa, ja], x[sa, ja + 1], x[sb, jb], x[sb, jb + 1]
    rsum = radius[sa] + radius[sb]
    # bounding spheres: a cheap, conservative cut before the exact distances (the curves bulge
    # from the chords by at most a quarter segment here)
    reach = (np.linalg.norm(a1 - a0, axis=1) + np.linalg.norm(b1 - b0, axis=1)) + rsum
    near = allowed & (np.linalg.norm((a0 + a1) / 2 - (b0 + b1) / 2, axis=1) < reach)
    s, t = closest_params(a0[near], a1[near], b0[near], b1[near])
    d = np.linalg.norm(curve_points(x, counts, sa[near], ja[near], s, radius)
                       - curve_points(x, counts, sb[near], jb[near], t, radius), axis=1)
    keep = d < rsum[near]
    rows = np.stack([sa, ja, sb, jb], axis=1)[near][keep]
    return {tuple(int(v) for v in r): float(p) for r, p in zip(rows, rsum[near][keep] - d[keep])}


def random_strands(counts, max_nodes, box, length, seed):
    """Smooth random walks (segment lengths about `length` [m], varying +-20 %) reflected into a
    cube of side `box` [m]; padding nodes sit on the first node, where they would touch
    everything if they were not ignored. Returns x [S, N, 3] and rest lengths [S, N - 1]."""
    rng = np.random.default_rng(seed)
    x = np.zeros((len(counts), max_nodes, 3))
    for s, n in enumerate(counts):
        p = rng.uniform(0, box, 3)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        for i in range(n):
            x[s, i] = p
            d = d + 0.7 * rng.normal(size=3)
            d /= np.linalg.norm(d)
            p = p + length * rng.uniform(0.8, 1.2) * d
            out = (p < 0) | (p > box)
            p = np.where(p < 0, -p, np.where(p > box, 2 * box - p, p))
            d = np.where(out, -d, d)
        x[s, n:] = x[s, 0]
    rest = np.linalg.norm(np.diff(x, axis=1), axis=2)
    return x, rest


def state(x, inv_mass, x_prev=None):
    S, N = x.shape[:2]
    # positions and previous positions are float64 in both precisions (arrays.Points2)
    return (arrays.vectors(3, (S, N), x, dtype=ti.f64), arrays.vectors(3, (S, N)),
            arrays.vectors(3, (S, N), x if x_prev is None else x_prev, dtype=ti.f64),
            arrays.scalars((S, N), inv_mass))


# ---------------------------------------------------------------- closest points


def closest_cases(rng):
    """Random segment pairs [k, 3] x 4 with the hard cases spelled out."""
    cases = []
    n = 400
    u = lambda: rng.uniform(-1, 1, (n, 3))  # noqa: E731
    cases.append((u(), u(), u(), u()))  # general
    a0, a1 = u(), u()
    k = rng.uniform(-2, 2, (n, 1))
    off = u()
    cases.append((a0, a1, a0 + off, a0 + off + k * (a1 - a0)))  # parallel, either sense
    t0 = rng.uniform(-1.5, 1.5, (n, 1))
    cases.append((a0, a1, a0 + t0 * (a1 - a0), a0 + (t0 + k) * (a1 - a0)))  # collinear, overlapping or not
    p = u()
    da, db = u(), u()
    sa, sb = rng.uniform(0.05, 0.95, (n, 1)), rng.uniform(0.05, 0.95, (n, 1))
    cases.append((p - sa * da, p + (1 - sa) * da, p - sb * db, p + (1 - sb) * db))  # crossing, d = 0
    cases.append((a0, a1, a0 + rng.uniform(0, 1, (n, 1)) * (a1 - a0), u()))  # b0 touches a
    cases.append((a0, a1, a1.copy(), u()))  # shared endpoint
    cases.append((a0, a0.copy(), u(), u()))  # a is a point
    cases.append((u(), u(), a1, a1.copy()))  # b is a point
    cases.append((a0, a0.copy(), a1, a1.copy()))  # both points
    tilt = da + 1e-7 * u()
    q = p + 1e-3 * off
    cases.append((p - sa * da, p + (1 - sa) * da, q - sb * tilt, q + (1 - sb) * tilt))  # nearly parallel
    return [np.concatenate(c) for c in zip(*cases)]


def test_segment_closest_matches_brute_force():
    a0, a1, b0, b1 = closest_cases(np.random.default_rng(1))
    st = run_closest(a0, a1, b0, b1)
    assert np.all((st >= 0) & (st <= 1))
    s, t = st[:, :1], st[:, 1:]
    got = np.linalg.norm(a0 + s * (a1 - a0) - b0 - t * (b1 - b0), axis=1)
    expected = segment_distance(a0, a1, b0, b1)
    assert np.abs(got - expected).max() < 1e-9
    # the crossing cases really are at distance 0, so both sides were tested near 0
    assert np.abs(got[1200:1600]).max() < 1e-12


# ---------------------------------------------------------------- the grid's pair set


def pair_scene():
    counts = np.array([40, 55, 60, 33, 60, 47, 52, 60])
    radius = np.array([0.5, 1.0, 2.0, 3.0, 6.0, 0.8, 1.5, 2.5]) * 1e-3
    x, rest = random_strands(counts, 60, box=0.04, length=0.005, seed=3)
    return counts, radius, x, rest


@pytest.mark.parametrize("self_contact", [True, False])
def test_grid_finds_exactly_the_brute_force_pairs(self_contact):
    counts, radius, x, rest = pair_scene()
    S, N = x.shape[:2]
    mean = np.array([rest[s, :n - 1].mean() for s, n in enumerate(counts)])
    gap = reference_gap(radius, mean)
    assert gap.max() >= 4  # the thick strand's gap goes beyond the shared-node rule
    expected = brute_pairs(x, counts, radius, gap, self_contact)
    grid = ContactGrid(counts, radius, friction=0.0, self_contact=self_contact, max_nodes=N, rest_length=rest)
    assert np.array_equal(grid.neighbour_gap, gap)
    xa, dx, xp, im = state(x, 1.0)
    found = {tuple(int(v) for v in r) for r in grid.contact_pairs(xa)}
    assert len(expected) > 100
    assert found == set(expected)
    same = [p for p in expected if p[0] == p[2]]
    assert (len(same) > 0) == self_contact
    if self_contact:  # some pairs within the gap touch: the exclusion was exercised
        within_gap = brute_pairs(x, counts, radius, np.full(len(counts), 2), True)
        assert len(set(within_gap) - set(expected)) > 0
    assert grid.max_penetration(xa) == pytest.approx(max(expected.values()), rel=1e-9, abs=1e-12)
    assert grid.last_pairs == len(expected)
    # resolve reports the same contacts (all nodes free)
    assert grid.resolve(xa, dx, xp, im) == len(expected)
    assert grid.last_max_penetration == pytest.approx(max(expected.values()), rel=1e-9, abs=1e-12)


def test_pairs_of_held_segments_are_left_out():
    counts, radius, x, rest = pair_scene()
    S, N = x.shape[:2]
    mean = np.array([rest[s, :n - 1].mean() for s, n in enumerate(counts)])
    gap = reference_gap(radius, mean)
    inv_mass = np.ones((S, N))
    held = (2, 4)
    inv_mass[list(held)] = 0.0
    expected = brute_pairs(x, counts, radius, gap, True, held_strands=held)
    everything = brute_pairs(x, counts, radius, gap, True)
    assert len(everything) > len(expected)
    grid = ContactGrid(counts, radius, friction=0.0, self_contact=True, max_nodes=N, rest_length=rest)
    xa, dx, xp, im = state(x, inv_mass)
    assert {tuple(int(v) for v in r) for r in grid.contact_pairs(xa, im)} == set(expected)
    assert grid.resolve(xa, dx, xp, im) == len(expected)
    moved = np.abs(xa.to_numpy() - x).max(axis=(1, 2))
    assert np.all(moved[list(held)] == 0.0)
    assert np.all(np.abs(dx.to_numpy()[list(held)]) == 0.0)


def test_tips_almost_touching_are_found():
    """The grid's worst case: collinear or angled segments tip to tip, a hair less than r_a + r_b
    apart, so their midpoints are almost a cell (longest segment + 2 r_max) apart, at random
    positions relative to the cells. One segment per strand, pairs of strands far apart."""
    rng = np.random.default_rng(5)
    n_pairs = 300
    radius = np.full(2 * n_pairs, 1e-3)
    x = np.zeros((2 * n_pairs, 2, 3))
    for k in range(n_pairs):
        origin = rng.uniform(0, 1.0, 3)
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        v = u if k % 2 else u + 0.3 * rng.normal(size=3)  # collinear, or slightly bent
        v /= np.linalg.norm(v)
        x[2 * k] = [origin - L * u, origin]
        tip = origin + 0.999 * 2e-3 * u
        x[2 * k + 1] = [tip, tip + L * v]
    counts = np.full(2 * n_pairs, 2)
    expected = brute_pairs(x, counts, radius, np.full(2 * n_pairs, 2), True)
    assert set(expected) >= {(2 * k, 0, 2 * k + 1, 0) for k in range(1, n_pairs, 2)}  # the collinear ones
    grid = ContactGrid(counts, radius, friction=0.0, self_contact=True, max_nodes=2)
    found = {tuple(int(v) for v in r) for r in grid.contact_pairs(arrays.vectors(3, x.shape[:2], x))}
    assert found == set(expected)


def closest_params(a0, a1, b0, b1):
    """(s, t) of the closest points of generic (non-parallel) segment pairs, vectorised: the
    minimum of the distance over the unit square is at the interior stationary point, when that
    lies inside, or on one of the four edges (each a clamped projection); take the best."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, b = (d1 * d1).sum(-1), (d2 * d2).sum(-1), (d1 * d2).sum(-1)
    c, f = (d1 * r).sum(-1), (d2 * r).sum(-1)
    det = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):  # parallel pairs: the edges decide
        options = [((b * f - c * e) / det, (a * f - b * c) / det)]
    options += [(np.zeros_like(a), np.clip(f / e, 0, 1)), (np.ones_like(a), np.clip((f + b) / e, 0, 1)),
                (np.clip(-c / a, 0, 1), np.zeros_like(a)), (np.clip((b - c) / a, 0, 1), np.ones_like(a))]
    best = np.full(a.shape, np.inf)
    s_best, t_best = np.zeros_like(a), np.zeros_like(a)
    for s, t in options:
        inside = (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
        d = np.linalg.norm(r + s[:, None] * d1 - t[:, None] * d2, axis=1)
        better = inside & (d < best)
        best = np.where(better, d, best)
        s_best, t_best = np.where(better, s, s_best), np.where(better, t, t_best)
    return s_best, t_best


def reference_pass(x, x_prev, inv_mass, pairs, radius, friction, counts):
    """One Jacobi contact pass in numpy, written from the PBD edge-edge response with the push
    shared p1 = s + sin(2 pi s) / (2 pi) (strand_contact.push_shares): (the moves of x and dx
    [S, N, 3], the pairs acted on: those with a free node of nonzero weight)."""
    delta = np.zeros_like(x)
    hits = np.zeros(x.shape[:2], dtype=int)
    acted = 0
    keys = np.array(sorted(pairs))
    sa, ja, sb, jb = keys.T
    a0, a1, b0, b1 = x[sa, ja], x[sa, ja + 1], x[sb, jb], x[sb, jb + 1]
    s, t = closest_params(a0, a1, b0, b1)
    for k in range(len(keys)):
        nodes = [(sa[k], ja[k]), (sa[k], ja[k] + 1), (sb[k], jb[k]), (sb[k], jb[k] + 1)]
        w = np.array([1 - s[k], s[k], 1 - t[k], t[k]])
        share_a, share_b = (u + np.sin(2 * np.pi * u) / (2 * np.pi) for u in (s[k], t[k]))
        p = np.array([1 - share_a, share_a, 1 - share_b, share_b])
        sign = np.array([1, 1, -1, -1])
        im = np.array([inv_mass[n] for n in nodes])
        W = (p * w * im).sum()
        if W == 0:
            continue
        acted += 1
        on = lambda y, strand, seg, u: curve_points(y, counts, np.array([strand]), np.array([seg]),  # noqa: E731
                                                    np.array([u]), radius)[0]
        pa, pb = on(x, sa[k], ja[k], s[k]), on(x, sb[k], jb[k], t[k])
        d = np.linalg.norm(pa - pb)
        n = (pa - pb) / d
        depth = radius[sa[k]] + radius[sb[k]] - d
        # a pair that crossed since x_prev (at the same material points) goes back to its side
        before = on(x_prev, sa[k], ja[k], s[k]) - on(x_prev, sb[k], jb[k], t[k])
        if (pa - pb) @ before < 0:
            n = before / np.linalg.norm(before)
            depth = radius[sa[k]] + radius[sb[k]] + (pa - pb) @ -n
        push = depth * n
        slip = sum(sign[i] * w[i] * (x[nodes[i]] - x_prev[nodes[i]]) for i in range(4))
        tangential = slip - (slip @ n) * n
        if np.linalg.norm(tangential) < friction * depth:
            push -= tangential
        else:
            push -= friction * depth * tangential / np.linalg.norm(tangential)
        for i in range(4):
            if p[i] * im[i] > 0:
                delta[nodes[i]] += sign[i] * p[i] * im[i] * push / W
                hits[nodes[i]] += 1
    move = np.where(hits[..., None] > 0, delta / np.maximum(hits, 1)[..., None], 0.0)
    return move * (inv_mass > 0)[..., None], acted


@pytest.mark.parametrize("friction", [0.0, 0.4])
def test_one_pass_matches_a_numpy_jacobi_pass(friction):
    """Many pairs share nodes here: the averaging, the weights, the held nodes and friction."""
    counts, radius, x, rest = pair_scene()
    S, N = x.shape[:2]
    rng = np.random.default_rng(9)
    inv_mass = rng.uniform(0.5, 2.0, (S, N))
    inv_mass[:, 0] = 0.0
    inv_mass[4] = 0.0  # the thick strand is held entirely
    # a slip of 10 um: friction acts, and no pair crosses within the step (a crossed pair at
    # any distance is a contact too, which brute_pairs' distance test would not list)
    x_prev = x - rng.normal(scale=1e-5, size=x.shape)
    mean = np.array([rest[s, :n - 1].mean() for s, n in enumerate(counts)])
    pairs = brute_pairs(x, counts, radius, reference_gap(radius, mean), True, held_strands=(4,))
    expected, acted = reference_pass(x, x_prev, inv_mass, pairs, radius, friction, counts)
    assert 0 < acted < len(pairs)  # some pairs touch the held strand only at a held root
    grid = ContactGrid(counts, radius, friction=friction, self_contact=True, max_nodes=N, rest_length=rest)
    xa, dx, xp, im = state(x, inv_mass, x_prev)
    assert grid.resolve(xa, dx, xp, im) == acted
    assert np.abs(expected).max() > 1e-4
    assert np.abs(xa.to_numpy() - x - expected).max() < 1e-14
    assert np.abs(dx.to_numpy() - expected).max() < 1e-14


# ---------------------------------------------------------------- crossings


RA, RB = 1.0e-3, 1.5e-3
L = 0.01


S0, T0 = 0.3, 0.6  # where the crossing lies on segment 2 of strands a and b


def crossing(height, n=6, along_b=(0.0, 1.0, 0.0), shift_b=0.0):
    """Strand a along x through the origin, strand b along `along_b` at z = height [m], crossing
    at s = S0 of segment 2 of a and t = T0 of segment 2 of b (off-centre, so that the two nodes
    of a segment take different shares): one contact pair only, the next segments being over
    0.3 L = 3 mm > r_a + r_b away."""
    x = np.zeros((2, n, 3))
    x[0, :, 0] = (np.arange(n) - 2 - S0) * L
    x[1] = (np.arange(n)[:, None] - 2 - T0 + shift_b) * L * np.asarray(along_b) + np.array([0, 0, height])
    return x


def test_contact_sees_the_curve_not_the_chord():
    """Strand a on a circle of radius 2 cm (nodes 0.2 rad apart, its lowest point in the middle
    of segment 2, the circle's bottom at the origin), strand b straight along y, 0.98 of the
    radius sum below that point: the curves overlap by 0.02 rsum, which the contact must report,
    while segment 2's chord sits 1.0e-4 m (0.04 rsum) above the circle, so chords alone would
    see a gap. The contact's curve is the parabola through the nodes with their curvature
    vectors averaged (each 1 / R towards the centre, dphi / 2 off the vertical): sag
    l^2 cos(dphi / 2) / (8 R), against the arc's R (1 - cos(dphi / 2)), 7.5e-7 m apart here,
    1.5 % of the overlap: second order in dphi."""
    rsum = RA + RB
    radius_circle, dphi, n = 0.02, 0.2, 6
    angle = (np.arange(n) - (n - 1) / 2) * dphi
    x = np.zeros((2, n, 3))
    x[0] = np.stack([radius_circle * np.sin(angle), np.zeros(n), radius_circle * (1 - np.cos(angle))], axis=1)
    x[1, :, 1] = (np.arange(n) - (n - 1) / 2) * L
    x[1, :, 2] = -0.98 * rsum
    chord_gap = x[0, 2, 2] - x[1, 0, 2]  # segment 2's chord at its middle, above b
    assert chord_gap > rsum  # chords: no contact
    grid = ContactGrid(np.array([n, n]), np.array([RA, RB]), friction=0.0, self_contact=False, max_nodes=n)
    xa, dx, xp, im = state(x, 1.0)
    overlap = 0.02 * rsum  # of the circle and the line
    chord = 2 * radius_circle * np.sin(dphi / 2)
    sag_difference = radius_circle * (1 - np.cos(dphi / 2)) - chord**2 * np.cos(dphi / 2) / (8 * radius_circle)
    assert grid.max_penetration(xa) == pytest.approx(overlap - sag_difference, rel=1e-6)
    assert grid.max_penetration(xa) == pytest.approx(overlap, rel=2e-2)
    assert grid.contact_pairs(xa).shape[0] == 1


@pytest.mark.parametrize("pinned", [False, True])
def test_crossing_is_pushed_apart(pinned):
    rsum = RA + RB
    x = crossing(0.5 * rsum)  # overlapping by half the radius sum
    rng = np.random.default_rng(7)
    inv_mass = rng.uniform(0.5, 2.0, (2, 6))
    inv_mass[:, 0] = 0.0  # roots held
    if pinned:
        inv_mass[1, 3] = 0.0  # a node of the touching segment is held
    counts = np.array([6, 6])
    radius = np.array([RA, RB])
    grid = ContactGrid(counts, radius, friction=0.0, self_contact=True, max_nodes=6)
    xa, dx, xp, im = state(x, inv_mass)
    assert grid.resolve(xa, dx, xp, im) == 1
    assert grid.last_max_penetration == pytest.approx(0.5 * rsum, rel=1e-12)
    first = xa.to_numpy() - x
    # at a right-angle crossing the normal is z: a normal push, nothing sideways
    assert np.abs(first[:, :, :2]).max() < 1e-12 * rsum
    # the push splits by inverse mass: strand a went down, strand b up
    assert first[0, 2:4, 2].max() < 0 and first[1, 2:4, 2].min() >= 0
    for _ in range(4):
        grid.resolve(xa, dx, xp, im)
    after = xa.to_numpy()
    move = after - x
    # each pass satisfies the linearised constraint exactly at the pair's closest points; the
    # segments tilt (unequal masses), which moves the closest points by a second-order amount
    # that the next pass removes: the gap left shrinks quadratically (0.5, 1e-3, 1e-9, 1e-16
    # of rsum here, 0.5, 6e-3, 1e-6, 1e-14 pinned), so five passes leave float64 rounding of
    # the 1 cm coordinates (~1e-18 m, 1e-15 of rsum); 1e-12 leaves room for other libms
    # (of the curves through the nodes: the pushed strands bend, and their chords then sit
    # closer than the curves by the sag: 1.2e-3 of rsum here, 6.5e-3 pinned)
    a0, a1, b0, b1 = after[0, 2], after[0, 3], after[1, 2], after[1, 3]
    s, t = closest_params(a0[None], a1[None], b0[None], b1[None])
    on_curves = np.linalg.norm(curve_points(after, counts, np.array([0]), np.array([2]), s, radius)
                               - curve_points(after, counts, np.array([1]), np.array([2]), t, radius))
    assert on_curves >= rsum * (1 - 1e-12)
    assert segment_distance(a0[None], a1[None], b0[None], b1[None])[0] >= rsum * (1 - 1e-2)
    assert grid.max_penetration(xa) <= 1e-12 * rsum
    assert brute_pairs(after, counts, radius * (1 - 1e-12), np.full(2, 2), True) == {}  # no pair at all
    held = inv_mass == 0
    assert np.all(move[held] == 0.0)
    # dx took the same corrections as x (x - x0 rounds at |x| ~ L, dx at |dx| ~ rsum)
    assert np.abs(dx.to_numpy() - move).max() < 1e-15
    if not pinned:
        momentum = (move[~held] / inv_mass[~held][:, None]).sum(axis=0)
        scale = (np.linalg.norm(move[~held], axis=1) / inv_mass[~held]).sum()
        assert np.linalg.norm(momentum) < 1e-12 * scale


@pytest.mark.parametrize("case", ["crossing", "collinear"])
def test_intersecting_segments_get_a_normal(case):
    """d == 0: crossing segments separate along their common normal, overlapping collinear ones
    along some perpendicular; never NaN."""
    rsum = RA + RB
    x = crossing(0.0) if case == "crossing" else crossing(0.0, along_b=(1.0, 0.0, 0.0), shift_b=0.3)
    inv_mass = np.ones((2, 6))
    grid = ContactGrid([6, 6], [RA, RB], friction=0.0, self_contact=True, max_nodes=6)
    xa, dx, xp, im = state(x, inv_mass)
    assert grid.resolve(xa, dx, xp, im) >= 1
    first = xa.to_numpy() - x
    assert np.all(np.isfinite(first)) and np.abs(first).max() > 0.1 * rsum
    if case == "crossing":
        assert np.abs(first[:, :, :2]).max() < 1e-12 * rsum  # along z, the normal of x and y
    else:
        assert np.abs(first[:, :, 0]).max() < 1e-12 * rsum  # perpendicular to the common x axis
    for _ in range(9):
        grid.resolve(xa, dx, xp, im)
    assert np.all(np.isfinite(xa.to_numpy()))
    assert grid.max_penetration(xa) <= 1e-9 * rsum


def test_all_held_pair_is_skipped():
    x = crossing(0.5 * (RA + RB))
    inv_mass = np.ones((2, 6))
    inv_mass[:, 2:4] = 0.0  # both touching segments held
    grid = ContactGrid([6, 6], [RA, RB], friction=0.5, self_contact=True, max_nodes=6)
    xa, dx, xp, im = state(x, inv_mass)
    assert grid.resolve(xa, dx, xp, im) == 0
    assert np.array_equal(xa.to_numpy(), x)
    assert grid.max_penetration(xa, im) == 0.0
    assert grid.max_penetration(xa) == pytest.approx(0.5 * (RA + RB))  # without masses it counts


# ---------------------------------------------------------------- friction


def contact_points(x):
    """Material points of the crossing's contact (segment 2 of each, at S0 and T0)."""
    return (1 - S0) * x[0, 2] + S0 * x[0, 3], (1 - T0) * x[1, 2] + T0 * x[1, 3]


def contact_slip(x, x_prev):
    """Relative displacement over the step of the crossing's contact points, less its normal (z)
    part."""
    pa, pb = contact_points(x - x_prev)
    return (pa - pb)[:2]


@pytest.mark.parametrize("friction,slip,expected", [
    (0.5, (0.10, 0.05), "stick"),  # |slip| = 0.11 rsum < friction x depth = 0.25 rsum
    (0.5, (0.30, 0.20), "slide"),  # |slip| = 0.36 rsum > 0.25 rsum: shortened by 0.25 rsum
    (0.0, (0.10, 0.05), "free"),
])
def test_coulomb_friction(friction, slip, expected):
    rsum = RA + RB
    depth = 0.5 * rsum
    x = crossing(rsum - depth)
    x_prev = x.copy()
    slip = np.array([slip[0], slip[1], 0.0]) * rsum
    x_prev[0] -= slip  # strand a moved by `slip` over the step, strand b stood still
    rng = np.random.default_rng(11)
    inv_mass = rng.uniform(0.5, 2.0, (2, 6))
    grid = ContactGrid([6, 6], [RA, RB], friction=friction, self_contact=True, max_nodes=6)
    xa, dx, xp, im = state(x, inv_mass, x_prev)
    dx.from_numpy(x - x_prev)
    assert grid.resolve(xa, dx, xp, im) == 1
    after = xa.to_numpy()
    remaining = contact_slip(after, x_prev)
    if expected == "stick":
        assert np.linalg.norm(remaining) < 1e-12 * rsum
    elif expected == "slide":
        assert np.linalg.norm(remaining) == pytest.approx(np.linalg.norm(slip) - friction * depth, rel=1e-9)
        cross = remaining[0] * slip[1] - remaining[1] * slip[0]
        assert abs(cross) < 1e-12 * rsum**2 and remaining @ slip[:2] > 0  # same direction
    else:
        assert np.abs(remaining - slip[:2]).max() < 1e-15  # unchanged but for x - x_prev rounding
        assert np.abs((after - x)[:, :, :2]).max() == 0.0  # no tangential correction at all
    # friction is internal: momentum of the corrections still sums to zero
    move = after - x
    momentum = (move / inv_mass[..., None]).sum(axis=(0, 1))
    assert np.linalg.norm(momentum) < 1e-12 * (np.linalg.norm(move, axis=2) / inv_mass).sum()
    assert np.allclose(dx.to_numpy(), after - x_prev, rtol=0, atol=1e-15)
    # the normal push is as without friction: the contact points end rsum apart along z
    pa, pb = contact_points(after)
    assert (pb - pa)[2] == pytest.approx(rsum, rel=1e-12)


# ---------------------------------------------------------------- cost


def test_candidates_grow_linearly():
    """Doubling the segments at constant density about doubles the candidate pairs examined;
    an all-pairs search would quadruple them."""
    candidates = []
    segments = []
    for S in (40, 80, 160):
        counts = np.full(S, 21)
        box = 0.05 * (S / 40) ** (1 / 3)
        x, rest = random_strands(counts, 21, box=box, length=0.005, seed=S)
        grid = ContactGrid(counts, 0.5e-3, friction=0.0, self_contact=True, max_nodes=21, rest_length=rest)
        xa = arrays.vectors(3, (S, 21), x)
        grid.max_penetration(xa)
        candidates.append(grid.last_candidates)
        segments.append(S * 20)
    ratios = np.array(candidates[1:]) / np.array(candidates[:-1])
    assert np.all(ratios < 3.0), (candidates, ratios)
    assert np.all(ratios > 1.4), (candidates, ratios)
    # and far below all pairs of the largest scene
    assert candidates[-1] < 0.1 * segments[-1] ** 2 / 2


# ---------------------------------------------------------------- float32


def test_float32_crossing_and_scene(tmp_path):
    """In float32 (a subprocess: this one runs float64) a crossing still separates to the
    precision's resolution, and a dense scene's contacts shrink without non-finite values.
    1e-4 of rsum is ~2.5e-7 m: a few float32 ulps of the 1 cm coordinates (6e-10 m each) times
    the corrections' rounding, well above it but far below the 0.5 rsum overlap."""
    import subprocess
    import sys
    import textwrap
    from pathlib import Path
    script = textwrap.dedent("""
        import numpy as np
        import taichi_hair as th
        th.init(arch="cpu", precision="float32")
        from test_strand_contact import *
        rsum = RA + RB
        x = crossing(0.5 * rsum)
        inv_mass = np.ones((2, 6))
        inv_mass[:, 0] = 0.0
        grid = ContactGrid([6, 6], [RA, RB], friction=0.3, self_contact=True, max_nodes=6)
        xa, dx, xp, im = state(x, inv_mass)
        for _ in range(5):
            grid.resolve(xa, dx, xp, im)
        after = xa.to_numpy().astype(np.float64)
        assert np.all(np.isfinite(after))
        assert np.all(after[:, 0] == x[:, 0])  # held roots untouched (positions are float64)
        d = segment_distance(after[0, 2][None], after[0, 3][None], after[1, 2][None], after[1, 3][None])[0]
        assert d >= rsum * (1 - 1e-4), d / rsum
        counts, radius, x, rest = pair_scene()
        mean = np.array([rest[s, :n - 1].mean() for s, n in enumerate(counts)])
        expected = brute_pairs(x, counts, radius, reference_gap(radius, mean), True)
        grid = ContactGrid(counts, radius, friction=0.3, self_contact=True, max_nodes=x.shape[1], rest_length=rest)
        xa, dx, xp, im = state(x, 1.0)
        first = grid.resolve(xa, dx, xp, im)
        start = grid.last_max_penetration
        # float32 rounding may flip a pair within ~1e-7 relative of touching: none here, but allow 2
        assert abs(first - len(expected)) <= 2, (first, len(expected))
        assert abs(start - max(expected.values())) < 1e-6 * start
        for _ in range(20):
            grid.resolve(xa, dx, xp, im)
        assert np.all(np.isfinite(xa.to_numpy()))
        assert grid.max_penetration(xa) < start
        print("ok", first, start, grid.last_max_penetration)
    """)
    result = subprocess.run([sys.executable, "-c", script], cwd=Path(__file__).parent,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip().splitlines()[-1].startswith("ok")
