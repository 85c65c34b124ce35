"""A groom read from a USD file (BasisCurves), animated through picked guides.

The groom is made here on first run (a wavy scalp groom on the default head, written with
th.write_usd_curves to out/assets/groom.usdc) so nothing is downloaded; point GROOM at your own
USD file (any BasisCurves, linear or cubic, any metersPerUnit / upAxis) to animate it instead.
Needs the usd extra: pip install 'taichi_hair[usd]'.

    .venv/bin/taichi-hair run scenes/usd_groom.py --out out/usd_groom --usd
"""

from functools import lru_cache
from pathlib import Path

import numpy as np

import taichi_hair as th

GROOM = Path("out/assets/groom.usdc")
MOTION = th.Turntable(period_s=4.0)


def make_groom(path: Path, n_strands=1500, seed=11):
    """A wavy scalp groom on the default head with per-strand colours, saved as USD curves."""
    head = th.default_head()
    grid = th.SignedDistanceGrid.from_mesh(head.vertices, head.faces, spacing=0.004)
    groom = th.scalp_groom(head, n_strands, style="wavy", length=0.18, n_nodes=20, wave_amplitude=0.005,
                           wave_wavelength=0.05, collider=grid, seed=seed)
    shade = np.random.default_rng(seed).uniform(0.8, 1.2, (groom.n_strands, 1))
    colours = np.clip(shade * np.array([0.40, 0.24, 0.11]), 0.0, 1.0)
    th.write_usd_curves(path, [groom.strand(s) for s in range(groom.n_strands)], widths=8e-5, colours=colours)


@lru_cache(maxsize=1)
def _selection():
    if not GROOM.exists():
        make_groom(GROOM)
    curves = th.read_usd_curves(GROOM)
    strands = [curves.groom.strand(s) for s in range(curves.groom.n_strands)]
    return th.pick_guides(strands, 120, seed=0), curves


def build() -> th.Scene:
    selection, _ = _selection()
    return th.Scene(groom=th.Groom.from_polylines(selection.guides), head=th.Head.default(body="head"),
                    material=th.Material(), motion=MOTION, drag=5e-4)


def interpolator(scene, simulator):
    """Dense hair: the USD groom's own strands, turned with their guides' material frames."""
    selection, _ = _selection()
    return th.style_interpolator(selection, simulator)


def shot() -> th.Shot:
    _, curves = _selection()
    colour = tuple(float(c) for c in np.nanmean(curves.colors, axis=0)) if curves.colors is not None else (0.4, 0.24, 0.11)
    return th.Shot(frames=48, fps=24, hair_colour=colour, view=(0.47, 0.87, 0.13),
                usd="both")
