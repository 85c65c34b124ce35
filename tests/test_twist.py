"""The quasistatic twist solve on curly elliptic hair: it converges from anywhere, its forces are
the gradient of the energy at twist equilibrium, and a solve that cannot converge refuses the
step instead of returning forces that are not a gradient."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.app.runner import load_scene_module

ELLIPTICITIES = (1.3, 1.7, 2.5, 4.0)
CURL_RADII = (0.003, 0.006, 0.01, 0.02)  # [m]


def random_helices(count, seed):
    """`count` elliptic helices (13 nodes, every ellipticity 1.3 to 4 and curl radius 3 mm to
    2 cm of the sweep), one Material each, and their rest nodes moved by up to a quarter of a segment."""
    rng = np.random.default_rng(seed)
    grooms, materials = [], []
    for k in range(count):
        radius = CURL_RADII[k % len(CURL_RADII)] * rng.uniform(0.8, 1.2)
        pitch = radius * rng.uniform(1.0, 3.0)
        length = 1.7 * np.hypot(2 * np.pi * radius, pitch)
        grooms.append(th.Groom.curly(roots=[[0.1 * k, 0.0, 0.0]], directions=[rng.normal(size=3)],
                                     length=length, n_nodes=13, curl_radius=radius,
                                     curl_pitch=pitch, phase=rng.uniform(0, 2 * np.pi)))
        materials.append(th.Material(ellipticity=ELLIPTICITIES[(k // len(CURL_RADII)) % 4]))
    groom = th.Groom.concatenate(grooms)
    segment = np.linalg.norm(np.diff(groom.positions, axis=1), axis=2).min(axis=1)
    moved = groom.positions + rng.uniform(-1, 1, groom.positions.shape) * 0.25 / np.sqrt(3) * segment[:, None, None]
    moved[:, 0] = groom.positions[:, 0]  # the clamped root node
    return groom, materials, moved


def strandwise_gradient(sim, x0, h, settle):
    """Central differences [S, N, 3] of each strand's energy after settle(x) (which puts the
    simulator at positions x and updates its angles). Strands are independent, so one
    perturbation of node i on every strand gives all their columns at once."""
    grad = np.zeros_like(x0)
    for i in range(x0.shape[1]):
        for k in range(3):
            for sign in (1.0, -1.0):
                x = x0.copy()
                x[:, i, k] += sign * h
                settle(x)
                grad[:, i, k] += sign * sim.strand_elastic_energy() / (2 * h)
    return grad


STRAINS = ("rotation", "der")  # both strain measures (rods/rod.py)


def quasistatic(groom, materials, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return th.Simulator(groom, materials, twist="quasistatic", **options)


@pytest.mark.parametrize("strain", STRAINS)
def test_forces_are_the_gradient_at_twist_equilibrium_on_elliptic_helices(strain):
    """Central differences of the energy re-solved at twist equilibrium, per strand (strands
    are independent, so one perturbation of node i on every strand gives all their columns)."""
    groom, materials, x0 = random_helices(52, seed=14)
    sim = quasistatic(groom, materials, strain=strain)
    sim.set_positions(x0)
    solve = sim.update_twist()
    assert solve["residual"] < 1e-10 and solve["cap_hits"] == 0
    force = sim.elastic_forces()
    iterations = [solve["iterations"]]
    h = 1e-7 * np.linalg.norm(np.diff(groom.positions[0], axis=0), axis=1).min() / 1e-3

    def solved(x):
        sim.set_positions(x)
        report = sim.update_twist()
        assert report["residual"] < 1e-10 and report["cap_hits"] == 0
        iterations.append(report["iterations"])
    grad = strandwise_gradient(sim, x0, h, solved)
    scale = np.abs(force).max(axis=(1, 2))
    assert scale.min() > 1e-9, "vacuous: a strand has no force"
    worst = (np.abs(force + grad).max(axis=(1, 2)) / scale).max()
    print(f"\n{strain}: {groom.n_strands} elliptic helices, worst relative error {worst:.2e}; Newton "
          f"iterations per solve: median {np.median(iterations):.0f}, max {max(iterations)}")
    assert worst <= 1e-6


def test_solve_from_zero_angles_finds_the_same_minimum():
    """The reported case: a 13-node elliptic helix (ellipticity 1.7, curl radius 1 cm, pitch
    1.5 cm, 1.7 turns) with its nodes moved by 2 mm; re-solved from zero angles, a solve whose
    step cap binds stops 0.98 rad away from the warm-started answer."""
    length = 1.7 * np.hypot(2 * np.pi * 0.01, 0.015)
    groom = th.Groom.curly(length=length, n_nodes=13, curl_radius=0.01, curl_pitch=0.015)
    sim = quasistatic(groom, th.Material(ellipticity=1.7))
    rng = np.random.default_rng(0)
    x = groom.positions + 2e-3 * rng.standard_normal(groom.positions.shape)
    x[:, 0] = groom.positions[:, 0]
    sim.set_positions(x)
    warm = sim.update_twist()
    angles, energy = sim.material_angles(), sim.elastic_energy()
    sim.set_material_angles(np.zeros_like(angles))
    sim.set_positions(x)
    cold = sim.update_twist()
    print(f"\nwarm start {warm}, from zero {cold}")
    assert warm["residual"] < 1e-10 and cold["residual"] < 1e-10
    assert abs(sim.elastic_energy() - energy) <= 1e-9 * energy
    assert np.abs(np.abs(sim.theta_gradient())[0, :12]).max() < 1e-9


def test_a_twist_solve_at_its_cap_refuses_the_step():
    groom, materials, _ = random_helices(4, seed=3)
    sim = quasistatic(groom, materials, root_motion=lambda t: (th.Shake(amplitude_deg=60.0, frequency_hz=5.0)(t)),
                      twist_iterations=1, twist_tol=1e-14)
    with pytest.raises(th.SimulationDiverged, match="twist solve of strand") as info:
        sim.step(20)
    assert sim.steps_taken < 20 and np.all(np.isfinite(sim.positions()))
    assert info.value.strand >= 0
    assert sim.stats()["twist_cap_hits"] >= 1


def test_shaken_elliptic_curls_never_hit_the_cap():
    groom, materials, _ = random_helices(8, seed=5)
    sim = quasistatic(groom, materials, drag=1e-4,
                      root_motion=lambda t: th.Shake(amplitude_deg=40.0, frequency_hz=3.0)(t))
    sim.run(0.3, progress=False)
    stats = sim.stats()
    print(f"\nshaken curls: {stats}")
    assert stats["twist_cap_hits"] == 0 and stats["twist_residual_max"] < 1e-6


def test_kmoch_forces_are_the_total_derivative_of_the_energy():
    """Under Kmoch's rule the angles follow the centreline: the force must be minus the gradient
    of E(x, theta_kmoch(x)), the rule applied (Jacobi, from the same old angles) at every x."""
    groom, _, x0 = random_helices(12, seed=7)
    materials = [th.Material(ellipticity=e) for e in (1.0, 1.3, 1.7, 2.5, 4.0, 1.5) * 2]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sim = th.Simulator(groom, materials, twist="kmoch")  # strain=None: DER under Kmoch's rule
    sim.set_positions(x0)
    sim.update_twist()
    old = sim.material_angles()
    sim.update_twist()
    force = sim.elastic_forces()

    def ruled(x):
        sim.set_material_angles(old)
        sim.set_positions(x)
        sim.update_twist()
    grad = strandwise_gradient(sim, x0, 1e-8, ruled)
    scale = np.abs(force).max(axis=(1, 2))
    assert scale.min() > 1e-9
    errors = np.abs(force + grad).max(axis=(1, 2)) / scale
    print(f"\nKmoch's rule, worst relative error {errors.max():.2e} (round strands solved exactly)")
    assert errors.max() <= 1e-6


def swinging_curl(twist, ellipticity):
    """A horizontal curl, DER measure under either twist mode (Kmoch's rule runs DER), so the
    two modes are compared on one energy."""
    groom = th.Groom.curly(length=0.2, n_nodes=30, curl_radius=0.01, curl_pitch=0.02,
                           directions=[[1, 0, 0]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return th.Simulator(groom, th.Material(ellipticity=ellipticity), twist=twist, dt=1e-3, strain="der")


@pytest.mark.parametrize("ellipticity", [1.0, 1.5, 2.5, 4.0])
def test_kmoch_gains_no_energy_beyond_the_integrators_drift(ellipticity):
    """A horizontal curl falling and swinging under gravity without drag for 0.5 s: Kmoch's rule
    against the quasistatic twist in the same run."""
    swing = {}
    for twist in ("quasistatic", "kmoch"):
        sim = swinging_curl(twist, ellipticity)
        e0, energies, kinetic = sim.total_energy(), [], 0.0
        while sim.time < 0.5 - 1e-9:
            sim.step(10)
            energies.append(sim.total_energy())
            kinetic = max(kinetic, sim.kinetic_energy())
        swing[twist] = (max(energies) - e0, np.ptp(energies), sim.stats())
    print(f"\nellipticity {ellipticity}: energy rise (J) quasistatic {swing['quasistatic'][0]:.2e}, "
          f"kmoch {swing['kmoch'][0]:.2e}; range {swing['quasistatic'][1]:.2e} vs {swing['kmoch'][1]:.2e}; "
          f"branch switches {swing['kmoch'][2]['twist_branch_switches']}; kinetic {kinetic:.2e} J")
    assert kinetic > 5 * swing["kmoch"][1]  # it swings: peak kinetic energy well above the drift
    assert swing["kmoch"][0] <= max(swing["quasistatic"][0], 0.0) + 1e-9
    assert swing["kmoch"][1] <= 3 * swing["quasistatic"][1] + 1e-9
    assert swing["kmoch"][2]["twist_branch_switches"] == 0


def test_kmoch_on_elliptic_strands_takes_the_der_measure():
    """strain=None picks DER under Kmoch's rule; asking for the rotation measure with it on an
    elliptic strand is refused (it gained energy there), on round strands (solved exactly) not."""
    groom = swinging_curl("quasistatic", 1.0).groom
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert th.Simulator(groom, th.Material(ellipticity=2.0), twist="kmoch").strain == "der"
        assert th.Simulator(groom, th.Material(ellipticity=2.0)).strain == "rotation"
        assert th.Simulator(groom, th.Material(), twist="kmoch", strain="rotation").strain == "rotation"
        with pytest.raises(ValueError, match="twist='kmoch' on elliptic strands runs with strain='der'"):
            th.Simulator(groom, th.Material(ellipticity=2.0), twist="kmoch", strain="rotation")


def test_hanging_curl_settles_under_kmoch():
    groom = swinging_curl("kmoch", 1.5).groom
    material = th.Material(ellipticity=1.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sim = th.Simulator(groom, material, twist="kmoch", dt=1e-3, drag=2 * material.linear_density * 10)
    sim.run(3.0, progress=False)
    tip = sim.positions()[0, -1]
    sim.run(0.1, progress=False)
    motion = np.linalg.norm(sim.positions()[0, -1] - tip) / 0.2
    print(f"\nKmoch's rule, hanging curl: tip motion over the last 0.1 s {motion:.1e} L")
    assert motion < 1e-9


@pytest.mark.slow
def test_combed_strands_keep_a_fast_twist_solve_through_an_indefinite_hessian():
    """scenes/touch_comb.py: the comb and the grab twist strands near their roots, where the
    exact twist Hessian is indefinite in most Newton iterations. Shifting it (Levenberg-Marquardt)
    keeps the solve to a few dozen iterations; clamping the bending diagonal alone (the fallback
    before) crept at 8 halvings an iteration and hit the cap at t = 0.90 s in float64 (1.38 s in
    float32)."""
    scene = load_scene_module(Path(__file__).resolve().parents[1] / "scenes" / "touch_comb.py").build()
    sim = th.Simulator.from_scene(scene, dt=1.0 / 24.0)
    steps = sim.fit_step(1.0 / 24.0)
    worst = 0
    for _ in range(26):  # to t = 1.08 s
        sim.step(steps)
        stats = sim.stats(reset=True)
        worst = max(worst, stats["twist_iterations_max"])
        assert stats["twist_cap_hits"] == 0 and stats["twist_stalls"] == 0, stats
    print(f"\ntouch_comb to t = {sim.time:.3f} s: at most {worst} twist iterations in a step")
    assert sim.time > 1.0 and worst <= 60
