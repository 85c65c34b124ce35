"""The implicit step (integrator="implicit"): its stiffness against central differences, its
block solver against a dense solve, and its dynamics against the explicit step's references:
the elastica cantilever, the hanging-chain pendulum's swing, a stiff case past the explicit
bound, and tight elliptic curls on a shaking head."""

import warnings
from dataclasses import replace

import numpy as np
import pytest
import taichi as ti

import taichi_hair as th
from taichi_hair.rods import arrays
from taichi_hair.rods.linalg import block_pentadiagonal_solve
from taichi_hair.solver.system import RodSystem
from helpers import force_jacobian
from taichi_hair.rods.references import cantilever_elastica_tip, cantilever_first_frequency
from test_pins import crossing_times, pendulum
from test_step import BEAM, LENGTH, clamped_beam

CURLY = dict(length=0.05, n_nodes=12, curl_radius=0.004, curl_pitch=0.01)


def stiffness_error(rods, x0, h=1e-7):
    """|K - (-df/dx)|max / |df/dx|max over strand 0's free nodes at positions x0 (central
    differences of step h [m])."""
    rods.set_positions(x0)
    rods.update_twist()
    free = list(np.flatnonzero(rods.model.inv_mass.to_numpy()[0] > 0))
    reference = force_jacobian(rods, x0, [(i, k) for i in free for k in range(3)], h)
    rows = (3 * np.array(free)[:, None] + np.arange(3)).ravel()
    stiffness = rods.bending_stiffness()[0][np.ix_(rows, rows)]
    return np.abs(stiffness - reference).max() / np.abs(reference).max(), stiffness


@pytest.mark.parametrize("ellipticity", [1.0, 4.0])
def test_stiffness_is_the_force_jacobian_at_straight_rest(ellipticity):
    rods = RodSystem(th.Groom.straight(length=0.05, n_nodes=8), th.Material(ellipticity=ellipticity),
                     integrator="implicit")
    error, _ = stiffness_error(rods, rods.positions())
    print(f"\nstraight rest, ellipticity {ellipticity}: |K - (-df/dx)| / |df/dx| = {error:.2e}")
    assert error < 1e-6


@pytest.mark.parametrize("root,strain", [("clamped", "der"), ("pinned", "der"), ("clamped", "rotation"),
                                         ("pinned", "rotation")])
def test_stiffness_is_the_force_jacobian_on_curled_elliptic_rest_shapes(root, strain):
    """The angles condensed out of the Gauss-Newton Hessian over positions and angles: at any
    rest shape it is the exact Jacobian of the forces at twist equilibrium (curls, elliptic
    sections, the twist-bending coupling included; a K without the angles is about 20 % off
    on tight elliptic curls). Both strain measures; the rotation measure's forces
    carry more rounding, so its differences take h = 1e-6 m (at 1e-7 their own asymmetry, which
    the exact Jacobian does not have, reaches 3.5e-7 on the tightest curl; at 1e-6 it is the
    differences' truncation, 9e-8)."""
    worst = 0.0
    for seed, ellipticity in enumerate([1.3, 1.7, 2.5, 4.0]):
        rng = np.random.default_rng(seed)
        radius = float(rng.uniform(0.003, 0.02))
        groom = th.Groom.curly(length=0.05, n_nodes=12, curl_radius=radius, curl_pitch=2.5 * radius,
                               phase=float(rng.uniform(0, 2 * np.pi)))
        rods = RodSystem(groom, th.Material(ellipticity=ellipticity), integrator="implicit", root=root,
                         strain=strain)
        error, stiffness = stiffness_error(rods, rods.positions(), 1e-6 if strain == "rotation" else 1e-7)
        print(f"\n{strain}, {root} curl radius {radius * 1e3:.1f} mm, ellipticity {ellipticity}: {error:.2e}")
        worst = max(worst, error)
        assert np.linalg.eigvalsh(stiffness).min() > -1e-9 * np.abs(stiffness).max()  # what the solve needs
    assert worst < 1e-6


