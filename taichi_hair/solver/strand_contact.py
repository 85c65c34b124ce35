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

Stages, one function each (taichi_hair.solver.contact_stages): `_count` (clear, cell size, bin
segments, count per hash bucket), `_prefix` (serial exclusive scan), `_fill` (counting sort),
`_pair_pass` (pair search and the response, or measuring/recording only), `_apply` (averaged
corrections into x and dx); the segment geometry they use is taichi_hair.solver.segment_geometry.
One kernel, `_contact_pass`, runs them in order as its top-level loops: a pass is one launch,
since launch overhead, not the work, dominates scenes of a few strands. It takes ndarrays, so it
compiles once per process (per mode) and serves every simulator.
"""

import math

import numpy as np
import taichi as ti

from ..rods import arrays
from ..rods.arrays import Ints1, Ints2, Points2, Scalars2, Vec3s2
# the fused contact step (step/contact.py) takes the pass, its bundle and its slots from here
from .contact_stages import (CANDIDATES, CELL, CONTACT_GRID_VALUES, DEPTH_MAX, DONE,  # noqa: F401
                             MAX_PENETRATION, MEASURE, PAIR_COUNT, PAIRS, RECORD, RECORDED, RESOLVE,
                             STEP_VALUES, ContactGridArgs, contact_pass)
from .segment_geometry import segment_closest  # noqa: F401  (the tests take it from here)


@ti.kernel
def _contact_pass(mode: ti.template(), with_friction: ti.template(), cg: ContactGridArgs, node_count: Ints1,
                  x: Points2, x_prev: Points2, inv_mass: Scalars2, dx: Vec3s2, self_contact: ti.i32, mask: ti.i32,
                  friction: float, record: Ints2):
    """One contact pass in one launch (launch overhead, not the work, dominates small scenes):
    the stages _count, _prefix, _fill, _pair_pass and, resolving, _apply, each a top-level
    loop (Taichi runs a kernel's top-level loops one after another)."""
    contact_pass(mode, with_friction, cg, node_count, x, x_prev, inv_mass, dx, self_contact, mask, friction, record)


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
