"""A hand brushes through the hair while a grab tool combs a lock back.

    .venv/bin/taichi-hair run scenes/touch_comb.py --out out/touch_comb
"""

import numpy as np

import taichi_hair as th


def hand(t):
    """Sweeps from the left ear over the back of the head to the right, 1.2 s after the start."""
    angle = np.pi * np.clip((t - 0.5) / 2.0, 0.0, 1.0)
    return np.array([-0.16 * np.cos(angle), -0.16 * np.sin(angle) - 0.02, -0.05])


def comb(t):
    """Pulls a lock of the fringe back over the crown."""
    u = np.clip((t - 0.5) / 1.5, 0.0, 1.0)
    return np.array([0.0, 0.14 - 0.22 * u, 0.0 + 0.1 * np.sin(np.pi * u)])


def build() -> th.Scene:
    head = th.Head.default()
    groom = th.scalp_groom(head.model, 300, style="straight", length=0.25, n_nodes=26,
                           comb=(0.0, 1.0, 0.0), comb_strength=0.6, collider=head.distance_field(), seed=5)
    return th.Scene(
        groom=groom, head=head, material=th.Material(),
        touch=(th.Hand(path=hand, radius=0.035), th.Grab(path=comb, radius=0.03, stiffness=0.01,
                                                          active=lambda t: 0.5 <= t <= 2.0)),
        drag=5e-4)


def shot() -> th.Shot:
    return th.Shot(frames=72, fps=24, dense_strands=15000, hair_colour=(0.2, 0.12, 0.06),
                view=(0.57, -0.76, 0.32))