def test_stiffness_leaves_out_only_a_term_proportional_to_the_strain():
    """Away from rest K is the Gauss-Newton part (positive semi-definite, as the solve needs):
    it misses the residual term (strain times the strains' second derivatives), so its error
    against the force Jacobian is proportional to the deformation."""
    rods = RodSystem(th.Groom.curly(**CURLY), th.Material(ellipticity=4.0), integrator="implicit")
    rest = rods.positions()
    noise = np.random.default_rng(1).standard_normal(rest.shape)
    noise[:, 0] = 0.0
    errors = []
    for amplitude in (1e-5, 1e-4):
        error, stiffness = stiffness_error(rods, rest + amplitude * noise)
        errors.append(error)
        assert np.linalg.eigvalsh(stiffness).min() > -1e-9 * np.abs(stiffness).max()
    print(f"\nnodes moved 10 / 100 um: |K - (-df/dx)| / |df/dx| = {errors[0]:.2e} / {errors[1]:.2e}")
    assert 0.05 < errors[0] / errors[1] < 0.2


@ti.kernel
def _solve(blocks: arrays.BlockMats3, rhs: arrays.BlockVecs2, n: int, failed: arrays.Ints1):
    for s in range(1):
        failed[s] = block_pentadiagonal_solve(s, n, blocks, rhs)


def block_system(matrix, n):
    size = arrays.BLOCK
    blocks = np.zeros((1, n, 3, size, size))
    for i in range(n):
        for k in range(3):
            if i - k >= 0:
                blocks[0, i, k] = matrix[size * i:size * i + size, size * (i - k):size * (i - k) + size]
    out = arrays.matrices(size, (1, n, 3), ti.f64)
    out.from_numpy(blocks)
    return out


def test_block_solver_matches_a_dense_solve_and_refuses_a_singular_matrix():
    """An indefinite saddle-point-like system: SPD velocity and angle blocks, zero multiplier
    diagonals."""
    n, size = 9, arrays.BLOCK
    rng = np.random.default_rng(0)
    matrix = np.zeros((size * n, size * n))
    for i in range(n):
        for j in range(max(0, i - 2), i + 1):
            matrix[size * i:size * i + size, size * j:size * j + size] = rng.standard_normal((size, size))
    matrix = matrix + matrix.T
    for i in range(n):
        matrix[size * i:size * i + 3, size * i:size * i + 3] += 30 * np.eye(3)
        matrix[size * i + 3, size * i + 3] = 0.0
        matrix[size * i + 4, size * i + 4] += 30.0
    b = rng.standard_normal(size * n)
    rhs = arrays.vectors(size, (1, n), b.reshape(1, n, size), dtype=ti.f64)
    failed = arrays.ints((1,), 0)
    _solve(block_system(matrix, n), rhs, n, failed)
    tol = 1e-10  # the solver works in float64 in both precisions
    expected = np.linalg.solve(matrix, b)
    assert failed.to_numpy()[0] == 0
    assert np.abs(rhs.to_numpy().ravel() - expected).max() < tol * np.abs(expected).max()
    for singular in (slice(0, 4), slice(4, 5)):  # the pivot's leading part, then its angle
        broken = matrix.copy()
        broken[singular, :] = 0.0
        broken[:, singular] = 0.0
        _solve(block_system(broken, n), rhs, n, failed)
        assert failed.to_numpy()[0] == 1


