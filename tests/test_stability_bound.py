"""The explicit step's bending bound against the stiffest mode it must hold: for every shape the
curvature rule (stability.curvature_stiffening) must be at least the stiffest mode's ratio to a
straight chain's estimate, measured from central differences of the elastic forces on the
inextensible chain's tangent space (tests/helpers.stiffest_mode_ratios). At factor 0.5 the
step then runs that mode at h omega <= 2 sqrt(measured / rule) <= 2, symplectic Euler's limit."""

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.solver.stability import curvature_stiffening, rest_turns

from helpers import stiffest_mode_ratios

N, DS = 13, 0.01


def planar(turns):
    """A planar polyline of N nodes, DS apart, turning by `turns` [rad] (signed) at interior nodes."""
    angles = np.concatenate([[0.0], np.cumsum(turns)])
    edges = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], 1) * DS
    return np.vstack([np.zeros(3), np.cumsum(edges, 0)])


def turned(degrees, at, second=0.0):
    turns = np.zeros(N - 2)
    turns[at] = np.radians(degrees)
    if at + 1 < N - 2:
        turns[at + 1] = np.radians(second)
    return planar(turns)


def shapes():
    out = {f"arc {a}": planar(np.full(N - 2, np.radians(a))) for a in (20, 40, 60, 75, 90, 110, 130)}
    for a in (60, 90, 110, 130, 150):
        for b in (0, 60, -60, -90):
            out[f"turns {a}, {b}"] = turned(a, 5, b)
        out[f"root turn {a}"] = turned(a, 0)
    rng = np.random.default_rng(3)
    for k in range(12):  # out of plane: each edge turns by a random angle about a random axis
        edges = [np.array([DS, 0.0, 0.0])]
        for _ in range(N - 2):
            axis = np.cross(edges[-1], rng.normal(size=3))
            axis /= np.linalg.norm(axis)
            angle = rng.uniform(0.0, np.radians(120 if k < 6 else 60))
            e = edges[-1]
            edges.append(e * np.cos(angle) + np.cross(axis, e) * np.sin(angle))
        out[f"random 3d {k}"] = np.vstack([np.zeros(3), np.cumsum(edges, 0)])
    helix = th.Groom.curly(length=(N - 1) * 0.004, n_nodes=N, curl_radius=0.004, curl_pitch=0.006)
    out["tight curl"] = helix.strand(0)
    return out


@pytest.mark.parametrize("strain", ["rotation", "der"])
def test_curvature_rule_bounds_the_stiffest_mode_of_every_rest_shape(strain):
    cases = shapes()
    if strain == "der":  # the DER rule is sec^4 of the largest turn; past 90 degree arcs it fails
        cases = {k: v for k, v in cases.items() if rest_turns(v).max() <= np.radians(91)}
    names = list(cases)
    x = np.array([cases[k] for k in names])
    sim = th.Simulator(th.Groom.from_polylines(x), th.Material(), strain=strain, twist="none")
    measured = stiffest_mode_ratios(sim, x)
    rule = np.array([curvature_stiffening(rest_turns(p)) for p in x])
    assert measured.max() > 1.5  # not vacuous: some shapes are well stiffer than straight
    worst = int(np.argmax(measured / rule))
    assert np.all(measured <= rule), f"{names[worst]}: measured {measured[worst]:.3f} > rule {rule[worst]:.3f}"
