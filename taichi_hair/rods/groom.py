"""Grooms: the rest shapes of the guide strands.

A groom is data: rest node positions [S, N, 3] in metres (node 0 of each strand is the root,
clamped to the head) and per-strand node counts [S], so strands of different
lengths load together (positions past a strand's count repeat its last node and are never
read). Rest curvature and rest twist are not stored here: the simulator derives them from this
shape (see `taichi_hair.rods.state.build_model`), so an unloaded strand keeps its shape exactly.
"""

from dataclasses import dataclass
import math

import numpy as np

from ..validation import integer, real

MIN_SEGMENT_LENGTH = 1e-7  # [m]; shorter edges make the curvature binormal ill-conditioned
MAX_TURNING_ANGLE_DEG = 170.0  # kb = 2 tan(phi/2) diverges as a strand folds back on itself


@dataclass(frozen=True)
class Groom:
    """Rest shape of S guide strands.

    positions: float64 [S, N, 3], metres; node 0 is the root.
    node_counts: int32 [S], 3 <= node_counts[s] <= N.
    rest_curvature: optional float64 [S, N, 4], the rest material curvatures (wbar_i^{i-1},
        wbar_i^i) [1] of each node; None (the default) measures them on `positions`, so the
        groomed shape is the unloaded shape. Set by `taichi_hair.sag_free`, which chooses them so
        that the groomed shape is the shape at rest under gravity.
    rest_twist: optional float64 [S, N], the rest twist [rad] of each interior node (the turn of
        the material frame against the Bishop frame from edge i-1 to edge i; entries 0 and N-1
        unused); None measures it on `positions`. Set by `sag_free` for twist="quasistatic".
    """

    positions: np.ndarray
    node_counts: np.ndarray
    rest_curvature: np.ndarray | None = None
    rest_twist: np.ndarray | None = None

    def __post_init__(self):
        _validate(self.positions, self.node_counts)
        if self.rest_curvature is not None:
            rc = np.asarray(self.rest_curvature)
            if rc.shape != self.positions.shape[:2] + (4,) or not np.all(np.isfinite(rc)):
                raise ValueError(f"rest_curvature must be finite with shape {list(self.positions.shape[:2]) + [4]}, "
                                 f"got {list(rc.shape)}")
        if self.rest_twist is not None:
            rt = np.asarray(self.rest_twist)
            if rt.shape != self.positions.shape[:2] or not np.all(np.isfinite(rt)):
                raise ValueError(f"rest_twist must be finite with shape {list(self.positions.shape[:2])}, "
                                 f"got {list(rt.shape)}")

    def with_rest_curvature(self, rest_curvature, rest_twist=None) -> "Groom":
        """The same groom with explicit rest material curvatures [S, N, 4] (see rest_curvature)
        and, optionally, rest twist [S, N] rad (see rest_twist)."""
        return Groom(self.positions, self.node_counts, np.asarray(rest_curvature, dtype=np.float64),
                     None if rest_twist is None else np.asarray(rest_twist, dtype=np.float64))

    @property
    def n_strands(self) -> int:
        return int(self.positions.shape[0])

    @property
    def max_nodes(self) -> int:
        return int(self.positions.shape[1])

    def strand(self, s: int) -> np.ndarray:
        """Rest nodes of strand s, [node_counts[s], 3]."""
        return self.positions[s, : self.node_counts[s]].copy()

    def lengths(self) -> np.ndarray:
        """Rest arc length of each strand [S], metres."""
        return np.array([np.linalg.norm(np.diff(self.strand(s), axis=0), axis=1).sum()
                         for s in range(self.n_strands)])

    @classmethod
    def from_polylines(cls, points) -> "Groom":
        """Groom from a numpy [S, N, 3] array, one [N, 3] strand, or a list of [N_i, 3] arrays."""
        if isinstance(points, np.ndarray) and points.ndim == 2:
            points = points[None]
        if isinstance(points, np.ndarray) and points.ndim == 3:
            strands = list(points)
        elif isinstance(points, (list, tuple)):
            strands = list(points)
        else:
            raise ValueError("points must be a numpy array [S, N, 3] or [N, 3], or a list of [N_i, 3] "
                             f"arrays; got {type(points).__name__} "
                             f"with shape {getattr(points, 'shape', None)}")
        if not strands:
            raise ValueError("points must contain at least one strand, got none")
        arrays = []
        for s, p in enumerate(strands):
            p = np.asarray(p, dtype=np.float64)
            if p.ndim != 2 or p.shape[1] != 3:
                raise ValueError(f"points[{s}] must have shape [N, 3], got {p.shape}")
            if p.shape[0] < 3:
                raise ValueError(f"points[{s}] must have at least 3 nodes (two edges), got {p.shape[0]}")
            arrays.append(p)
        counts = np.array([len(p) for p in arrays], dtype=np.int32)
        padded = np.empty((len(arrays), counts.max(), 3))
        for s, p in enumerate(arrays):
            padded[s, : len(p)] = p
            padded[s, len(p):] = p[-1]
        return cls(padded, counts)

    @classmethod
    def straight(cls, roots=None, directions=None, *, length=0.3, n_nodes=32) -> "Groom":
        """Straight strands of `length` [m] with `n_nodes` nodes from `roots` [S, 3] along
        `directions` [S, 3] (default: one strand at the origin hanging along -z)."""
        return cls.from_polylines(_procedural(roots, directions, length, n_nodes,
                                              lambda d: np.zeros_like(d)))

    @classmethod
    def wavy(cls, roots=None, directions=None, *, length=0.3, n_nodes=32,
             amplitude=0.01, wavelength=0.06, phase=0.0) -> "Groom":
        """Planar sine waves: offset amplitude * sin(2 pi d / wavelength + phase) [m] sideways at
        distance d along `directions`; nodes are spaced evenly in arc length."""
        real("amplitude", amplitude, "m", low=0.0)
        real("wavelength", wavelength, "m", low=0.0, low_open=True)

        def wave(d):
            return amplitude * (np.sin(2 * np.pi * d / wavelength + phase) - math.sin(phase))
        return cls.from_polylines(_procedural(roots, directions, length, n_nodes, wave))

    @classmethod
    def curly(cls, roots=None, directions=None, *, length=0.3, n_nodes=64,
              curl_radius=0.01, curl_pitch=0.02, phase=0.0) -> "Groom":
        """Helices of radius `curl_radius` [m] and pitch `curl_pitch` [m per turn] about an axis
        along `directions` that passes curl_radius beside the root; nodes evenly spaced in arc
        length, so every edge has the same length and the discrete curvature is uniform."""
        real("curl_radius", curl_radius, "m", low=0.0, low_open=True)
        real("curl_pitch", curl_pitch, "m", low=0.0)
        real("length", length, "m", low=0.0, low_open=True)
        rise = curl_pitch / (2 * np.pi)
        omega = 1.0 / math.hypot(curl_radius, rise)  # helix angle per unit arc length [rad/m]
        s = np.linspace(0.0, length, integer("n_nodes", n_nodes, low=3))
        angle = omega * s + phase
        local = np.stack([curl_radius * (np.cos(angle) - math.cos(phase)),
                          curl_radius * (np.sin(angle) - math.sin(phase)),
                          rise * omega * s], axis=1)
        return cls.from_polylines(_place(local, roots, directions))

    @classmethod
    def concatenate(cls, grooms) -> "Groom":
        """One groom holding the strands of several (e.g. mixed hair types)."""
        return cls.from_polylines([g.strand(s) for g in grooms for s in range(g.n_strands)])


