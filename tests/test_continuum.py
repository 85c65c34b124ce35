"""The continuum Kirchhoff reference (taichi_hair/rods/continuum.py) against closed forms, the planar
elastica of taichi_hair/rods/references.py, Groom.curly's geometry, and its own balance equations."""

import functools
import math
import time

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.rods.continuum import curly_root_frame, hanging_helix, helix_strains, kirchhoff_static

from taichi_hair.rods.references import cantilever_elastica_tip

# the reference hanging helix: 3 turns of radius 5 cm, pitch 5 cm; rod radius 1 cm, E 1e7 Pa
CURL_RADIUS, CURL_PITCH, TURNS = 0.05, 0.05, 3
HELIX_LENGTH = TURNS * math.hypot(2 * math.pi * CURL_RADIUS, CURL_PITCH)
ROD_RADIUS, YOUNGS, DENSITY = 0.01, 1e7, 1300.0
SHEAR = YOUNGS / 3
LINEAR_DENSITY = DENSITY * math.pi * ROD_RADIUS ** 2  # rho A [kg/m]
ROUND = (YOUNGS * math.pi * ROD_RADIUS ** 4 / 4,) * 2 + (SHEAR * math.pi * ROD_RADIUS ** 4 / 2,)
# elliptic section of the same area, semi-axes a (along d1) and b (along d2)
SEMI_A, SEMI_B = ROD_RADIUS * 1.25, ROD_RADIUS / 1.25
ELLIPTIC = (YOUNGS * math.pi * SEMI_A * SEMI_B ** 3 / 4, YOUNGS * math.pi * SEMI_A ** 3 * SEMI_B / 4,
            SHEAR * math.pi * SEMI_A ** 3 * SEMI_B ** 3 / (SEMI_A ** 2 + SEMI_B ** 2))
