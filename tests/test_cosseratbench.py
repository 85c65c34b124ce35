"""The cosseratbench plugin: taichi_hair run on cosseratbench's own scenarios and scored by its
own metrics and references, at low resolution (the `bench` extra installs cosseratbench)."""

import numpy as np
import pytest

cosseratbench = pytest.importorskip(
    "cosseratbench", reason="cosseratbench is not installed: pip install -e '.[test,bench]'")

import taichi_hair as th  # noqa: E402
from cosseratbench import Capability, registry  # noqa: E402
from cosseratbench.experiment import run  # noqa: E402

from taichi_hair.app.cosseratbench_plugin import (TaichiHairShakeSolver, TaichiHairSolver,  # noqa: E402
                                                  TaichiHairStretchSolver, _Strand)

needs_pins = pytest.mark.skipif(not hasattr(th.Simulator, "add_pin"),
                                reason="needs pins (Simulator.add_pin) for pinned ends")


def bench(name, n_elements, time_step_scale=1.0, solver=TaichiHairSolver, **values):
    result = run(registry.load_experiment(name), solver(time_step_scale), values=values,
                 n_elements=n_elements)
    assert result.outcome == "completed", (result.failure, result.missing)
    return result


def test_registered_with_honest_capabilities():
    solver = registry.load_solver("taichi_hair")
    assert isinstance(solver, TaichiHairSolver) and solver.name == "taichi_hair"
    assert "taichi_hair" in solver.backend_version
    # inextensible, unshearable; rod-rod contact with friction (StrandContact)
    for missing in (Capability.STRETCH, Capability.SHEAR):
        assert missing not in solver.capabilities
    assert {Capability.ROD_CONTACT, Capability.ROD_FRICTION} <= solver.capabilities
    stretch = registry.load_solver("taichi_hair_stretch")
    assert isinstance(stretch, TaichiHairStretchSolver) and Capability.STRETCH in stretch.capabilities


def test_cantilever_against_euler_bernoulli():
    result = bench("cantilever", 20)
    # a rigid clamped element of 1/20 of the length: first-order error, as in PyElastica
    assert result.metrics["tip_deflection_error"] < 0.1
    assert result.metrics["settling_residual"] < 1e-2
    assert result.observations["max_strain"] < 1e-5  # inextensible
    traj = result.trajectory
    assert traj.positions[0].shape == (101, 21, 3) and traj.directors[0].shape == (101, 20, 3)
    assert np.allclose(np.linalg.norm(traj.directors[0], axis=2), 1.0)
    scenario = registry.load_experiment("cantilever").scenario
    assert np.allclose(traj.directors[0][0], scenario.rods[0].directors(20), atol=1e-9)


@needs_pins
def test_pendulum_period_and_first_order_energy_loss():
    coarse, fine = bench("pendulum", 20), bench("pendulum", 20, time_step_scale=0.5)
    # inextensible: the stretched start is shortened to the rest length (strain ~1e-3)
    assert coarse.metrics["period_error"] < 0.01 and fine.metrics["period_error"] < 0.01
    # no damping is added, but the projection's velocity update (v = (x - x_prev) / h) loses
    # energy at first order in the step: the swing shrinks, never grows, and half the step
    # loses about half as much
    a_coarse, a_fine = coarse.metrics["amplitude_change"], fine.metrics["amplitude_change"]
    assert -0.5 < a_coarse < a_fine < 0.0
    assert 0.35 < a_fine / a_coarse < 0.75


def test_shake_pendulum_keeps_its_swing():
    """The explicit step with projection="shake" (registered as taichi_hair_shake): the undamped
    pendulum keeps its amplitude to 1e-4 over 5 s (the fast projection loses a few percent,
    test above), period as accurate."""
    assert isinstance(registry.load_solver("taichi_hair_shake"), TaichiHairShakeSolver)
    result = run(registry.load_experiment("pendulum"), TaichiHairShakeSolver(), n_elements=20)
    assert result.outcome == "completed", (result.failure, result.missing)
    print(f"\nshake pendulum (20): amplitude_change {result.metrics['amplitude_change']:.2e}, "
          f"period_error {result.metrics['period_error']:.2e}")
    assert abs(result.metrics["amplitude_change"]) < 1e-4
    assert result.metrics["period_error"] < 0.01
    assert result.observations["max_strain"] < 1e-6


