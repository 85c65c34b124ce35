"""Sag-free start: rest curvatures that make the groomed shape a static equilibrium under
gravity. Checked independently of the solve by simulating the result: a balanced groom does not
move; the same groom taken as its own rest shape sags."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.app.runner import load_scene_module

SCENES = Path(__file__).resolve().parent.parent / "scenes"

DIAGONAL = np.array([[1.0, 0.0, -1.0]])  # leaning out at 45 degrees: it sags if not balanced


def drift_after(groom, seconds, twist="none", head=None, motion=None, drag=3e-4):
    """Max node distance [m] from the groomed positions after `seconds` of simulation."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # substep notices
        sim = th.Simulator.from_scene(th.Scene(groom=groom, head=head, motion=motion, drag=drag,
                                               twist=twist), dt=1e-3)
    sim.run(seconds, progress=False)
    return float(np.linalg.norm(sim.positions() - groom.positions, axis=2).max())


@pytest.mark.parametrize("style", ["straight", "curly"])
def test_sag_free_groom_stays_where_it_was_groomed(style):
    root = np.zeros((1, 3))
    groom = (th.Groom.straight(roots=root, directions=DIAGONAL, length=0.2, n_nodes=25) if style == "straight"
             else th.Groom.curly(roots=root, directions=DIAGONAL, length=0.2, n_nodes=48, curl_radius=0.01,
                                 curl_pitch=0.02))
    fixed, report = th.sag_free(groom, th.Material(), twist="none")
    print(f"\n{style}: {report.summary()}")
    assert report.reachable.all() and report.relative_residual.max() < 1e-4
    assert np.array_equal(fixed.positions, groom.positions)
    sagged, held = drift_after(groom, 1.0), drift_after(fixed, 1.0)
    print(f"max drift after 1 s: groomed rest shape {sagged * 1e3:.2f} mm, sag-free {held * 1e3:.4f} mm")
    assert sagged > 0.01 and held < 1e-4


def test_quasistatic_twist_balances_the_angles_too():
    groom = th.Groom.curly(roots=np.zeros((1, 3)), directions=DIAGONAL, length=0.2, n_nodes=48,
                           curl_radius=0.01, curl_pitch=0.02)
    fixed, report = th.sag_free(groom, th.Material(), twist="quasistatic")
    assert fixed.rest_twist is not None and report.torsion_stable.all()
    sim = th.Simulator(fixed, th.Material(), twist="quasistatic")
    # dE/dtheta on the free edges vs a unit twist's GJ [J/rad]: every edge, edge 0 included (the
    # root node twists against the clamp, so edge 0's angle is free)
    assert np.abs(sim.theta_gradient()).max() < 1e-6 * sim.model.stiffness.to_numpy()[0, 2]
    assert drift_after(fixed, 1.0, twist="quasistatic") < 1e-4 < drift_after(groom, 1.0, twist="quasistatic")


@pytest.mark.parametrize("bend_radius, stable", [(0.03, True), (0.06, False)])
def test_rolling_instability_is_flagged(bend_radius, stable):
    # hair leaving its root horizontally and bending down: the wider bend needs a rest curl
    # against its groomed curvature to hold the flat part up, and free angles roll it over.
    # Independent check: perturb the angles and let the simulator's own quasistatic solve
    # settle them: back to the balance if stable, to another minimum if not.
    draped = load_scene_module(SCENES / "sagfree_pair.py")._straight_draped
    groom = th.Groom.from_polylines(draped(np.zeros(3), length=0.3, bend_radius=bend_radius))
    _, report = th.sag_free(groom, th.Material(), twist="quasistatic", max_turning_deg=170.0)
    assert bool(report.torsion_stable[0]) is stable and bool(report.fell_back[0]) is not stable
    assert report.n_unreachable == (not stable)
    fixed, report = th.sag_free(groom, th.Material(), twist="quasistatic", max_turning_deg=170.0,
                                keep_saddles=True)
    assert report.relative_residual.max() < 1e-4  # balanced either way
    sim = th.Simulator(fixed, th.Material(), twist="quasistatic")
    balance = sim.material_angles()
    nudged = balance.copy()
    nudged += 0.05 * np.random.default_rng(0).standard_normal(nudged.shape)  # every edge is free
    sim.set_material_angles(nudged)
    sim.update_twist()
    moved = np.abs(sim.material_angles() - balance).max()
    print(f"\nbend radius {bend_radius}: angles settle {moved:.2e} rad from the balance")
    assert (moved < 1e-6) if stable else (moved > 0.5)