def long_chain_saddle_system(n=201, segment=1e-3, dt=1e-3, bend=3e-6):
    """The implicit step's matrix, assembled here in numpy, for a horizontal human hair of n
    nodes `segment` [m] apart, its tip bent down by `bend` [m] (a cubic): position blocks
    M + hh^2 K, angle blocks hh^2 K (K over positions and angles from the simulator, checked
    elsewhere), each edge's length row m_i t . (v_i - v_{i-1}) stored with its far node, the
    root held (identity rows, as is the clamp's angle slot)."""
    groom = th.Groom.straight(length=segment * (n - 1), n_nodes=n, directions=[[1.0, 0.0, 0.0]])
    rods = RodSystem(groom, th.Material(), integrator="implicit")
    x = rods.positions()
    s = (x[0, :, 0] - x[0, 0, 0]) / (x[0, -1, 0] - x[0, 0, 0])
    x[0, :, 1] -= bend * s ** 2 * (3 - s)
    rods.set_positions(x)
    hh = 2 * dt / 3
    mass = rods.model.mass.to_numpy()[0].astype(np.float64)
    size = arrays.BLOCK
    matrix = hh * hh * rods.bending_stiffness(condensed=False)[0]
    for i in range(n):
        matrix[size * i:size * i + 3, size * i:size * i + 3] += mass[i] * np.eye(3)
    matrix[:3, :] = matrix[:, :3] = 0.0
    matrix[:3, :3] = np.eye(3)
    matrix[3, 3] = mass[0]
    matrix[4, 4] = 1.0
    for i in range(1, n):
        e = x[0, i] - x[0, i - 1]
        t = mass[i] * e / np.linalg.norm(e)
        matrix[size * i + 3, size * i:size * i + 3] = matrix[size * i:size * i + 3, size * i + 3] = t
        if i > 1:
            matrix[size * i + 3, size * i - size:size * i - size + 3] = t * -1
            matrix[size * i - size:size * i - size + 3, size * i + 3] = t * -1
    return matrix


def test_block_solver_stays_accurate_on_a_long_fine_bent_chain():
    """201 nodes at 1 mm, bent by 3 um: rounding left the pivots slightly asymmetric and the
    one-sided recurrence amplified that along the chain (|L| 6e9 by node 120, solution off by
    1e21); symmetrised pivots keep it at a dense solve's accuracy."""
    n = 201
    matrix = long_chain_saddle_system(n)
    b = np.random.default_rng(2).standard_normal(arrays.BLOCK * n) * np.tile([1e-9, 1e-9, 1e-9, 1e-17, 1e-12], n)
    rhs = arrays.vectors(arrays.BLOCK, (1, n), b.reshape(1, n, arrays.BLOCK), dtype=ti.f64)
    failed = arrays.ints((1,), 0)
    _solve(block_system(matrix, n), rhs, n, failed)
    expected = np.linalg.solve(matrix, b)
    error = np.abs(rhs.to_numpy().ravel() - expected).max() / np.abs(expected).max()
    print(f"\nlong bent chain: block solve against dense, relative {error:.1e}")
    assert failed.to_numpy()[0] == 0
    assert error < 1e-8


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
@pytest.mark.parametrize("n_nodes, segment", [(201, 1e-3), (101, 4e-4)])
def test_long_fine_strand_falls_with_the_implicit_step(n_nodes, segment):
    """The two cases that failed at their first step fall for 0.1 s as the explicit step has
    them fall (substepped under its bound), lengths held, never gaining energy (no drag)."""
    groom = th.Groom.straight(length=segment * (n_nodes - 1), n_nodes=n_nodes, directions=[[1.0, 0.0, 0.0]])
    tips = {}
    for integrator in ("implicit", "explicit"):
        sim = th.Simulator(groom, th.Material(), dt=1e-3, integrator=integrator, drag=0.0)
        start = highest = sim.total_energy()
        tips[integrator] = []
        for _ in range(20):
            sim.step(5)
            highest = max(highest, sim.total_energy())
            tips[integrator].append(sim.positions()[0, -1])
        if integrator == "implicit":
            assert highest <= start + 1e-9 * abs(start)
            assert sim.stats()["projection_residual_max"] <= sim.stats()["projection_tol"]
    implicit, explicit = np.array(tips["implicit"]), np.array(tips["explicit"])
    drop = (groom.positions[0][-1][2] - explicit[:, 2]).max()  # gravity is -z
    error = np.linalg.norm(implicit - explicit, axis=1).max() / drop
    print(f"\n{n_nodes} nodes at {segment * 1e3:g} mm: largest tip drop {drop * 1e3:.2f} mm, implicit "
          f"tip off the explicit one by at most {error:.1e} of it (every 5 ms for 0.1 s)")
    assert error < 0.05


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
@pytest.mark.parametrize("stiffness", [10.0, 1000.0])
def test_stiff_grab_swings_a_strand_under_the_implicit_step(stiffness):
    """A grab (radius 4 mm: one node, 5 mm segments) takes a hanging strand's middle node round
    the root at 0.5 m/s, at dt 1 ms: its spring is far past the explicit bound (omega h ~ 17-170
    on a 3.3e-8 kg node), so the implicit step holds its stiffness in the matrix. The strand
    swings as the explicit step, substepped under its bound, swings it: the grabbed node's
    path within 1 mm of it, and within 4 mm of the grab."""
    groom = th.Groom.straight(length=0.1, n_nodes=21, directions=[[0.0, 0.0, -1.0]])
    reach = np.linalg.norm(groom.positions[0, 10] - groom.positions[0, 0])

    def path(t):
        angle = 10.0 * t
        return groom.positions[0, 0] + reach * np.array([np.sin(angle), 0.0, -np.cos(angle)])

    grab = th.Grab(path=path, radius=0.004, stiffness=stiffness)
    paths = {}
    for integrator in ("implicit", "explicit"):
        sim = th.Simulator(groom, th.Material(), dt=1e-3, integrator=integrator, touch=[grab], drag=1e-4)
        if integrator == "implicit":
            assert sim.substeps == 1
        paths[integrator] = []
        for _ in range(20):
            sim.step(5)
            paths[integrator].append(sim.positions()[0, 10])
    implicit, explicit = np.array(paths["implicit"]), np.array(paths["explicit"])
    error = np.linalg.norm(implicit - explicit, axis=1).max()
    lag = max(np.linalg.norm(x - path(5e-3 * (k + 1))) for k, x in enumerate(implicit))
    print(f"\ngrab {stiffness:g} N/m: implicit path off the explicit one by at most {error * 1e3:.2f} mm, "
          f"{lag * 1e3:.2f} mm from the grab")
    assert error < 1e-3
    assert lag < 4e-3


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_real_hair_cantilever_first_mode_at_one_millisecond():
    """A human hair (10 cm, 40 segments, no gravity, no damping set) started in its first mode:
    frequency within 0.5 % of the beam formula at dt = 1 ms and, as the step's only damping,
    under 1e-3 of the amplitude lost per period; at 16 ms it damps more than at 1 ms."""
    from taichi_hair.app.implicit_report import cantilever_row
    fine, coarse = cantilever_row(1e-3, "implicit"), cantilever_row(16e-3, "implicit")
    print(f"\ncantilever at 1 ms: f / f_beam - 1 = {fine['frequency_error']:+.2e}, amplitude lost per period "
          f"{fine['loss_per_period']:.1e}; at 16 ms: {coarse['frequency_error']:+.2e}, {coarse['loss_per_period']:.1e}")
    assert abs(fine["frequency_error"]) < 5e-3
    assert abs(fine["loss_per_period"]) < 1e-3
    assert coarse["loss_per_period"] > 10 * abs(fine["loss_per_period"])


