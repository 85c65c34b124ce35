"""An imported `.hair` hairstyle, animated through guides picked from it.

The style is made here (a dense wavy bob written as a Cem Yuksel `.hair` file under
out/assets/) so nothing is downloaded; point STYLE at your own file to animate it instead.

    .venv/bin/taichi-hair run scenes/imported_style.py --out out/imported_style
"""

from pathlib import Path

import taichi_hair as th

STYLE = Path("out/assets/bob.hair")
MOTION = th.Nod(amplitude_deg=20, frequency_hz=1.0, pivot=(0.0, -0.01, -0.10), ramp_s=0.3)


def make_style(path: Path, n_strands=3000, seed=7):
    """A dense wavy bob on the default head's scalp, saved as .hair (centimetre units)."""
    head = th.default_head()
    grid = th.SignedDistanceGrid.from_mesh(head.vertices, head.faces, spacing=0.004)
    groom = th.scalp_groom(head, n_strands, style="wavy", length=0.2, n_nodes=24, wave_amplitude=0.006,
                           wave_wavelength=0.06, collider=grid, seed=seed)
    strands = [groom.strand(s) * 100.0 for s in range(groom.n_strands)]
    path.parent.mkdir(parents=True, exist_ok=True)
    th.write_hair(path, th.HairFile.from_strands(strands, info="taichi_hair synthetic bob"))


def guide_selection() -> th.GuideSelection:
    """The style's strands (written first if STYLE is missing) and the 200 guides picked from them."""
    if not STYLE.exists():
        make_style(STYLE)
    strands = th.read_hair(STYLE).strands(scale=0.01)
    return th.pick_guides(strands, 200, seed=0)


def build() -> th.Scene:
    selection = guide_selection()
    groom = th.Groom.from_polylines(selection.guides)
    head = th.Head.default()
    return th.Scene(groom=groom, head=head, material=th.Material(), motion=MOTION, drag=5e-4)


def interpolator(scene, simulator):
    """Dense hair: the imported strands themselves, turned with their guides' material frames."""
    return th.style_interpolator(guide_selection(), simulator)


def shot() -> th.Shot:
    return th.Shot(frames=48, fps=24, hair_colour=(0.45, 0.28, 0.12), view=(0.47, 0.87, 0.13))