@needs_pins
def test_catenary_sags_nearly_as_the_elastic_catenary():
    result = bench("catenary", 20)
    # an inextensible cable misses the ~1% of sag stretch adds
    assert result.metrics["sag_error"] < 0.03
    assert result.metrics["shape_error"] < 0.01
    assert result.metrics["settling_residual"] < 1e-2


@needs_pins
def test_extensible_catenary_sags_as_the_elastic_catenary():
    """taichi_hair_stretch (extensible=True, EA = E A): the cable stretches as the analytic
    elastic catenary does, so the sag the inextensible cable misses (1.2 % at 50 elements) is
    gone but for the discretisation's: at 20 elements under 0.3 of the inextensible
    cable's sag error and below 5e-3 (measured 2.2e-3 against 9.7e-3; 1.3e-4 at 50), settled."""
    result = bench("catenary", 20, solver=TaichiHairStretchSolver)
    held = bench("catenary", 20)
    print(f"\nstretch catenary (20): sag_error {result.metrics['sag_error']:.2e} (inextensible "
          f"{held.metrics['sag_error']:.2e}), shape_error {result.metrics['shape_error']:.2e}, "
          f"max_strain {result.observations['max_strain']:.2e}")
    assert result.metrics["sag_error"] < min(5e-3, 0.3 * held.metrics["sag_error"])
    assert result.metrics["shape_error"] < 2e-3
    assert result.metrics["settling_residual"] < 1e-6
    assert result.observations["max_strain"] > 1e-3  # it did stretch


def test_a_symmetric_rope_stays_symmetric_when_shortened():
    """The crossing ropes (an even number of nodes) walked to their unstretched length from
    their middle point: each stays mirror-symmetric about its middle (walked from node n // 2,
    they were 0.1 mm off, enough to seed the slide of one rope along the other)."""
    scenario = registry.load_experiment("crossing").scenario
    for axis, rod in enumerate(scenario.rods):
        rest = _Strand(rod, 51).rest_nodes
        mirrored = rest[::-1].copy()
        mirrored[:, axis] *= -1.0
        assert np.abs(rest - mirrored).max() < 1e-12
        assert np.allclose(np.linalg.norm(np.diff(rest, axis=0), axis=1), rod.length / 51)


def test_time_steps_past_the_explicit_limit_are_reported_not_faked():
    # cosseratbench's time_step_scale sweep goes to 4x: past the explicit limit taichi_hair refuses
    result = run(registry.load_experiment("cantilever"), TaichiHairSolver(4.0), n_elements=10)
    assert result.outcome == "unsupported" and "explicit step's limit" in result.missing[0]


def test_all_seven_experiments_are_supported():
    solver = TaichiHairSolver()
    for name in registry.names(registry.EXPERIMENTS):
        experiment = registry.load_experiment(name)
        assert experiment.requires <= solver.capabilities, name


def test_crossing_ropes_rest_on_each_other_without_passing_through():
    """Two pinned ropes, the upper pressed on the lower (frictionless rod-rod contact), at 21
    elements, where a frame's fall is more than a diameter (tunnelling if contact were only
    discrete): their chords overlap by under one radius at any frame, and the lift is within
    15 % (the ropes cannot stretch, the reference's stretch is about 0.6 %: the remaining
    error). Contact keeps the curves through the nodes a diameter apart, and at 4.8 cm segments
    the two chords sit inside those curves by 0.75 radii together where the ropes bend over
    each other (measured); a rope passing through the other would overlap by 2 radii or more."""
    result = bench("crossing", 21)
    assert result.outcome == "completed"
    assert result.observations["max_rod_overlap"] < 1.0
    assert result.metrics["lift_error"] < 0.15
    assert result.metrics["settling_residual"] < 1e-2


