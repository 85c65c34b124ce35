"""A tiny head scene for the cluster tests: 24 short guides on a coarse head mesh (an ellipsoid
collider, no distance grid), shaken, with dense hair interpolated from them, so a frame exercises
interpolation, the head mesh and the renderer, and a process prepares the scene in about a second.

    .venv/bin/taichi-hair run tests/data/tiny_head.py --out out/tiny_head --workers 2
"""

import taichi_hair as th
from taichi_hair.app.runner import Shot


def build() -> th.Scene:
    model = th.default_head(resolution=3)
    head = th.Head(colliders=(th.Ellipsoid(radii=(0.085, 0.105, 0.11), margin=0.002),),
                   mesh=(model.vertices, model.faces), model=model)
    groom = th.scalp_groom(model, 24, style="wavy", length=0.12, n_nodes=10,
                           collider=head.distance_field(), seed=2)
    return th.Scene(groom=groom, head=head, material=th.Material(),
                    motion=th.Shake(amplitude_deg=25, frequency_hz=2), drag=5e-4)


def shot() -> Shot:
    return Shot(frames=12, fps=24, dense_strands=1500, width=96, height=72, hair_colour=(0.2, 0.12, 0.06),
                eye=(0.0, 0.6, 0.05), target=(0.0, 0.0, -0.02))
