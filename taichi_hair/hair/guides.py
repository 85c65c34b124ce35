"""Animate an imported hairstyle: pick guide strands, simulate them, re-densify.

    sel = pick_guides(read_hair("style.hair").strands(scale=0.01), 200)
    sim, interp = animate_style(sel, th.Material(), dt=1e-3, root_motion=motion)
    for frame in range(n_frames):
        sim.step(k)
        R, t = motion(sim.time)
        dense = interp.interpolate(sim.positions(), head_rotation=R, head_translation=t,
                                   directors=sim.material_directors())

`pick_guides` (numpy): every strand is resampled to a common node count by arc length, the
roots are clustered by k-means, and each cluster's guide is the member strand whose root is
nearest the cluster's mean root, a real strand of the style, so the simulated guides start
with the style's own shapes. `animate_style` builds the simulator for the guides and an
`Interpolator` that reproduces every imported strand at rest (see `Interpolator`'s
rest_shapes): each dense edge turns as the material frame of the same edge of its guides turns
(`style_interpolator` builds it for a simulator of your own), so the strands keep their own
shapes and lengths while they follow the guides.

Positions are metres; arrays are [strand, node, xyz]; node 0 is the root.
"""

from dataclasses import dataclass
import math

import numpy as np

from ..rods.groom import MIN_SEGMENT_LENGTH, Groom
from .interpolate import Interpolator
from .scalp import nearest
from ..solver.simulator import Simulator

PLANAR_RADIUS_RATIO = 100.0  # a fitted scalp sphere this many times wider than the roots is a plane


@dataclass(frozen=True, eq=False)
class GuideSelection:
    """Guides picked from a dense style, everything resampled to n_nodes nodes.

    guides: [G, n_nodes, 3] (m) the guide strands' rest shapes (= dense[guide_index]).
    guide_index: int64 [G], index of each guide in the input strands.
    dense: [D, n_nodes, 3] (m) every input strand (guides included), in input order.
    cluster: int64 [D], the k-means cluster (= guide number) of each strand's root.
    guide_normals [G, 3], dense_normals [D, 3]: outward unit scalp normals at the roots,
        radial from scalp_centre (see `scalp_normals`).
    scalp_centre [3] (m), scalp_radius (m; inf for a flat scalp): the sphere fitted to the roots.
    """

    guides: np.ndarray
    guide_index: np.ndarray
    dense: np.ndarray
    cluster: np.ndarray
    guide_normals: np.ndarray
    dense_normals: np.ndarray
    scalp_centre: np.ndarray
    scalp_radius: float

    @property
    def n_guides(self) -> int:
        return int(len(self.guides))

    @property
    def n_dense(self) -> int:
        return int(len(self.dense))

    @property
    def n_nodes(self) -> int:
        return int(self.dense.shape[1])

    @property
    def guide_roots(self) -> np.ndarray:
        """[G, 3] (m)."""
        return self.guides[:, 0]

    @property
    def dense_roots(self) -> np.ndarray:
        """[D, 3] (m)."""
        return self.dense[:, 0]