def test_stiff_fine_strands_at_a_large_step_never_gain_energy():
    """Four 1 mm-segment strands with E = 1e11 swinging down at dt = 20 ms (the stability
    matrix's case): one length correction left edges ~3e-5 off, the fast projection took that
    up as a kink and the energy rose by 3.5 % of the energy in play; corrections repeat until
    the edges are within CORRECTION_TOL. Judged by the stability report's own energy rule."""
    from taichi_hair.app import stability_cases, stability_report
    case = stability_cases.StabilityCase(name="stiff fine, 20 ms", youngs_modulus=1e11, segment=1e-3, dt=2e-2,
                                 integrator="implicit")
    row = stability_report.run_stability_case(case, 0.2)
    print(f"\nE 1e11, 1 mm, dt 20 ms, implicit: {row['outcome']}, energy rise "
          f"{row['energy_max_rise']:.2e} of the energy in play")
    assert row["status"] == "stable"
    assert row["energy_max_rise"] <= 1e-3


def test_tight_curls_resting_on_a_head_never_gain_energy():
    """5 mm curls at 2.5 mm segments draped over a sphere head, undamped (the stability matrix's
    "head, curl 5 mm"): with the contacts left to the fast projection after the solve, the push
    out of the head kinked the stiff curls in the metric M and the energy rose by 0.74 of the
    energy in play in 0.2 s (or the step diverged); the length correction now takes the contacts
    as springs in the step's own metric. Judged by the stability report's own energy rule."""
    from taichi_hair.app import stability_cases, stability_report
    case = next(c for c in stability_cases.stability_cases(False) if c.name == "head, curl 5 mm")
    row = stability_report.run_stability_case(replace(case, integrator="implicit"), 0.2)
    print(f"\ncurls on a head, implicit: {row['outcome']}, energy rise {row['energy_max_rise']:.2e} of "
          f"the energy in play, deepest node {row['penetration']:.3f} margins")
    assert row["status"] == "stable"
    assert row["energy_max_rise"] <= 1e-3
    assert row["penetration"] <= 1.0