def test_the_root_node_carries_the_root_moment():
    # the clamp holds node 0 only and node 0 bends (its Voronoi length half the first edge): in
    # a straight strand leaning out at 45 degrees, the rest curvature's moment EI |wbar_i| / l_i
    # at every bending node 0..n-2 is the moment of the weight of the free nodes beyond it
    n, length = 25, 0.2
    groom = th.Groom.straight(roots=np.zeros((1, 3)), directions=DIAGONAL, length=length, n_nodes=n)
    material = th.Material()
    fixed, _ = th.sag_free(groom, material, twist="none")
    step = length / (n - 1)
    s = step * np.arange(n)
    mass = material.linear_density * step * np.r_[np.ones(n - 1), 0.5]
    weight_moment = np.array([np.sum(mass[i + 1:] * (s[i + 1:] - s[i])) for i in range(n - 1)]) * 9.81 * np.sqrt(0.5)
    voronoi = np.r_[0.5 * step, np.full(n - 2, step)]
    pairs = fixed.rest_curvature[0, :n - 1].reshape(n - 1, 2, 2)  # (seen from edge i-1 or the clamp, from edge i)
    moment = max(material.bending_stiffness) * np.linalg.norm(pairs.mean(axis=1), axis=1) / voronoi
    print(f"\nroot moment {moment[0]:.4e} N m (weight's {weight_moment[0]:.4e}); "
          f"max relative error {np.abs(moment / weight_moment - 1).max():.1e}")
    assert np.allclose(moment, weight_moment, rtol=1e-3)


def test_pinned_roots_are_refused():
    groom = th.Groom.straight(roots=np.zeros((1, 3)), directions=DIAGONAL, length=0.1, n_nodes=8)
    with pytest.raises(ValueError, match="hinge"):
        th.sag_free(groom, th.Material(), root="pinned")


def test_a_balance_that_is_a_saddle_is_flagged_and_not_used():
    # a wavy strand leaning out at 45 degrees: its balance needs rest curvatures against the
    # groomed waves, and the balanced pose is a saddle (the simulation leaves it at once)
    groom = th.Groom.wavy(roots=np.zeros((1, 3)), directions=DIAGONAL, length=0.3, n_nodes=40,
                          amplitude=0.01, wavelength=0.06)
    saddle, report = th.sag_free(groom, th.Material(), twist="none", max_turning_deg=170.0, keep_saddles=True)
    assert report.relative_residual[0] < 1e-4 and not report.shape_stable[0]
    left = drift_after(saddle, 0.3)
    kept, report = th.sag_free(groom, th.Material(), twist="none", max_turning_deg=170.0)
    print(f"\nthe saddle balance leaves the groom by {left * 1e3:.1f} mm in 0.3 s")
    assert left > 5e-3
    assert report.fell_back[0] and report.n_unreachable == 1
    assert np.allclose(kept.rest_curvature, th.sag_free(groom, th.Material(), twist="none",
                                                        strands=[])[0].rest_curvature)


