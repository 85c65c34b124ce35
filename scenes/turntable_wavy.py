"""Long wavy hair with hair-hair interaction, on a turntable.

    .venv/bin/taichi-hair run scenes/turntable_wavy.py --out out/turntable_wavy
"""

import taichi_hair as th


def build() -> th.Scene:
    head = th.Head.default(body="head")  # a turntable turns the whole model
    groom = th.scalp_groom(head.model, 400, style="wavy", length=0.4, n_nodes=40, wave_amplitude=0.01,
                           wave_wavelength=0.08, collider=head.distance_field(), seed=2)
    return th.Scene(
        groom=groom, head=head, material=th.Material(ellipticity=1.2),
        motion=th.Turntable(period_s=6.0, ramp_s=0.5),
        hair_interaction=th.HairInteraction(cell_size=0.02, repulsion=1.0, friction=5.0),
        drag=5e-4)


def shot() -> th.Shot:
    return th.Shot(frames=96, fps=24, dense_strands=20000, hair_colour=(0.35, 0.2, 0.1),
                view=(0.00, 0.99, 0.14))