def test_kmoch_twist_on_elliptic_strands_is_refused_by_the_implicit_step():
    """Kmoch's rule on elliptic strands puts twist forces stiffer than bending outside the
    implicit matrix (every such stability case diverged or gained energy): refused with a
    message naming both; round strands solve their twist exactly under the rule and run."""
    groom = th.Groom.curly(**CURLY)
    with pytest.raises(ValueError, match="twist='kmoch' on elliptic strands.*integrator='explicit'"):
        th.Simulator(groom, [th.Material(), th.Material(ellipticity=1.5)][1], twist="kmoch", integrator="implicit")
    with pytest.raises(ValueError, match="twist='kmoch'"):
        th.Simulator(th.Groom.concatenate([groom, groom]), [th.Material(), th.Material(ellipticity=1.5)],
                     twist="kmoch", integrator="implicit")
    th.Simulator(groom, th.Material(), twist="kmoch", integrator="implicit")


def test_frozen_angles_on_elliptic_strands_are_refused_by_the_implicit_step():
    """twist="none" on elliptic strands: the implicit matrix has no angle columns (the stability
    matrix's elliptic twist="none" curls gained all their energy or diverged), so refused with a
    message naming the mode, the strands and the integrator that runs them; round strands with
    frozen angles run (the implicit cantilever above)."""
    groom = th.Groom.curly(**CURLY)
    with pytest.raises(ValueError, match="twist='none' on elliptic strands.*integrator='explicit'"):
        th.Simulator(groom, th.Material(ellipticity=1.5), twist="none", integrator="implicit")
    th.Simulator(groom, th.Material(), twist="none", integrator="implicit")
    th.Simulator(groom, th.Material(ellipticity=1.5), twist="none", integrator="explicit")


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_implicit_cantilever_settles_on_the_elastica_at_large_steps():
    material = th.Material(**BEAM)
    ei, rho_a = material.bending_stiffness[0], material.linear_density
    omega1 = 2 * np.pi * cantilever_first_frequency(LENGTH, ei, rho_a)
    reference = cantilever_elastica_tip(LENGTH, rho_a * 9.81, ei)
    errors = {}
    for dt in (1e-3, 1e-2):
        sim = th.Simulator(clamped_beam(50), material, dt=dt, drag=2 * rho_a * omega1, twist="none",
                           integrator="implicit")
        assert sim.substeps == 1
        sim.run(8.0, progress=False)
        assert sim.kinetic_energy() < 1e-8 * sim.elastic_energy(), "not at rest yet"
        errors[dt] = np.linalg.norm(sim.positions()[0, -1][[0, 2]] - reference) / LENGTH
    print("\nimplicit cantilever tip error / L:", {dt: f"{e:.2e}" for dt, e in errors.items()})
    assert max(errors.values()) < 0.001  # the explicit step's bound at 50 segments (test_step)


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_implicit_pendulum_keeps_its_swing_and_period():
    sim, period = pendulum(integrator="implicit")
    times, tip = [], []
    while sim.time < 6 * period:
        sim.step(2)
        times.append(sim.time)
        tip.append(sim.positions()[0, -1, 0])
    times, tip = np.array(times), np.array(tip)
    crossings = crossing_times(times, tip)
    measured = np.mean(np.diff(crossings))
    first, last = np.abs(tip[times < period]).max(), np.abs(tip[times > 5 * period]).max()
    change = last / first - 1
    print(f"\nimplicit pendulum: period {measured:.5f} s (chain {period:.5f} s), amplitude change over "
          f"5 periods {change:.2e}")
    assert abs(measured / period - 1) < 0.005
    assert abs(change) < 1e-3  # the explicit step loses about 4 % of its swing here