def test_contact_with_the_head_carries_part_of_the_weight():
    # a strand combed over the top of a ball and hanging down its side, resting on it
    head = th.Head.sphere(radius=0.1, margin=0.002)
    r = 0.1 + 0.002
    phi = np.linspace(0.15, 0.5 * np.pi, 18)
    over = np.stack([r * np.sin(phi), np.zeros_like(phi), r * np.cos(phi)], axis=1)
    down = over[-1] + np.outer(np.arange(1, 11) * 0.012, [0.0, 0.0, -1.0])
    groom = th.Groom.from_polylines(np.vstack([over, down]))
    fixed, report = th.sag_free(groom, th.Material(), head=head, twist="none")
    print(f"\n{report.summary()}; contact force {report.contact_force[0]:.3e} N of weight {report.weight[0]:.3e} N")
    assert report.contact_nodes[0] >= 5 and report.contact_force[0] > 0.1 * report.weight[0]
    assert report.relative_residual[0] < 1e-4
    free_fixed, _ = th.sag_free(groom, th.Material(), twist="none")  # the ball ignored
    assert drift_after(fixed, 1.0, head=head) < 5e-4
    assert drift_after(free_fixed, 1.0, head=head) > drift_after(fixed, 1.0, head=head)


def test_sag_free_hair_still_moves_and_returns_after_a_shake():
    groom = th.Groom.straight(roots=np.zeros((1, 3)), directions=DIAGONAL, length=0.2, n_nodes=25)
    fixed, _ = th.sag_free(groom, th.Material(), twist="none")
    shake = th.Shake(amplitude_deg=20.0, frequency_hz=2.0, pivot=(0.0, -0.1, 0.0))
    stop = 1.0  # two full periods: the head is back at rest at angle 0
    motion = lambda t: shake(min(t, stop))  # noqa: E731
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sim = th.Simulator.from_scene(th.Scene(groom=fixed, motion=motion, drag=2e-3, twist="none"), dt=1e-3)
    swing = 0.0  # the largest offset from the groom carried rigidly by the head
    while sim.time < stop - 1e-9:
        sim.run(0.02, progress=False)
        rotation, translation = motion(sim.time)
        carried = groom.positions[0] @ np.asarray(rotation).T + translation
        swing = max(swing, np.linalg.norm(sim.positions()[0] - carried, axis=1).max())
    sim.run(6.0, progress=False)
    back = np.linalg.norm(sim.positions() - groom.positions, axis=2).max()
    print(f"\nmax swing away from the head-carried groom {swing * 1e3:.1f} mm; 6 s after the shake "
          f"{back * 1e3:.3f} mm from the groom")
    assert swing > 0.01 and back < 1e-3


def test_only_the_chosen_strands_change():
    groom = th.Groom.straight(roots=np.array([[0.0, 0, 0], [0.0, 0.05, 0]]), directions=np.tile(DIAGONAL, (2, 1)),
                              length=0.15, n_nodes=16)
    fixed, report = th.sag_free(groom, th.Material(), twist="none", strands=[1])
    assert report.solved.tolist() == [False, True] and report.reachable.all()
    assert np.abs(fixed.rest_curvature[0]).max() < 1e-9 < np.abs(fixed.rest_curvature[1]).max()
    assert report.relative_residual[0] > 0.01 > 1e-4 > report.relative_residual[1]


@pytest.mark.parametrize("kwargs, name", [
    ({"gravity": (0.0, float("nan"), 0.0)}, "gravity"),
    ({"twist": "spin"}, "twist"),
    ({"regularization": -1.0}, "regularization"),
    ({"max_turning_deg": 180.0}, "max_turning_deg"),
    ({"contact_tolerance": -1e-3}, "contact_tolerance"),
    ({"iterations": 0}, "iterations"),
    ({"strands": [5]}, "strands"),
    ({"head": "ball"}, "head"),
    ({"root": "glued"}, "root"),
])
def test_bad_input_names_the_parameter(kwargs, name):
    groom = th.Groom.straight(roots=np.zeros((1, 3)), directions=DIAGONAL, length=0.1, n_nodes=8)
    with pytest.raises(ValueError, match=name):
        th.sag_free(groom, th.Material(), **kwargs)
