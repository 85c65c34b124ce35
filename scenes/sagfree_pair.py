"""Sag-free start, side by side: the same grooms taken as the unloaded rest shape (left) and
with rest curvatures from `th.sag_free` (right). Top row: long straight hair leaving its root
horizontally and curving down; bottom row: curly hair leaning out at 45 degrees. Under gravity
the left half sags at once; the right half holds the groomed shape.

    .venv/bin/taichi-hair run scenes/sagfree_pair.py --out out/sagfree_pair

Twist "none": for round hair it is the robust choice with a sag-free rest shape (see
`th.sag_free`: free material angles can roll a rest curl that holds a strand up downward).
"""

import numpy as np

import taichi_hair as th

PER_BLOCK = 6  # strands per (row, half)
RAIL_DEPTH = 0.08  # [m] the roots of a block spread along y
HALF_OFFSET = 0.3  # [m] between the left (as groomed) and right (sag-free) halves


def _straight_draped(root, length=0.3, bend_radius=0.06, n_nodes=40):
    """Leaves the root along +x for 3 cm, turns down over a quarter circle, then hangs."""
    s = np.linspace(0.0, length, n_nodes)
    flat, arc = 0.03, 0.5 * np.pi * bend_radius
    phi = np.clip((s - flat) / bend_radius, 0.0, 0.5 * np.pi)
    x = np.minimum(s, flat) + bend_radius * np.sin(phi)
    z = -bend_radius * (1.0 - np.cos(phi)) - np.maximum(s - flat - arc, 0.0)
    return root + np.stack([x, np.zeros_like(s), z], axis=1)


def groom_pair() -> tuple[th.Groom, np.ndarray]:
    """(groom, right [S] bool): four blocks of PER_BLOCK strands; `right` marks the sag-free half."""
    ys = np.linspace(-RAIL_DEPTH / 2, RAIL_DEPTH / 2, PER_BLOCK)
    strands, right = [], []
    for half, x0 in enumerate((-HALF_OFFSET, 0.0)):
        for y in ys:
            strands.append(_straight_draped(np.array([x0, y, 0.0])))
            right.append(bool(half))
        curly = th.Groom.curly(roots=np.stack([np.full_like(ys, x0), ys, np.full_like(ys, -0.32)], axis=1),
                               directions=np.tile([1.0, 0.0, -1.0], (PER_BLOCK, 1)), length=0.2,
                               n_nodes=48, curl_radius=0.008, curl_pitch=0.02)
        strands += [curly.strand(s) for s in range(curly.n_strands)]
        right += [bool(half)] * PER_BLOCK
    return th.Groom.from_polylines(strands), np.array(right)


def build() -> th.Scene:
    groom, right = groom_pair()
    material = th.Material()
    groom, report = th.sag_free(groom, material, twist="none", strands=right)
    print(report.summary())
    return th.Scene(groom=groom, material=material, drag=5e-4, twist="none")


def shot() -> th.Shot:
    return th.Shot(frames=72, fps=24, hair_width=2.5e-3, hair_colour=(0.55, 0.4, 0.25),
                view=(0.00, -1.00, 0.01), fov_y=30.0, reach=0.1)