def _frames(roots, directions):
    """Roots [S, 3], unit growth directions [S, 3] and two perpendicular unit vectors [S, 3]."""
    roots = np.zeros((1, 3)) if roots is None else np.atleast_2d(np.asarray(roots, dtype=np.float64))
    if directions is None:
        directions = np.tile([0.0, 0.0, -1.0], (len(roots), 1))
    directions = np.atleast_2d(np.asarray(directions, dtype=np.float64))
    if roots.shape[1:] != (3,) or directions.shape != roots.shape:
        raise ValueError(f"roots and directions must both have shape [S, 3], got {roots.shape} and "
                         f"{directions.shape}")
    norms = np.linalg.norm(directions, axis=1)
    if not np.all(np.isfinite(norms)) or np.any(norms < 1e-12):
        raise ValueError("directions must be finite, non-zero vectors")
    up = directions / norms[:, None]
    helper = np.where(np.abs(up[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    side = np.cross(up, helper)
    side /= np.linalg.norm(side, axis=1)[:, None]
    return roots, up, side, np.cross(up, side)


def _place(local, roots, directions):
    """Map a local strand [N, 3] (x: side, y: side2, z: along growth) onto every root frame."""
    roots, up, side, side2 = _frames(roots, directions)
    return np.stack([r + np.outer(local[:, 0], a) + np.outer(local[:, 1], b) + np.outer(local[:, 2], u)
                     for r, u, a, b in zip(roots, up, side, side2)])


def _procedural(roots, directions, length, n_nodes, offset):
    """Strands along their directions with a sideways `offset(d)` [m] at distance d, resampled to
    `n_nodes` nodes evenly spaced in arc length."""
    real("length", length, "m", low=0.0, low_open=True)
    n_nodes = integer("n_nodes", n_nodes, low=3)
    fine = np.linspace(0.0, 4.0 * length, 64 * n_nodes)  # overshoot: a wave is longer than its span
    local = np.zeros((len(fine), 3))
    local[:, 2] = fine
    local[:, 0] = offset(fine)
    return _place(resample_by_arc_length(local, length, n_nodes), roots, directions)


def arc_lengths(curve) -> np.ndarray:
    """Arc length [M] m from the first point of the polyline curve [M, 3] to each of its points."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])


def resample_by_arc_length(curve, length, n_nodes) -> np.ndarray:
    """n_nodes points [n_nodes, 3] evenly spaced in arc length over the first `length` metres
    of the polyline curve [M, 3] (linear between its points)."""
    arc, targets = arc_lengths(curve), np.linspace(0.0, length, n_nodes)
    return np.stack([np.interp(targets, arc, curve[:, k]) for k in range(3)], axis=1)


def _validate(positions, node_counts):
    positions = np.asarray(positions)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise ValueError(f"positions must have shape [S, N, 3], got {positions.shape}")
    counts = np.asarray(node_counts)
    if counts.shape != (positions.shape[0],):
        raise ValueError(f"node_counts must have shape [{positions.shape[0]}], got {counts.shape}")
    wrong = np.flatnonzero((counts < 3) | (counts > positions.shape[1]))
    if len(wrong):
        s = int(wrong[0])
        raise ValueError(f"strand {s}: node count must be in [3, {positions.shape[1]}], got {counts[s]}")
    # every strand at once (a loop over strands cost 35 us each: 35 s for a million curves), then the
    # first strand that fails anything is checked alone for its message
    n_max = positions.shape[1]
    nodes = np.arange(n_max)[None, :] < counts[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        edges = np.diff(positions, axis=1)
        lengths = np.linalg.norm(edges, axis=2)
        cos_turn = np.sum(edges[:, 1:] * edges[:, :-1], axis=2) / (lengths[:, 1:] * lengths[:, :-1])
        suspect = ((~np.isfinite(positions).all(axis=2) & nodes).any(axis=1)
                   | (~(lengths >= MIN_SEGMENT_LENGTH) & nodes[:, 1:]).any(axis=1)
                   | (~(cos_turn >= math.cos(math.radians(MAX_TURNING_ANGLE_DEG))) & nodes[:, 2:]).any(axis=1))
    for s in np.flatnonzero(suspect):
        _validate_strand(int(s), positions[s, :counts[s]])


def _validate_strand(s, p):
    """ValueError naming strand s for a non-finite node, a short segment or a fold of its nodes p [n, 3]."""
    bad = np.argwhere(~np.isfinite(p))
    if len(bad):
        raise ValueError(f"strand {s}: node {bad[0][0]} has a non-finite coordinate (NaN or inf): "
                         f"{p[bad[0][0]]}")
    edges = np.diff(p, axis=0)
    lengths = np.linalg.norm(edges, axis=1)
    short = np.flatnonzero(lengths < MIN_SEGMENT_LENGTH)
    if len(short):
        raise ValueError(f"strand {s}: segment {short[0]} has length {lengths[short[0]]:.3g} m; "
                         f"segment lengths must be >= {MIN_SEGMENT_LENGTH:g} m (zero-length segment)")
    cos_turn = np.sum(edges[1:] * edges[:-1], axis=1) / (lengths[1:] * lengths[:-1])
    folded = np.flatnonzero(cos_turn < math.cos(math.radians(MAX_TURNING_ANGLE_DEG)))
    if len(folded):
        raise ValueError(f"strand {s}: turning angle at node {folded[0] + 1} exceeds "
                         f"{MAX_TURNING_ANGLE_DEG:g} degrees; the strand folds back on itself")
