"""The body below the default head: one smooth neck-shoulders-chest surface, a dress-form bust.

Head-local coordinates as in `taichi_hair.world.headmesh` (metres, +z up, the face along +y).
The bust is a stack of horizontal superellipses |x / a|^p + |(y - c) / b|^p = 1 whose half
width a(z), half depth b(z), centre c(z) and exponent p(z) change smoothly with height:

- the neck: round (p = 2), radius 0.042 m at its top (z = -0.135 m, inside the head's neck
  capsule, radius 0.055 m, which turns with the head) widening to 0.07 m by z = -0.2 m, so
  that the capsule disappears into it, also with the head turned by 40 degrees; its centre
  follows the capsule's forward tilt;
- the shoulders: the width grows from the neck to 0.18 m at z = -0.255 m along a smoothstep,
  whose flanks are vertical at both ends: the neck's sides, the slope of the trapezius, the
  rounded shoulder;
- the chest: deeper (0.11 m) and slightly forward, tapering a little in width where the arms
  would leave it, cut flat at z = -0.56 m (a bust's base).

Rings are spaced evenly along the outline (a(z), z), so the slope of the shoulders gets as many
rings as the neck. The surface is closed by a flat disc at each end (the top one hidden inside
the neck capsule), outward oriented and 2-manifold by construction; the tests check all three.
It is drawn as it is and, through its signed-distance grid, is the collider the hair meets
(`taichi_hair.world.scene.Head.default`): in the world, the head turning on it, or turned
with the head (a turntable).
"""
import functools

import numpy as np

from .headmesh import NECK_CAPSULE, smoothstep
from .sdf import SignedDistanceGrid

NECK_TOP = -0.135  # [m] the bust's top, inside the head's neck capsule
BASE = -0.56  # [m] the flat base
SHOULDER_HALF_WIDTH = 0.18  # [m]
NECK_RADIUS = (0.042, 0.07)  # [m] at the top, and from z = -0.2 m down


def bust_section(z):
    """(a, b, c, p) [m, m, m, 1] of the horizontal section at heights z [m] (arrays): half width
    along x, half depth along y, the centre's y, and the superellipse exponent."""
    z = np.asarray(z, dtype=np.float64)
    neck = NECK_RADIUS[0] + (NECK_RADIUS[1] - NECK_RADIUS[0]) * smoothstep(NECK_TOP, -0.2, z)
    shoulders = smoothstep(-0.165, -0.255, z)
    a = neck + (SHOULDER_HALF_WIDTH - neck) * shoulders - 0.02 * smoothstep(-0.32, -0.52, z)
    chest = smoothstep(-0.22, -0.36, z)
    b = neck + (0.085 - neck) * smoothstep(-0.165, -0.25, z) + 0.025 * chest
    (_, y0, z0), (_, y1, z1), _ = NECK_CAPSULE
    axis = y0 + (y1 - y0) * (np.clip(z, z1, z0) - z0) / (z1 - z0)
    c = axis + (-0.02 - axis) * shoulders + 0.01 * chest
    p = 2.0 + 0.5 * shoulders
    return a, b, c, p


@functools.lru_cache(maxsize=4)
def default_bust(rings: int = 72, sectors: int = 96) -> tuple:
    """The bust's triangle mesh (vertices float64 [V, 3] m, faces int32 [F, 3] counter-clockwise
    seen from outside): `rings` sections evenly spaced along its outline, `sectors` vertices
    around each, a centre vertex closing each end. V = rings x sectors + 2,
    F = 2 x rings x sectors. The arrays are read-only (cached: one build per process)."""
    if not (isinstance(rings, int) and isinstance(sectors, int) and rings >= 4 and sectors >= 8):
        raise ValueError(f"rings must be an integer >= 4 and sectors >= 8, got {rings!r}, {sectors!r}")
    fine = np.linspace(NECK_TOP, BASE, 4001)
    a, b, _, _ = bust_section(fine)
    outline = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(np.maximum(a, b)), np.diff(fine)))])
    z = np.interp(np.linspace(0.0, outline[-1], rings), outline, fine)
    a, b, c, p = bust_section(z)
    phi = np.linspace(0.0, 2.0 * np.pi, sectors, endpoint=False)
    cos, sin = np.cos(phi), np.sin(phi)
    e = 2.0 / p[:, None]
    x = a[:, None] * np.sign(cos) * np.abs(cos) ** e
    y = c[:, None] + b[:, None] * np.sign(sin) * np.abs(sin) ** e
    ring_points = np.stack([x, y, np.broadcast_to(z[:, None], x.shape)], axis=-1).reshape(-1, 3)
    vertices = np.vstack([ring_points, [[0.0, c[0], z[0]], [0.0, c[-1], z[-1]]]])
    top, bottom = len(ring_points), len(ring_points) + 1
    k, j = np.meshgrid(np.arange(rings - 1), np.arange(sectors), indexing="ij")
    here, right = k * sectors + j, k * sectors + (j + 1) % sectors
    below, below_right = here + sectors, right + sectors
    # phi turns counter-clockwise seen from above and the rings go down: (here, below, right)
    # winds counter-clockwise seen from outside
    sides = np.concatenate([np.stack([here, below, right], -1).reshape(-1, 3),
                            np.stack([right, below, below_right], -1).reshape(-1, 3)])
    j = np.arange(sectors)
    last = (rings - 1) * sectors
    caps = np.concatenate([np.stack([np.full(sectors, top), j, (j + 1) % sectors], -1),
                           np.stack([np.full(sectors, bottom), last + (j + 1) % sectors, last + j], -1)])
    faces = np.concatenate([sides, caps]).astype(np.int32)
    vertices.setflags(write=False)
    faces.setflags(write=False)
    return vertices, faces


@functools.lru_cache(maxsize=2)
def default_bust_grid(spacing: float = 0.006) -> SignedDistanceGrid:
    """The bust's signed-distance grid (spacing [m]), built once per process: several seconds
    on 2 cores. 6 mm keeps the trilinear surface within 1 mm of the drawn one away from the
    two end discs (0.62 mm, tests/test_bust.py), against a collision margin of 2 mm."""
    vertices, faces = default_bust()
    return SignedDistanceGrid.from_mesh(vertices, faces, spacing=spacing)
