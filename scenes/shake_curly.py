"""Curly elliptic hair under a violent head shake.

    .venv/bin/taichi-hair run scenes/shake_curly.py --out out/shake_curly
"""

import taichi_hair as th


def build() -> th.Scene:
    head = th.Head.default()
    groom = th.scalp_groom(head.model, 300, style="curly", length=0.22, n_nodes=40, curl_radius=0.008,
                           curl_pitch=0.03, collider=head.distance_field(), seed=3)
    return th.Scene(
        groom=groom, head=head,
        material=th.Material(youngs_modulus=3e9, shear_modulus=1e9, radius=45e-6, ellipticity=1.5),
        motion=th.Shake(amplitude_deg=40, frequency_hz=2.0, pivot=(0.0, -0.01, -0.10), ramp_s=0.3),
        drag=5e-4)


def shot() -> th.Shot:
    return th.Shot(frames=72, fps=24, dt=1e-3, dense_strands=20000, hair_colour=(0.12, 0.07, 0.04),
                view=(0.13, 0.97, 0.19))
