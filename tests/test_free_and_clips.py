"""Free strands (root="free"), clips that hold twist (hold_twist, turn_pin) and sliders
(slide): forces against central differences of the energy, conserved momentum, the twist a
turned clip puts in, a slider's motion against rigid-body mechanics, the twist at which a rod
between a clamp and a slider buckles against Greenhill's, and bad input."""

import warnings

import numpy as np
import pytest

import taichi_hair as th

from helpers import force_jacobian
from taichi_hair.rods.references import greenhill_critical_moment

CURLY_ELLIPTIC = th.Material(youngs_modulus=3e9, shear_modulus=1e9, radius=5e-5, density=1300.0,
                             ellipticity=4.0)
ROUND = th.Material(youngs_modulus=1e6, shear_modulus=1e6 / 3, radius=0.002, density=1000.0)


def curl(n=16):
    """A tight curl: 5 mm radius, 1 cm pitch, 6 cm of hair."""
    return th.Groom.curly(length=0.06, n_nodes=n, curl_radius=0.005, curl_pitch=0.01)


def straight(n=21, length=0.2):
    x = np.stack([np.linspace(0.0, length, n), np.zeros(n), np.zeros(n)], axis=1)
    return th.Groom.from_polylines(x[None])


def simulator(groom, material, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # substepping notices
        return th.Simulator(groom, material, **options)


def minimised_energy(sim, x):
    """E(x) with every free angle at its twist equilibrium (clips holding theirs)."""
    sim.set_positions(x)
    sim.update_twist()
    return sim.elastic_energy()


def central_difference_error(sim, movable, eps=1e-7, seed=0):
    """max |F + dE/dx| / max |dE/dx| over the movable nodes of strand 0, at a random perturbation
    of the current shape (E minimised over the free angles: the force must be its gradient)."""
    x = sim.positions().copy()
    x[0, movable] += np.random.default_rng(seed).normal(scale=3e-4, size=(len(movable), 3))
    minimised_energy(sim, x)
    force = sim.elastic_forces()
    worst = scale = 0.0
    for i in movable:
        for a in range(3):
            plus, minus = x.copy(), x.copy()
            plus[0, i, a] += eps
            minus[0, i, a] -= eps
            gradient = (minimised_energy(sim, plus) - minimised_energy(sim, minus)) / (2 * eps)
            worst = max(worst, abs(force[0, i, a] + gradient))
            scale = max(scale, abs(gradient))
    return worst / scale


def test_free_root_forces_are_the_energy_gradient_on_a_tight_elliptic_curl():
    sim = simulator(curl(), CURLY_ELLIPTIC, root="free", gravity=(0, 0, 0))
    assert central_difference_error(sim, list(range(16))) < 1e-6


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_clip_holding_twist_forces_include_its_holonomy_term():
    """With a clip holding edge 8's material frame in space (turned by 1 rad), the energy's
    gradient has the term dE/dtheta^8 grad Psi^8; without it the check fails by ~30 %."""
    sim = simulator(curl(), CURLY_ELLIPTIC, gravity=(0, 0, 0))
    pid = sim.add_pin(0, 8, clamp=True, hold_twist=True)
    sim.turn_pin(pid, 1.0)
    sim.step(1)
    free_nodes = [1, 2, 3, 4, 5, 6, 7, 10, 11, 12, 13, 14, 15]
    assert central_difference_error(sim, free_nodes) < 1e-6
    with_term = sim.elastic_forces()
    without = sim.rods.elastic_forces()
    assert np.abs(with_term - without).max() > 0.1 * np.abs(with_term).max()


def test_free_curly_elliptic_strand_conserves_momentum_and_keeps_its_lengths():
    """No gravity, no drag, a bent curl released: internal forces and the projection move the
    centre of mass not at all, and the lengths hold."""
    groom = curl()
    sim = simulator(groom, CURLY_ELLIPTIC, root="free", gravity=(0, 0, 0), dt=1e-4)
    x = sim.positions().copy()
    x[0, :, 2] *= 1.3  # stretch the helix's pitch: elastic forces act, lengths projected back
    sim.set_positions(x)
    sim.step(1)
    mass = sim.model.mass.to_numpy()[0]
    centre = (mass[:, None] * sim.positions()[0]).sum(0) / mass.sum()
    for _ in range(20):
        sim.step(5)
    momentum = (mass[:, None] * sim.velocities()[0]).sum(0)
    speed_scale = np.abs(sim.velocities()[0]).max()
    assert speed_scale > 1e-3  # it does move
    assert np.abs(momentum).max() < 1e-9 * mass.sum() * speed_scale
    moved = (mass[:, None] * sim.positions()[0]).sum(0) / mass.sum() - centre
    assert np.abs(moved).max() < 1e-9
    lengths = np.linalg.norm(np.diff(sim.positions()[0], axis=0), axis=1)
    rest = np.linalg.norm(np.diff(groom.strand(0), axis=0), axis=1)
    assert np.abs(lengths / rest - 1).max() < 1e-6


def test_free_strand_falls_as_a_rigid_body():
    """Under gravity alone a free curl keeps its shape (every node falls alike: symplectic Euler's
    z = -g h^2 k (k + 1) / 2 after k steps) and its twist solve stays at rest."""
    groom = curl()
    sim = simulator(groom, CURLY_ELLIPTIC, root="free", dt=1e-4)
    h = sim.dt / sim.substeps
    sim.step(50)
    k = 50 * sim.substeps
    drop = sim.positions()[0] - groom.strand(0)
    assert np.allclose(drop[:, :2], 0.0, atol=1e-12)
    assert np.allclose(drop[:, 2], -9.81 * h * h * k * (k + 1) / 2, rtol=1e-9)
    assert sim.elastic_energy() < 1e-12 * sim.total_energy() + 1e-18


def twist_angles(positions, directors):
    """Twist at each interior node [rad]: the turn of d1 from one edge to the next about the
    tangent beyond what parallel transport across the bend carries (cosseratbench's measure)."""
    t = np.diff(positions, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    out = []
    for j in range(len(t) - 1):
        axis = np.cross(t[j], t[j + 1])
        sin, cos = np.linalg.norm(axis), t[j] @ t[j + 1]
        d = directors[j]
        if sin > 1e-12:
            axis /= sin
            d = d * cos + np.cross(axis, d) * sin + axis * (axis @ d) * (1 - cos)
        out.append(np.arctan2(np.cross(d, directors[j + 1]) @ t[j + 1], d @ directors[j + 1]))
    return np.array(out)


@pytest.mark.parametrize("turns", [1.0, -2.0])
def test_clip_turned_through_full_turns_twists_the_strand_that_much(turns):
    sim = simulator(straight(), ROUND, gravity=(0, 0, 0))
    clamp_director = sim.frames()["m1"][0, 0].copy()  # the root clamp's frame: theta^0 = 0 at rest
    pid = sim.add_pin(0, -2, clamp=True, hold_twist=True)
    for k in range(1, 9):  # in eighths: the clip's drive is interpolated over each step call
        sim.turn_pin(pid, 2 * np.pi * turns * k / 8)
        sim.step(5)
    x = sim.positions()[0]
    # the clamp as an edge before edge 0, along it: node 0 twists between the clamp and edge 0
    x = np.vstack([2 * x[0] - x[1], x])
    directors = np.vstack([clamp_director, sim.frames()["m1"][0]])
    total = twist_angles(x, directors).sum()
    assert abs(total - 2 * np.pi * turns) < 1e-9
    assert sim.pins()[0]["angle"] == pytest.approx(2 * np.pi * turns)


def test_clip_with_elliptic_curl_holds_twist_against_the_root_clamp():
    """Tight elliptic curl, clip on the last edge turned by pi: the free angles reach twist
    equilibrium (dE/dtheta = 0 on free edges) and the held edge sits at the clip's angle."""
    sim = simulator(curl(), CURLY_ELLIPTIC, gravity=(0, 0, 0), dt=1e-4)
    pid = sim.add_pin(0, -2, clamp=True, hold_twist=True)
    m1_before = sim.frames()["m1"][0, -1].copy()
    sim.turn_pin(pid, np.pi)
    sim.step(4)
    gradient = sim.theta_gradient()[0]
    assert np.abs(gradient[:-1]).max() < 1e-9 * np.abs(gradient).max() + 1e-15
    assert np.abs(gradient[-1]) > 0  # the clip carries the torque
    m1_after = sim.frames()["m1"][0, -1]
    assert m1_after @ m1_before == pytest.approx(-1.0, abs=1e-9)


@pytest.mark.parametrize("strain", ["rotation", "der"])
def test_twisted_rod_between_clamp_and_slider_buckles_at_greenhills_twist(strain):
    """cosseratbench's twist rod (1 m, radius 1 cm, G = E / 3, tension tau = T L^2 / B = 10,
    40 elements; measured 0.9977 of Greenhill's twist with the rotation measure, 1.0015 with
    DER's, which cosseratbench runs):
    clamped root, a clip on the last edge that holds its frame and slides along the axis. Its
    straight shape is stable until the smallest eigenvalue of the stiffness (bending, the clip's
    holonomy term, the tension's string stiffness) reaches zero; that twist is within 0.5 % of
    Greenhill's (references.greenhill_critical_moment). The elastic stiffness is the central
    difference of the forces (the energy's gradient, checked above) at the straight twisted rod;
    the twist part is linear in the twist, so two twists give the threshold's eigenproblem."""
    n, length, tau = 40, 1.0, 10.0
    material = th.Material(youngs_modulus=1e6, shear_modulus=1e6 / 3, radius=0.01, density=1000.0)
    bending = material.youngs_modulus * np.pi * material.radius ** 4 / 4
    critical = greenhill_critical_moment(tau) * bending / (2 * material.shear_modulus * np.pi
                                                           * material.radius ** 4 / 4)
    sim = simulator(straight(n + 1, length), material, gravity=(0, 0, 0), dt=1e-6, strain=strain)
    pid = sim.add_pin(0, -2, clamp=True, hold_twist=True, slide=(1.0, 0.0, 0.0))
    rest = sim.positions().copy()
    free = [(i, a) for a in (1, 2) for i in range(1, n - 1)]  # across the axis; the ends are held

    def stiffness(twist):
        for k in range(1, 33):  # in steps under pi: the held angle follows its nearest branch
            sim.turn_pin(pid, twist * k / 32)
            sim.step(1)
        jacobian = force_jacobian(sim, rest, free)
        return 0.5 * (jacobian + jacobian.T)

    untwisted = stiffness(0.0)
    twisted = stiffness(critical) - untwisted
    tension = tau * bending / length ** 2
    string = np.zeros_like(untwisted)  # T / l on the two sideways offsets each edge joins
    index = {dof: row for row, dof in enumerate(free)}
    for e in range(n):  # edge e joins nodes e and e + 1
        for a in (1, 2):
            for i, si in ((e, 1.0), (e + 1, -1.0)):
                for j, sj in ((e, 1.0), (e + 1, -1.0)):
                    if (i, a) in index and (j, a) in index:
                        string[index[i, a], index[j, a]] += si * sj * tension / (length / n)
    stable = untwisted + string
    cholesky = np.linalg.cholesky(stable)
    inverse = np.linalg.inv(cholesky)
    growth = np.linalg.eigvalsh(-inverse @ twisted @ inverse.T)
    threshold = 1.0 / growth.max()  # smallest twist fraction at which stable + s twisted is singular
    assert abs(threshold - 1.0) < 5e-3


def test_slider_pulls_a_free_strand_as_one_rigid_body():
    """A free straight strand whose last edge slides along its own axis, pulled along it by F at
    the tip: everything accelerates at F / M (lengths hold, the slider drags the rest through
    the constraints); pushed across the axis, nothing moves."""
    groom = straight(11, 0.1)
    sim = simulator(groom, ROUND, root="free", gravity=(0, 0, 0), dt=1e-3)
    sim.add_pin(0, -2, clamp=True, slide=True)
    force = np.zeros((1, 11, 3))
    force[0, -1] = (1e-3, 0.0, 0.0)
    sim.set_user_forces(force)
    steps = 100
    sim.step(steps)
    mass = sim.model.mass.to_numpy()[0].sum()
    h = sim.dt / sim.substeps
    k = steps * sim.substeps
    expected = force[0, -1, 0] / mass * h * h * k * (k + 1) / 2  # symplectic Euler's sum
    shift = sim.positions()[0] - groom.strand(0)
    assert np.allclose(shift[:, 0], expected, rtol=1e-6)
    assert np.abs(shift[:, 1:]).max() < 1e-12
    force[0, -1] = (0.0, 1e-3, 0.0)
    sim.set_user_forces(force)
    before = sim.positions().copy()
    v_along = sim.velocities()[0, -1, 0]
    sim.step(10)
    after = sim.positions()
    assert np.abs(after[0, :, 1:] - before[0, :, 1:]).max() < 1e-12  # held across its axis
    assert np.allclose(after[0, :, 0] - before[0, :, 0], v_along * 10 * sim.dt, rtol=1e-6)


def test_slider_under_compression_buckles_and_slides_in():
    """Clamped root, slider tip along the axis, pushed with 4x the Euler load of a clamped-
    clamped rod (4 pi^2 EI / L^2): the strand bows out and the slider moves in."""
    groom = straight(21, 0.2)
    x = groom.positions.copy()
    x[0, :, 1] = 1e-4 * np.sin(np.pi * np.linspace(0, 1, 21))  # a seed for the buckle
    groom = th.Groom.from_polylines(x)
    sim = simulator(groom, ROUND, gravity=(0, 0, 0), drag=0.05, dt=1e-3)
    sim.add_pin(0, -2, clamp=True, slide=(1.0, 0.0, 0.0))
    ei = ROUND.youngs_modulus * np.pi * ROUND.radius ** 4 / 4
    force = np.zeros((1, 21, 3))
    force[0, -1, 0] = -4 * 4 * np.pi ** 2 * ei / 0.2 ** 2
    sim.set_user_forces(force)
    sim.step(300)
    tip = sim.positions()[0, -1]
    assert tip[0] < 0.19  # slid in by more than a segment
    assert abs(tip[1] - x[0, -1, 1]) < 1e-12 and abs(tip[2]) < 1e-12


def test_bad_clip_input_names_the_parameter():
    sim = simulator(straight(), ROUND)
    with pytest.raises(ValueError, match="clamp=True"):
        sim.add_pin(0, 5, hold_twist=True)
    with pytest.raises(ValueError, match="last edge"):
        sim.add_pin(0, 5, clamp=True, slide=True)
    with pytest.raises(ValueError, match="slide"):
        sim.add_pin(0, -2, clamp=True, slide=(0.0, 0.0, 0.0))
    pid = sim.add_pin(0, 5)
    with pytest.raises(ValueError, match="hold_twist"):
        sim.turn_pin(pid, 1.0)
    kmoch = simulator(straight(), ROUND, twist="kmoch")
    with pytest.raises(ValueError, match="quasistatic"):
        kmoch.add_pin(0, 5, clamp=True, hold_twist=True)
    with pytest.raises(ValueError, match="root='free'"):
        simulator(straight(), ROUND, root="free", integrator="implicit")
    with pytest.raises(ValueError, match="root must be one of"):
        simulator(straight(), ROUND, root="loose")
