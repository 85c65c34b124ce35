"""A full head of guides: 1000 wavy human hairs, 25 cm, on the default head (collisions against
its skull, neck and shoulders), shaken side to side. The scene of the implicit step's large-step
study (`taichi-hair report implicit --scene scenes/full_head.py`, docs/model.md).

    .venv/bin/taichi-hair run scenes/full_head.py --out out/full_head
"""

import taichi_hair as th


def build() -> th.Scene:
    head = th.Head.default()
    groom = th.scalp_groom(head.model, 1000, style="wavy", length=0.25, n_nodes=26, wave_amplitude=0.006,
                           collider=head.distance_field(), seed=21)
    return th.Scene(
        groom=groom, head=head, material=th.Material(),
        motion=th.Shake(amplitude_deg=30, frequency_hz=1.5, pivot=(0.0, -0.01, -0.10), ramp_s=0.3),
        drag=5e-4)


def shot() -> th.Shot:
    return th.Shot(frames=48, fps=24, dt=1e-3, dense_strands=20000, hair_colour=(0.30, 0.18, 0.09),
                view=(0.13, 0.97, 0.19))
