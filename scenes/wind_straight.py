"""Straight hair in gusty, turbulent wind.

    .venv/bin/taichi-hair run scenes/wind_straight.py --out out/wind_straight
"""

import taichi_hair as th


def build() -> th.Scene:
    head = th.Head.default()
    groom = th.scalp_groom(head.model, 300, style="straight", length=0.3, n_nodes=31,
                           collider=head.distance_field(), seed=1)
    return th.Scene(
        groom=groom, head=head, material=th.Material(),
        wind=th.Wind(velocity=(2.5, 0.0, 0.0), gust_amplitude=0.6, gust_frequency=0.7,
                     turbulence=0.8, turbulence_scale=0.15, seed=4),
        drag=5e-4)


def shot() -> th.Shot:
    return th.Shot(frames=72, fps=24, dense_strands=20000, hair_colour=(0.55, 0.38, 0.2),
                view=(0.00, 0.99, 0.16), reach=1.0)
