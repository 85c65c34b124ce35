"""Regression tests for the defects of issue 15 (hardening): each failed on the code before its fix."""

import warnings

import numpy as np
import pytest

import taichi_hair as th


# ---- 1. a root exactly on a head's surface keeps that head as a collider ----------------------

@pytest.mark.parametrize("head", [th.Head.sphere(radius=0.1), th.Head.ellipsoid(radii=(0.1, 0.1, 0.1))],
                         ids=["sphere", "ellipsoid"])
@pytest.mark.parametrize("root", ["clamped", "pinned"])
def test_root_on_the_surface_keeps_the_head_collider(head, root):
    groom = th.Groom.straight(roots=[[0, 0, 0.1]], directions=[[1, 0, 0]], length=0.3, n_nodes=31)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no collider is skipped, so nothing to warn about
        sim = th.Simulator.from_scene(th.Scene(groom=groom, head=head), dt=1e-3, root=root)
    sim.run(0.5, progress=False)
    free = sim.positions()[0, 2 if root == "clamped" else 1:]
    depth = np.linalg.norm(free, axis=1) - 0.1
    # before the fix: 11 (clamped) / 13 (pinned) nodes inside, 1.5 / 3.5 cm deep after 1 s
    assert np.count_nonzero(depth < 0) == 0, f"{np.count_nonzero(depth < 0)} nodes inside, deepest {depth.min():.3g} m"
    assert depth.min() > 0.002 - 1e-9  # and out to the margin
    assert sim.skipped_colliders == []


def test_root_deep_inside_a_collider_skips_it_with_a_warning():
    """A groom rooted 5 mm inside a neck capsule (margin 2 mm) does not collide with the capsule,
    and says so; a root 1 mm inside (within the margin) keeps it."""
    groom = th.Groom.straight(roots=[[0, 0, 0.045], [0.02, 0, 0.045]], directions=[[1, 0, 0], [1, 0, 0]],
                              length=0.1, n_nodes=11)
    neck = th.Capsule(p0=(0, 0, 0), p1=(0, 0, -0.2), radius=0.05, margin=0.002)
    with pytest.warns(RuntimeWarning, match=r"inside Capsule \(colliders\[0\]\) by more than its margin"):
        sim = th.Simulator(groom, th.Material(), colliders=(neck,), gravity=(0, 0, 0))
    assert sim.skipped_colliders == [(0, 0)]