@pytest.mark.parametrize("dt", [1e-3, 2e-2])
def test_falling_stiff_hair_never_gains_energy(dt):
    """Undamped, undriven: a horizontal human hair swings down and whips. The implicit step's
    only loss is its own numerical damping (BDF2's, growing with dt); it must never add energy
    (without the constraints' geometric stiffness it gained 3 % at 1 ms)."""
    n = 21
    groom = th.Groom.from_polylines(np.stack([np.linspace(0, 0.2, n), np.zeros(n), np.zeros(n)], axis=1))
    sim = th.Simulator(groom, th.Material(youngs_modulus=3e9, radius=40e-6), dt=dt, twist="none",
                       integrator="implicit")
    start = sim.total_energy()
    drift, in_play = [], []
    for _ in range(int(round(0.3 / dt))):
        sim.step(1)
        drift.append(sim.total_energy() - start)
        in_play.append(sim.kinetic_energy() + sim.elastic_energy())
    drift = np.array(drift) / max(in_play)
    print(f"\nfalling hair, dt {dt}: energy drift max {drift.max():.1e}, end {drift[-1]:.1e} of the energy in play")
    assert drift.max() < 1e-3
    if dt == 1e-3:
        assert abs(drift[-1]) < 1e-3  # the explicit step loses 3 % here


def test_stiff_strand_runs_one_step_past_the_explicit_bound():
    groom = th.Groom.straight(length=0.04, n_nodes=21)  # 2 mm segments
    material = th.Material(youngs_modulus=1e10, radius=1e-4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        explicit = th.Simulator(groom, material, dt=2e-3)
    implicit = th.Simulator(groom, material, dt=2e-3, integrator="implicit")
    assert explicit.substeps > 50 and implicit.substeps == 1
    energies = []
    for _ in range(50):
        implicit.step(1)
        energies.append(implicit.total_energy())
    x = implicit.positions()[0]
    strain = np.abs(np.linalg.norm(np.diff(x, axis=0), axis=1) / 0.002 - 1).max()
    assert np.all(np.isfinite(x)) and strain < 1e-4
    # no damping but the step's own: the energy never rises above its start
    assert max(energies) <= energies[0] + 1e-9 * abs(energies[0])


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_tight_elliptic_curls_on_a_shaking_head_stay_out_of_it():
    radius = 0.1
    roots = radius * np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [-0.6, 0.0, 0.8]])
    groom = th.Groom.curly(roots, roots / radius, length=0.12, n_nodes=40, curl_radius=0.004,
                           curl_pitch=0.008)

    def shake(t):
        return rotation_about_z(0.6 * np.sin(2 * np.pi * 3.0 * t)), np.zeros(3)

    sim = th.Simulator(groom, th.Material(ellipticity=4.0), dt=1e-3, drag=5e-4, root_motion=shake,
                       colliders=[th.Sphere(radius=radius, margin=1e-3)],
                       integrator="implicit")
    assert sim.substeps == 1
    deepest = np.inf
    for _ in range(20):
        sim.step(10)
        x = sim.positions()
        deepest = min(deepest, (np.linalg.norm(x[:, 1:], axis=2) - radius).min())
    edges = np.linalg.norm(np.diff(sim.positions(), axis=1), axis=2)
    rest = sim.model.rest_length.to_numpy()
    strain = np.abs(edges / rest - 1).max()
    print(f"\nshaking curls: deepest node {deepest * 1e3:.3f} mm outside the head, strain {strain:.1e}")
    assert deepest > -1e-4 and strain < 1e-4


def rotation_about_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_integrator_is_checked_and_the_implicit_stage_compiles_only_when_chosen():
    with pytest.raises(ValueError, match="integrator must be one of"):
        th.Simulator(th.Groom.straight(), th.Material(), integrator="rk4")
    from taichi_hair.solver.step.fused import compiled_variants
    sim = th.Simulator(th.Groom.straight(n_nodes=8), th.Material())
    sim.step(2)
    assert any(not v["implicit"] for v in compiled_variants())
    with pytest.raises(ValueError, match="integrator"):
        sim.rods.bending_stiffness()