def pick_guides(strands, n_guides, *, n_nodes=None, seed=0, iterations=20) -> GuideSelection:
    """Pick n_guides guide strands from a dense style.

    strands: list of [N_i, 3] arrays (m), root first, N_i >= 3, no zero-length segment (e.g.
        `read_hair(path).strands(scale=0.01)`), or an array [S, N, 3].
    n_guides: integer in [3, number of strands with distinct roots].
    n_nodes: common node count (>= 3) every strand is resampled to, evenly spaced in arc length
        (the first and last nodes stay where they are); default the median N_i (at least 3).
    seed: seeds the k-means++ initialisation; the same seed gives the same guides.
    iterations: cap on Lloyd iterations (they stop earlier when no root changes cluster).

    Clustering is k-means on the root positions, seeded by k-means++, rather than farthest-point
    sampling: farthest-point sampling picks the outermost roots first (the hairline, stray
    strands) and leaves clusters of very unequal size, while k-means gives compact clusters of
    similar extent over the scalp, each guide near the middle of the strands it stands for.
    Empty clusters (possible in Lloyd's iteration) are re-seeded with the root farthest from
    its centre, so every cluster has members."""
    polylines = _check_strands(strands)
    if not (isinstance(n_guides, (int, np.integer)) and 3 <= n_guides <= len(polylines)):
        raise ValueError(f"n_guides must be an integer in [3, {len(polylines)}] (the number of "
                         f"strands), got {n_guides!r}")
    if n_nodes is None:
        n_nodes = max(3, int(np.median([len(p) for p in polylines])))
    if not (isinstance(n_nodes, (int, np.integer)) and n_nodes >= 3):
        raise ValueError(f"n_nodes must be an integer >= 3, got {n_nodes!r}")
    if not (isinstance(iterations, (int, np.integer)) and iterations >= 1):
        raise ValueError(f"iterations must be an integer >= 1, got {iterations!r}")
    dense = resample_strands(polylines, int(n_nodes))
    roots = dense[:, 0]
    unique, inverse = np.unique(roots, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    if len(unique) < n_guides:
        raise ValueError(f"n_guides must be at most the number of distinct roots ({len(unique)}), "
                         f"got {n_guides}")
    labels, centres = _kmeans(unique, int(n_guides), np.random.default_rng(seed), int(iterations))
    guide_index = np.empty(n_guides, dtype=np.int64)
    for c in range(n_guides):
        members = np.flatnonzero(labels == c)
        best = members[np.argmin(((unique[members] - centres[c]) ** 2).sum(1))]
        guide_index[c] = np.flatnonzero(inverse == best)[0]  # first strand with that root
    centre, radius, normals = scalp_normals(roots, dense[:, 1] - roots)
    return GuideSelection(dense[guide_index].copy(), guide_index, dense, labels[inverse],
                          normals[guide_index].copy(), normals, centre, radius)


def animate_style(selection: GuideSelection, material, *, mode="blend", blend=0.5, head=None,
                  head_margin=0.002, interpolator_options=None, **simulator_options):
    """(Simulator, Interpolator) for a GuideSelection.

    The simulator steps the guides (`Groom.from_polylines(selection.guides)` made of `material`;
    simulator_options such as dt, gravity, drag, root_motion go to `Simulator`). The
    interpolator maps its positions [G, n_nodes, 3] to all D strands; its rest shapes are the
    imported strands: with the guides at rest it returns `selection.dense` (to round-off, about
    1e-16 m in float64 and 1e-7 m in float32), a rigid head motion moves them rigidly, and as
    the guides bend each dense edge turns with the same edge of its guides and keeps its
    length. mode, blend: see `Interpolator` (blend weighs the nearest guide's rotations
    against those of the three guides around the root; "clump" follows the nearest only). head,
    head_margin: an optional sphere or ellipsoid collider for the dense nodes (it also moves
    any rest node that lies within head_margin of it). interpolator_options: further
    `Interpolator` keywords (clump_radius, frizz, ...; these alter the style's motion, never
    its rest shape)."""
    if not isinstance(selection, GuideSelection):
        raise ValueError(f"selection must be a GuideSelection (from pick_guides), got "
                         f"{type(selection).__name__}")
    try:
        groom = Groom.from_polylines(selection.guides)
    except ValueError as exc:
        raise ValueError(f"selection.guides cannot be simulated: {exc} (guide s is "
                         f"strands[guide_index[s]])") from None
    simulator = Simulator(groom, material, **simulator_options)
    return simulator, style_interpolator(selection, simulator, mode=mode, blend=blend, head=head,
                                         head_margin=head_margin, **(interpolator_options or {}))


def style_interpolator(selection: GuideSelection, simulator, *, mode="blend", blend=0.5, head=None,
                       head_margin=0.002, **options) -> Interpolator:
    """The `Interpolator` of an imported style for a simulator of the selection's guides, still
    at rest (before its first step): its rest shapes are the imported strands and each dense
    edge turns with the material frame of the same edge of its guides (rest_directors = the
    simulator's directors now). Each frame then takes the simulator's directors:
    `interp.interpolate(sim.positions(), R, t, directors=sim.material_directors())`.
    mode, blend, head, head_margin and further options: see `Interpolator`."""
    if not isinstance(selection, GuideSelection):
        raise ValueError(f"selection must be a GuideSelection (from pick_guides), got "
                         f"{type(selection).__name__}")
    x = simulator.positions()
    if x.shape != selection.guides.shape:
        raise ValueError(f"simulator must hold the selection's {len(selection.guides)} guides of "
                         f"{selection.n_nodes} nodes, got positions {list(x.shape)}")
    gap = float(np.abs(x - selection.guides).max())
    if gap > 1e-5:
        raise ValueError(f"simulator must hold selection.guides at rest (before its first step); its "
                         f"nodes are up to {gap:.3g} m away")
    return Interpolator(selection.guide_roots, selection.guide_normals, selection.dense_roots,
                        selection.n_nodes, mode=mode, blend=blend, head=head, head_margin=head_margin,
                        rest_guides=selection.guides, rest_shapes=selection.dense,
                        rest_directors=simulator.material_directors(), **options)


def resample_strands(strands, n_nodes) -> np.ndarray:
    """Strands [S, n_nodes, 3] (m): each polyline of the list resampled to n_nodes nodes evenly
    spaced along its arc length (linear between its points; roots and tips kept). Vectorised
    over all strands: one sorted search on the strands' normalised arc lengths."""
    counts = np.array([len(p) for p in strands])
    points = np.concatenate(strands)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    strand_of = np.repeat(np.arange(len(strands)), counts)
    node = np.arange(len(points)) - start[strand_of]  # index within its strand
    seg = np.zeros((len(strands), counts.max()))  # seg[s, i + 1] = |x_{i+1} - x_i| of strand s
    inner = node > 0
    step = points[inner] - points[np.flatnonzero(inner) - 1]
    seg[strand_of[inner], node[inner]] = np.linalg.norm(step, axis=1)
    arc = np.cumsum(seg, axis=1)  # per strand, so no cancellation against earlier strands
    s = arc[strand_of, node] / arc[strand_of, counts[strand_of] - 1]  # in [0, 1] along each strand
    target = np.linspace(0.0, 1.0, n_nodes)[None, :]
    # the segment of each target: the last point at or before it, by a search on strand + s
    j = np.searchsorted(2.0 * strand_of + s, 2.0 * np.arange(len(strands))[:, None] + target,
                        side="right") - 1
    j = np.clip(j, start[:, None], (start + counts - 2)[:, None])
    f = ((target - s[j]) / (s[j + 1] - s[j]))[..., None]
    return points[j] + f * (points[j + 1] - points[j])


def scalp_normals(roots, growth):
    """(centre [3] m, radius m, normals [D, 3]): the least-squares sphere through the roots
    [D, 3] and the unit directions from its centre to each root.

    Neither the strands' root edges nor the roots' centroid are used: combed hair leaves the
    scalp nearly tangent to it, so root edges are poor normals, and the centroid of a scalp
    cap lies just under the cap, tilting normals toward the rim; the sphere's centre is also
    the point where the Interpolator's scalp chart expects the normal lines to meet. When the
    fitted radius exceeds PLANAR_RADIUS_RATIO times the roots' extent (a flat patch) the
    normals are the plane's, oriented along the mean of `growth` [D, 3] (the root edges), and
    the radius is inf."""
    a = np.concatenate([2.0 * roots, np.ones((len(roots), 1))], axis=1)
    solution, *_ = np.linalg.lstsq(a, (roots ** 2).sum(1), rcond=None)
    centre = solution[:3]
    radius = math.sqrt(max(solution[3] + centre @ centre, 0.0))
    mean = roots.mean(0)
    extent = np.linalg.norm(roots - mean, axis=1).max()
    if np.all(np.isfinite(centre)) and 0 < radius < PLANAR_RADIUS_RATIO * extent:
        rel = roots - centre
        length = np.linalg.norm(rel, axis=1, keepdims=True)
        if length.min() > 1e-3 * radius:
            return centre, radius, rel / length
    normal = np.linalg.svd(roots - mean, full_matrices=False)[2][-1]
    if normal @ growth.sum(0) < 0:
        normal = -normal
    return mean, math.inf, np.tile(normal, (len(roots), 1))


def _kmeans(points, k, rng, iterations):
    """Labels [M] and centres [k, 3] (the means of their members) of k-means on distinct points
    [M, 3], M >= k, seeded by k-means++; no cluster is empty."""
    centres = np.empty((k, 3))
    centres[0] = points[rng.integers(len(points))]
    d2 = ((points - centres[0]) ** 2).sum(1)
    for c in range(1, k):
        centres[c] = points[rng.choice(len(points), p=d2 / d2.sum())]
        d2 = np.minimum(d2, ((points - centres[c]) ** 2).sum(1))
    labels = None
    for _ in range(iterations):
        new = _fill_empty(points, centres, nearest(points, centres), k)
        if labels is not None and np.array_equal(new, labels):
            break
        labels = new
        sizes = np.bincount(labels, minlength=k)[:, None]
        centres = np.stack([np.bincount(labels, points[:, i], minlength=k) for i in range(3)], 1) / sizes
    return labels, centres


def _fill_empty(points, centres, labels, k):
    """Give each empty cluster the point farthest from its centre among clusters of 2 or more
    (the centre moves onto it); labels [M] are changed in place and returned."""
    counts = np.bincount(labels, minlength=k)
    for c in np.flatnonzero(counts == 0):
        d2 = ((points - centres[labels]) ** 2).sum(1)
        d2[counts[labels] < 2] = -1.0
        far = int(np.argmax(d2))
        counts[labels[far]] -= 1
        labels[far], counts[c], centres[c] = c, 1, points[far]
    return labels


def _check_strands(strands):
    """float64 [N_i, 3] arrays, or ValueError naming the first bad strand."""
    if isinstance(strands, np.ndarray) and strands.ndim == 3:
        strands = list(strands)
    if not isinstance(strands, (list, tuple)):
        raise ValueError(f"strands must be a list of [N_i, 3] arrays or an array [S, N, 3], got "
                         f"{type(strands).__name__}")
    out = []
    for i, p in enumerate(strands):
        p = np.asarray(p, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3:
            raise ValueError(f"strands[{i}] must have shape [N, 3] with N >= 3 points, got "
                             f"{list(p.shape)}")
        out.append(p)
    if not out:
        raise ValueError("strands must hold at least 3 strands, got none")
    points = np.concatenate(out)
    if not np.all(np.isfinite(points)):
        bad = int(np.searchsorted(np.cumsum([len(p) for p in out]), np.argwhere(~np.isfinite(points))[0, 0],
                                  side="right"))
        raise ValueError(f"strands[{bad}] must be finite, got NaN or inf")
    counts = np.array([len(p) for p in out])
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    seg[np.cumsum(counts)[:-1] - 1] = np.inf  # tip-to-next-root jumps are not segments
    short = np.flatnonzero(seg < MIN_SEGMENT_LENGTH)
    if len(short):
        ends = np.cumsum(counts)
        s = int(np.searchsorted(ends, short[0], side="right"))
        first = short[0] - (ends[s - 1] if s else 0)
        raise ValueError(f"strands[{s}] has a zero-length segment (segment {first} shorter than "
                         f"{MIN_SEGMENT_LENGTH:g} m); remove repeated points")
    return out