def test_capstan_rope_slides_off_past_the_holding_overhang_and_not_before():
    """A free-free rope over a cylinder with friction 0.3 (100 elements, its default), against
    the heavy-rope capstan equation's longest overhang that holds: at 0.95 of it the rope holds
    (measured: 3.7 mm in 2 s; friction limited by each projection iteration's own push slid it
    off, 0.21 m), at 1.1 times it slides off the cylinder (0.21 m)."""
    held = bench("capstan", 100, overhang=0.95)
    slid = bench("capstan", 100, overhang=1.1)
    assert held.outcome == slid.outcome == "completed"
    assert held.metrics["slide"] < 0.01
    assert slid.metrics["slide"] > 0.1


def test_twisted_rods_buckle_near_greenhills_critical_twist():
    """Six rods clamped at both ends, one end turned (a twist-holding clip) and sliding under
    tension (a slider): the fitted critical twist within PyElastica's 1.1 % of Greenhill's at
    25 elements (measured 0.69 %: the discrete rod's own threshold is 0.72 % late there; with
    the clamps holding the tilted end chords the fit read 0.5 % early at 25 and 1.27 % at 50)."""
    result = bench("twist", 25)
    assert result.outcome == "completed"
    assert result.metrics["critical_twist_error"] < 1.1e-2


@pytest.mark.parametrize("n_elements", [20, 50])
def test_clamped_ends_hold_the_curves_tangent_not_the_end_chord(n_elements):
    """twist's rods start on a bump a (1 - cos 2 pi s / L) / 2 whose slope is zero at both
    clamps: the clamped end elements point along the axis to second order, within
    a (2 pi)^4 / 8 n^3 rad (1.6e-7 at 50 elements; the end chords tilt by a pi^2 / n, 2e-5),
    every other element keeps its direction, and the rod keeps its length and its bump."""
    rod = registry.load_experiment("twist").scenario.rods[0]
    rest = _Strand(rod, n_elements).rest_nodes
    chords = np.diff(rod.nodes(n_elements), axis=0)
    edges = np.diff(rest, axis=0)
    t = edges / np.linalg.norm(edges, axis=1, keepdims=True)
    tilt = np.abs(np.cross(t[[0, -1]], [1.0, 0.0, 0.0])).max()
    assert tilt < 1.1e-4 * (2 * np.pi)**4 / (8 * n_elements**3)
    chord = chords[[0, -1]] / np.linalg.norm(chords[[0, -1]], axis=1, keepdims=True)
    assert np.abs(np.cross(chord, [1.0, 0.0, 0.0])).max() > 0.9e-4 * np.pi**2 / n_elements
    assert np.allclose(t[1:-1], chords[1:-1] / np.linalg.norm(chords[1:-1], axis=1, keepdims=True))
    assert np.allclose(np.linalg.norm(edges, axis=1), rod.length / n_elements)
    assert np.isclose(rest[:, 1].max() - rest[0, 1], 1e-4 * rod.length, rtol=0.05)


@pytest.mark.slow  # the pile experiment stepped frame by frame (a benchmark experiment, by hand)
def test_pile_loses_energy_in_every_frame_once_its_clamp_stops():
    """The rope coiled on the floor, damped, its clamp still: the total energy (kinetic, elastic,
    gravity) falls in every frame of the settling second. At a bending-bound factor of 0.5 with
    contact (h omega = 1.97 for the stiffest mode), contact pushes pump it: a rise of 0.33 of
    itself in one frame, and the rope ends at 0.49 of the energy it had when the clamp stopped
    (measured); at 0.4, the default with strand contact, it falls in every frame."""
    from cosseratbench.experiments.pile import feed_time

    experiment = registry.load_experiment("pile")
    scenario = experiment.scenario_for()
    values = experiment.values()
    stop = feed_time(values["speed"], values["youngs_modulus"])
    sim, _, steps = TaichiHairSolver()._build(scenario, experiment.n_elements, experiment.n_frames)
    assert sim.stability_factor == 0.4
    interval = scenario.duration / (experiment.n_frames - 1)
    energy = []
    for frame in range(1, experiment.n_frames):
        sim.step(steps)
        if frame * interval > stop + 1e-9:
            energy.append(sim.total_energy())
    assert len(energy) > 40
    assert np.all(np.diff(energy) < 0.0)
