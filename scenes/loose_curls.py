"""Cut hair: loose tight curls (elliptic, 3 mm curl radius) dropped in a heap onto a table, where
they land on each other and stay apart: free strands (root="free", no node held), strand-strand
contact with friction, and a floor.

    .venv/bin/taichi-hair run scenes/loose_curls.py --out out/loose_curls

The curls are far thicker than hair for contact (a 0.5 mm contact radius: a lock of hair, each
guide standing for a few hundred fibres, not a single fibre), so the heap is visible.
"""

import numpy as np

import taichi_hair as th

N_CURLS = 16
CONTACT_RADIUS = 5e-4  # [m] a lock's half-thickness


def curls(n=N_CURLS, seed=3):
    """n helices of 3 mm radius and 6 mm pitch, 8 cm long, 24 nodes, with random axes, stacked
    in a loose pile 0.6-6 cm above the table (at least 0.9 mm apart)."""
    rng = np.random.default_rng(seed)
    turns = np.linspace(0.0, 1.0, 24)
    strands = []
    for k in range(n):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        side = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        side /= np.linalg.norm(side)
        up = np.cross(axis, side)
        rise = 0.006 / (2 * np.pi)
        omega = 1.0 / np.hypot(0.003, rise)
        angle = omega * 0.08 * turns
        local = (0.003 * np.cos(angle)[:, None] * side + 0.003 * np.sin(angle)[:, None] * up
                 + (rise * angle)[:, None] * axis)
        centre = np.array([rng.uniform(-0.02, 0.02), rng.uniform(-0.02, 0.02), 0.01 + 0.003 * k])
        strands.append(centre + local - local.mean(axis=0))
    return th.Groom.from_polylines(np.array(strands))


def build() -> th.Scene:
    table = th.Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), margin=CONTACT_RADIUS,
                     friction=0.4, attached="world")
    # drag 1e-4 N s/m per metre: a curl falls at up to rho A g / drag = 0.6 m/s and lands in a
    # quarter of a second (at 2e-3 it drifted down at 3 cm/s like snow)
    return th.Scene(
        groom=curls(), head=th.Head(colliders=(table,)),
        material=th.Material(ellipticity=2.0), root="free", drag=1e-4,
        strand_contact=th.StrandContact(radius=CONTACT_RADIUS, friction=0.3))


def shot() -> th.Shot:
    # from 70 degrees above the table: the heap's footprint, not its height, fills the frame
    return th.Shot(frames=48, fps=24, eye=(0.029, -0.029, 0.133), target=(0.0, 0.0, 0.02), fov_y=40.0,
                hair_colour=(0.35, 0.2, 0.1), hair_width=1e-3)