GRAVITY = np.array([0.0, 0.0, -9.81])
DOWN, HORIZONTAL = (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)
# clamped horizontally along +x, z up: d1 = y, d2 = z, d3 = x (d1 x d2 = d3)
ALONG_X = np.column_stack([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


@functools.lru_cache(maxsize=None)
def helix_solution(direction, stiffness=ROUND, n_steps=4000):
    """The loaded reference helix (cached: several tests read the same solve) and its wall time [s]."""
    start = time.perf_counter()
    result = hanging_helix(HELIX_LENGTH, CURL_RADIUS, CURL_PITCH, direction, stiffness,
                           LINEAR_DENSITY, gravity=GRAVITY, n_steps=n_steps)
    return result, time.perf_counter() - start


def unloaded_tip(direction):
    return hanging_helix(HELIX_LENGTH, CURL_RADIUS, CURL_PITCH, direction, ROUND, 0.0)["tip"]


@pytest.mark.parametrize("direction", [DOWN, HORIZONTAL, (0.3, -0.5, 0.8)])
def test_unloaded_helix_is_groom_curly(direction):
    root, phase, n_nodes, n_steps = np.array([0.02, -0.01, 0.3]), 0.7, 81, 4000
    kappa, tau = helix_strains(CURL_RADIUS, CURL_PITCH)
    assert tau > 0  # Groom.curly draws right-handed helices
    frame = curly_root_frame(direction, CURL_RADIUS, CURL_PITCH, phase)
    result = kirchhoff_static(HELIX_LENGTH, (kappa, 0.0, tau), ROUND, np.zeros(3), root, frame,
                              n_steps=n_steps)
    groom = th.Groom.curly(roots=[root], directions=[direction], length=HELIX_LENGTH,
                           n_nodes=n_nodes, curl_radius=CURL_RADIUS, curl_pitch=CURL_PITCH,
                           phase=phase)
    nodes = result["x"][:: n_steps // (n_nodes - 1)]  # Groom's nodes are even in arc length
    assert nodes.shape == (n_nodes, 3)
    np.testing.assert_allclose(nodes, groom.strand(0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(result["root_moment"], 0.0, atol=0)


def test_planar_large_deflection_matches_elastica():
    length, bending = 0.5, 2e-3
    weight = 3.0 * bending / length ** 3  # w L^3 / EI = 3: the tip drops about a third of L
    result = kirchhoff_static(length, (0.0, 0.0, 0.0), (bending, bending, bending),
                              (0.0, 0.0, -weight), (0.0, 0.0, 0.0), ALONG_X)
    reference = cantilever_elastica_tip(length, weight, bending, n=2000)
    tip = result["tip"]
    assert 0.25 * length < -tip[2] < 0.4 * length
    assert abs(tip[1]) < 1e-14  # the load stays in the x-z plane
    np.testing.assert_allclose(tip[[0, 2]], reference, rtol=0, atol=1e-6 * -reference[1])


def test_small_load_matches_linear_cantilever():
    length, bending = 0.5, 2e-3
    weight = 1e-3 * bending / length ** 3
    result = kirchhoff_static(length, (0.0, 0.0, 0.0), (bending, 3 * bending, bending),
                              (0.0, 0.0, -weight), (0.0, 0.0, 0.0), ALONG_X)
    linear = weight * length ** 4 / (8 * bending)  # bends about d1 = y, so B1 is the stiffness
    assert -result["tip"][2] == pytest.approx(linear, rel=1e-4)


def _frame_curvatures(result):
    """(k1, k2, k3) [n-3, 3] at the interior grid points 2 .. n-2 from 5-point differences of the
    frames (O(h^4)): k1 = d2' . d3, k2 = d3' . d1, k3 = d1' . d2."""
    h = result["s"][1] - result["s"][0]

    def derivative(d):
        return (d[:-4] - 8 * d[1:-3] + 8 * d[3:-1] - d[4:]) / (12 * h)
    d1, d2, d3 = (result[k] for k in ("d1", "d2", "d3"))
    inner = slice(2, -2)
    return np.stack([np.sum(derivative(d2) * d3[inner], axis=1),
                     np.sum(derivative(d3) * d1[inner], axis=1),
                     np.sum(derivative(d1) * d2[inner], axis=1)], axis=1)


def test_constitutive_moment_balances_the_load():
    result, _ = helix_solution(HORIZONTAL, ELLIPTIC)
    s, x = result["s"], result["x"]
    load = LINEAR_DENSITY * GRAVITY
    scale = np.linalg.norm(load) * HELIX_LENGTH ** 2
    # m(s) = int_s^L (x(t) - x(s)) x f dt, trapezoid from the tip
    h = s[1] - s[0]
    from_tip = np.concatenate([np.cumsum((0.5 * h * (x[1:] + x[:-1]))[::-1], axis=0)[::-1],
                               np.zeros((1, 3))])
    balance = np.cross(from_tip - (HELIX_LENGTH - s)[:, None] * x, load)
    kappa, tau = helix_strains(CURL_RADIUS, CURL_PITCH)
    strain = _frame_curvatures(result) - np.array([kappa, 0.0, tau])
    inner = slice(2, -2)
    constitutive = sum(ELLIPTIC[i] * strain[:, i:i + 1] * result[f"d{i + 1}"][inner] for i in range(3))
    assert np.max(np.abs(constitutive)) > 0.03 * scale  # the load really bends and twists it
    np.testing.assert_allclose(constitutive, balance[inner], rtol=0, atol=1e-6 * scale)
    np.testing.assert_allclose(result["root_moment"], balance[0], rtol=0, atol=1e-6 * scale)
    assert result["residual"] < 1e-10 * scale


def test_rk4_grid_convergence():
    coarse, _ = helix_solution(HORIZONTAL, n_steps=2000)
    fine, _ = helix_solution(HORIZONTAL)
    assert np.linalg.norm(coarse["tip"] - fine["tip"]) < 1e-9


@pytest.mark.parametrize("direction", [DOWN, HORIZONTAL])
def test_hanging_issue_helix(direction):
    result, seconds = helix_solution(direction)
    drop = unloaded_tip(direction)[2] - result["tip"][2]
    print(f"\nhanging helix, axis {direction}: tip drop {drop:.6f} m "
          f"(tip {np.round(result['tip'], 6).tolist()} m), {result['load_steps']} load steps, "
          f"{seconds:.2f} s")
    assert np.all(np.isfinite(result["x"]))
    assert 0.0 < drop < HELIX_LENGTH


def test_elliptic_helix_converges():
    round_result, _ = helix_solution(HORIZONTAL)
    result, seconds = helix_solution(HORIZONTAL, ELLIPTIC)
    drop = unloaded_tip(HORIZONTAL)[2] - result["tip"][2]
    print(f"\nelliptic hanging helix, axis horizontal: tip drop {drop:.6f} m, {seconds:.2f} s")
    assert 0.0 < drop < HELIX_LENGTH
    assert np.linalg.norm(result["tip"] - round_result["tip"]) > 1e-3  # B1 != B2 matters


@pytest.mark.parametrize("change, message", [
    ({"length": 0.0}, "length"), ({"stiffness": (1.0, -1.0, 1.0)}, "stiffness"),
    ({"n_steps": 1}, "n_steps"), ({"load": (0.0, 1.0)}, "load"),
    ({"root_frame": 2 * np.eye(3)}, "rotation"), ({"intrinsic": lambda s: (0.0, np.nan, 0.0)}, "intrinsic"),
])
def test_bad_input_raises(change, message):
    arguments = dict(length=1.0, intrinsic=(0.0, 0.0, 0.0), stiffness=(1.0, 1.0, 1.0),
                     load=(0.0, 0.0, -1.0), root_position=(0.0, 0.0, 0.0), root_frame=np.eye(3),
                     n_steps=10)
    arguments.update(change)
    with pytest.raises(ValueError, match=message):
        kirchhoff_static(**arguments)


def test_newton_failure_raises(monkeypatch):
    import taichi_hair.rods.continuum as continuum
    monkeypatch.setattr(continuum, "NEWTON_ITERATIONS", 0)  # every load step then fails
    with pytest.raises(RuntimeError, match="Newton failed"):
        kirchhoff_static(1.0, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.0, 0.0, -1.0), (0.0, 0.0, 0.0),
                         ALONG_X, n_steps=10)
