"""A single horizontal strand sagging under its own weight: the validation case of the
accuracy report (its tip is checked against the elastica in tests/test_step.py).

    .venv/bin/taichi-hair run scenes/cantilever.py --out out/cantilever
"""

import numpy as np

import taichi_hair as th

LENGTH = 0.3
SEGMENTS = 30


def build() -> th.Scene:
    ds = LENGTH / (SEGMENTS - 0.5)  # the clamped root edge straddles the clamp at x = 0
    x = -ds / 2 + ds * np.arange(SEGMENTS + 1)
    groom = th.Groom.from_polylines(np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1))
    material = th.Material(youngs_modulus=3e6, shear_modulus=1e6, radius=1e-3, density=1000.0)
    return th.Scene(groom=groom, material=material, drag=0.02, twist="none")


def shot() -> th.Shot:
    # a fixed side view holding the rod level at the start and hanging at the end: a horizontal
    # rod fills the frame's width, a hanging one its height
    return th.Shot(frames=48, fps=24, dt=1e-3, hair_width=2e-3, hair_colour=(0.6, 0.5, 0.4),
                eye=(0.15, 0.48, -0.097), target=(0.15, 0.0, -0.145), fov_y=35.0)
