"""Kmoch's time step against analytic references, conservation, constraints and the guard."""

import json
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

import taichi_hair as th
from helpers import rotation_matrix
from taichi_hair.rods.references import cantilever_elastica_tip, cantilever_first_frequency, first_mode_slope
from taichi_hair.solver.step.plan import STALL_BELOW

BEAM = dict(youngs_modulus=1e7, shear_modulus=1e7 / 3, radius=0.01, density=1000.0)
LENGTH = 1.0


def clamped_beam(n_segments, slope=None):
    """A horizontal beam of length LENGTH along +x clamped at the origin, its root node (the
    clamp sits at the groomed root: no allowance for the segment length).
    `slope(s)` optionally bends it to the angle theta(s) [rad] (edge lengths stay exact)."""
    ds = LENGTH / n_segments
    s_mid = ds * (np.arange(n_segments) + 0.5)  # arc length at edge midpoints
    theta = np.zeros(n_segments) if slope is None else slope(s_mid)
    steps = ds * np.stack([np.cos(theta), np.zeros_like(theta), np.sin(theta)], axis=1)
    nodes = np.vstack([[0.0, 0.0, 0.0], np.cumsum(steps, axis=0)])
    return th.Groom.from_polylines(nodes)


def quiet(factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # substepping notices
        return factory()


def cantilever_tip_error(n_segments):
    material = th.Material(**BEAM)
    ei, rho_a = material.bending_stiffness[0], material.linear_density
    omega1 = 2 * np.pi * cantilever_first_frequency(LENGTH, ei, rho_a)
    # mass-proportional drag 2 rho A omega1 damps every mode at the rate omega1
    sim = quiet(lambda: th.Simulator(clamped_beam(n_segments), material, dt=1e-3,
                                     drag=2 * rho_a * omega1, twist="none"))
    sim.run(6.0, progress=False)
    assert sim.kinetic_energy() < 1e-8 * sim.elastic_energy(), "not at rest yet"
    reference = cantilever_elastica_tip(LENGTH, rho_a * 9.81, ei)
    tip = sim.positions()[0, -1][[0, 2]]
    return np.linalg.norm(tip - reference) / LENGTH


def test_static_cantilever_matches_the_elastica():
    material = th.Material(**BEAM)
    assert 39 < material.linear_density * 9.81 * LENGTH**3 / material.bending_stiffness[0] < 39.5
    errors = {n: cantilever_tip_error(n) for n in (12, 25, 50)}
    print("\ncantilever tip error / L:", {n: f"{e:.2e}" for n, e in errors.items()})
    assert errors[50] < 0.001
    assert errors[12] > errors[25] > errors[50]
    assert errors[12] / errors[50] > 8  # second order with the clamp at the root node (11 here)


def test_first_vibration_frequency_matches_beam_theory():
    material = th.Material(**BEAM)
    ei, rho_a = material.bending_stiffness[0], material.linear_density
    expected = cantilever_first_frequency(LENGTH, ei, rho_a)
    amplitude = 0.01 * LENGTH
    groom = clamped_beam(30, slope=lambda s: amplitude * first_mode_slope(s, LENGTH))
    sim = quiet(lambda: th.Simulator(groom, material, dt=2e-3, gravity=(0, 0, 0), twist="none"))
    # the rest shape is straight: rebuild the simulator on a straight groom, start it bent
    straight = quiet(lambda: th.Simulator(clamped_beam(30), material, dt=2e-3, gravity=(0, 0, 0),
                                          twist="none"))
    straight.set_positions(sim.positions())
    times, tip = [], []
    while straight.time < 3.2 / expected:
        straight.step(5)  # samples every 10 ms, 360 a period
        times.append(straight.time)
        tip.append(straight.positions()[0, -1, 2])
    times, tip = np.array(times), np.array(tip)
    down = np.flatnonzero((tip[:-1] > 0) & (tip[1:] <= 0))  # downward zero crossings
    crossing = times[down] + (times[down + 1] - times[down]) * tip[down] / (tip[down] - tip[down + 1])
    measured = 1.0 / np.mean(np.diff(crossing))
    print(f"\nfirst frequency: measured {measured:.5f} Hz, beam theory {expected:.5f} Hz, "
          f"error {abs(measured / expected - 1):.2%}")
    assert len(crossing) >= 3
    assert abs(measured / expected - 1) < 0.003  # 30 segments of a 1 m beam, no clamp allowance


def test_unloaded_curly_strand_stays_put():
    groom = th.Groom.curly(length=0.3, n_nodes=48, curl_radius=0.01, curl_pitch=0.02)
    sim = quiet(lambda: th.Simulator(groom, th.Material(ellipticity=1.5), gravity=(0, 0, 0)))
    x0 = sim.positions()
    sim.run(1.0, progress=False)
    drift = np.abs(sim.positions() - x0).max()
    print(f"\nhelix drift after 1 s: {drift:.2e} m = {drift / 0.3:.2e} of its length")
    assert drift < 1e-6 * 0.3


def bent_beam_sim(**kwargs):
    material = th.Material(**BEAM)
    straight = quiet(lambda: th.Simulator(clamped_beam(20), material, dt=2e-3, twist="none", **kwargs))
    bent = clamped_beam(20, slope=lambda s: 0.3 * first_mode_slope(s, LENGTH))
    straight.set_positions(bent.positions)
    return straight


@pytest.mark.parametrize("gravity", [(0.0, 0.0, 0.0), (0.0, 0.0, -9.81)])
def test_energy_does_not_grow_without_drag(gravity):
    sim = bent_beam_sim(gravity=gravity)
    e0 = sim.total_energy()
    scale = sim.elastic_energy()
    energies, kinetic = [], []
    for _ in range(300):
        sim.step(5)
        energies.append(sim.total_energy())
        kinetic.append(sim.kinetic_energy())
    energies = np.array(energies)
    # symplectic Euler's energy oscillates by O(h omega) about a conserved value; projection
    # can only remove energy. So: bounded oscillation, and no upward trend over 3 s.
    growth = (energies.max() - e0) / scale
    trend = (energies[-100:].mean() - energies[:100].mean()) / scale
    print(f"\nmax energy excursion / initial elastic energy: {growth:.2e}; trend {trend:.2e}; "
          f"final loss {(e0 - energies[-1]) / scale:.2e}")
    assert max(kinetic) > 0.1 * scale  # it moved: elastic energy turned into kinetic
    assert growth < 5e-3
    assert trend < 1e-4


def test_energy_decays_with_drag():
    sim = bent_beam_sim(gravity=(0.0, 0.0, 0.0), drag=0.2)
    energies = [sim.total_energy()]
    for _ in range(100):
        sim.step(10)
        energies.append(sim.total_energy())
    energies = np.array(energies)
    assert np.all(np.diff(energies) <= 1e-9 * energies[0])
    assert energies[-1] < 0.5 * energies[0]


def shaking_head(t):
    angle = np.radians(40) * np.sin(2 * np.pi * 3.0 * t)
    return rotation_matrix([0, 0, 1], angle), np.array([0.02 * np.sin(2 * np.pi * 2.0 * t), 0, 0])


def test_constraints_hold_and_roots_follow_a_moving_head():
    roots = np.array([[0.05, 0.0, 0.0], [0.0, 0.05, 0.0], [-0.05, 0.0, 0.0]])
    groom = th.Groom.concatenate([
        th.Groom.straight(roots=roots[:1], directions=[[1, 0, -0.3]], length=0.25, n_nodes=26),
        th.Groom.wavy(roots=roots[1:2], directions=[[0, 1, -0.3]], length=0.2, n_nodes=21),
        th.Groom.curly(roots=roots[2:], directions=[[-1, 0, -0.3]], length=0.2, n_nodes=30)])
    sim = quiet(lambda: th.Simulator(groom, th.Material(ellipticity=1.3), root_motion=shaking_head,
                                     drag=1e-5))
    rest = groom.positions
    rest_len = [np.linalg.norm(np.diff(groom.strand(s), axis=0), axis=1) for s in range(3)]
    worst = 0.0
    for _ in range(40):
        sim.step(5)
        stats = sim.stats(reset=True)
        x = sim.positions()
        rotation, translation = shaking_head(sim.time)
        assert np.abs(x[:, 0] - (rest[:, 0] @ rotation.T + translation)).max() < 1e-12  # the clamped root node
        for s in range(3):
            n = groom.node_counts[s]
            lengths = np.linalg.norm(np.diff(x[s, :n], axis=0), axis=1)
            worst = max(worst, np.abs(lengths**2 / rest_len[s] ** 2 - 1).max())
        if stats["projection_cap_hits"] == 0 and stats["projection_stalls"] == 0:
            assert stats["projection_residual_max"] < stats["projection_tol"]
            assert worst < stats["projection_tol"]
    print(f"\nworst relative constraint residual seen: {worst:.2e}")
    assert worst < sim.plan.projection_tol


def test_fused_and_staged_drivers_agree():
    groom = th.Groom.curly(length=0.15, n_nodes=24, curl_radius=0.01, curl_pitch=0.02)
    results = []
    for staged in (False, True):
        sim = quiet(lambda: th.Simulator(groom, th.Material(ellipticity=1.4), twist="quasistatic",
                                         root_motion=shaking_head, drag=1e-5))
        for _ in range(30):
            sim.step(1, timers=(lambda name: _NoTimer()) if staged else None)
        results.append(sim.positions())
    assert np.abs(results[0] - results[1]).max() < 1e-12
    assert np.abs(results[0] - groom.positions).max() > 1e-4  # it moved


class _NoTimer:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_step_past_the_bound_substeps_quietly_or_refuses():
    """Past the bound a step runs as substeps within it, without a warning (a default scene must
    not warn: substeps are the same work as the smaller dt); strict=True refuses."""
    groom = th.Groom.straight(length=0.1, n_nodes=51)  # 2 mm segments of human hair
    material = th.Material()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sim = th.Simulator(groom, material, dt=1e-3)
    assert sim.substeps > 1 and sim.dt / sim.substeps <= sim.stable_dt
    with pytest.raises(ValueError, match="stability bound"):
        th.Simulator(groom, material, dt=1e-3, strict=True)
    quick = th.Simulator(groom, material, dt=0.5 * sim.stable_dt, strict=True)
    assert quick.substeps == 1


def test_stiff_extreme_case_runs_without_nan():
    material = th.Material(youngs_modulus=10e9, shear_modulus=3.3e9, radius=20e-6)
    groom = th.Groom.wavy(length=0.1, n_nodes=51, amplitude=0.003, wavelength=0.02)
    sim = quiet(lambda: th.Simulator(groom, material, dt=1e-3, root_motion=shaking_head))
    sim.run(0.2, progress=False)
    assert np.all(np.isfinite(sim.positions())) and np.all(np.isfinite(sim.velocities()))
    print(f"\nstiff case: {sim.substeps} substeps of {sim.dt / sim.substeps:.2e} s, {sim.stats()}")


def test_blow_up_is_detected_and_rolled_back():
    groom = th.Groom.straight(length=0.1, n_nodes=11)
    sim = quiet(lambda: th.Simulator(groom, th.Material(), dt=1e-3, max_speed=50.0))
    sim.step(3)
    before = sim.positions()
    force = np.zeros_like(before)
    force[0, 7] = [1e3, 0.0, 0.0]  # kilonewtons on a hair: no time step survives this
    sim.set_user_forces(force)
    with pytest.raises(th.SimulationDiverged, match=r"step 4 .*strand 0.*likely cause") as info:
        sim.step(10)
    assert info.value.step == 4 and info.value.strand == 0
    assert np.array_equal(sim.positions(), before) and sim.steps_taken == 3
    assert np.all(np.isfinite(sim.velocities()))


# ---- projection stalls are reported as what they are -----------------------------------------

def test_projection_stalls_in_contact_are_finished_and_rounding_stalls_reported_with_their_bound():
    """float64. In contact: hair combed round a sphere and pressed on it by a 50 m/s wind (DER
    strain measure), where contacts pushing back against the edge lengths stall the
    alternation unless length-only iterations finish a projection in contact (without them: 546
    stalls in 100 steps, residual 1.0e-3 against tolerance 1e-6): no stall, every step within
    the tolerance (measured 1.0e-6). Without contacts, a tolerance below float64's rounding
    floor (1e-15; the floor is about 1e-14) stalls every step, and stats() says where a stall
    stops (projection_stall_below) with the residual under it, no iteration cap hit."""
    angle = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    roots = 0.1 * np.stack([0.5 * np.cos(angle), 0.5 * np.sin(angle), np.full(8, 0.75 ** 0.5)], axis=1)
    combed = np.cross(roots, [0.0, 0.0, 1.0]) + 0.05 * roots  # along the head, nearly tangent
    groom = th.Groom.straight(roots=roots, directions=combed, length=0.25, n_nodes=26)
    scene = th.Scene(groom=groom, head=th.Head.sphere(radius=0.1), wind=th.Wind(velocity=(50.0, 0, 0)),
                     drag=5e-4, strain="der")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sim = th.Simulator.from_scene(scene, dt=1e-3)
    sim.step(100)
    stats = sim.stats()
    assert stats["projection_stalls"] == 0 and stats["projection_cap_hits"] == 0
    assert stats["projection_residual_max"] <= stats["projection_tol"]

    strand = th.Groom.straight(roots=[[0, 0, 0]], directions=[[1, 0, 0]], length=0.3, n_nodes=31)
    sim = th.Simulator.from_scene(th.Scene(groom=strand), dt=1e-3, projection_tol=1e-15)
    sim.step(100)
    stats = sim.stats()
    assert stats["projection_stalls"] > 50 and stats["projection_cap_hits"] == 0
    assert stats["projection_tol"] < stats["projection_residual_max"] <= stats["projection_stall_below"] == STALL_BELOW


# ---- float32 positions far from the origin ---------------------------------------------------

def test_float32_hair_far_from_the_origin_moves_as_at_the_origin():
    """float32 positions 100 m from the origin carry rounding of 8e-6 m, 8e-4 of a 1 cm edge:
    the projection could not resolve the lengths there and stiff modes heat. Positions are
    float64 (arrays.Points2): the same swinging strand at the origin and 100 m away follows the
    same path to float32's precision of the motion itself, and holds its lengths to 1e-6."""
    script = textwrap.dedent("""
        import json, numpy as np, taichi_hair as th
        th.init(arch="cpu", precision="float32")
        tips, residuals = [], []
        for offset in (0.0, 100.0):
            groom = th.Groom.straight(roots=[[offset, 0.0, 0.0]], directions=[[1.0, 0.0, 0.0]],
                                      length=0.2, n_nodes=21)
            sim = th.Simulator(groom, th.Material(), dt=1e-3)
            sim.step(200)
            x = sim.positions()[0]
            tips.append((x[-1] - [offset, 0.0, 0.0]).tolist())
            lengths = np.linalg.norm(np.diff(x, axis=0), axis=1)
            residuals.append(float(np.abs(lengths ** 2 / 0.01 ** 2 - 1).max()))
            assert sim.stats()["projection_tol"] == 1e-6
        print(json.dumps({"tips": tips, "residuals": residuals}))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    near, far = np.array(result["tips"])
    print(f"\nfloat32 tip at the origin {near}, 100 m away {far} (relative), residuals {result['residuals']}")
    assert np.linalg.norm(near - far) < 1e-4 * 0.2
    assert max(result["residuals"]) < 2e-6
