"""Strand-strand contact in the simulator (StrandContact): crossed strands pressed together, a
coil dropped onto a floor, energy through a frictionless collision, friction holding a strand
on another. Distances are measured here by brute force between the curves through the nodes
(curve_polyline, what strand contact keeps apart), sampled independently of the kernels."""

import warnings

import numpy as np
import pytest
from taichi_hair.rods.references import curve_points

import taichi_hair as th

ROPE = th.Material(youngs_modulus=1e6, shear_modulus=1e6 / 3, radius=0.005, density=1000.0)


def simulator(groom, material, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # substepping notices
        return th.Simulator(groom, material, **options)


def curve_polyline(x, radius, pieces=8):
    """The curve strand contact keeps apart through the nodes of polyline x [n, 3]
    (references.curve_points, the move at most `radius` [m]) as a finer polyline
    [(n - 1) pieces + 1, 3]."""
    n = len(x)
    j = np.repeat(np.arange(n - 1), pieces)
    u = np.tile(np.linspace(0.0, 1.0, pieces + 1)[:-1], n - 1)
    points = curve_points(x[None], np.array([n]), np.zeros_like(j), j, u, np.array([radius]))
    return np.vstack([points, x[-1:]])


def polyline_distances(a, b, samples):
    """Distance between every segment of polyline a [n, 3] and of polyline b [m, 3]: [n-1, m-1],
    by sampling a's segment densely and projecting each sample exactly onto b's segment (a's
    segments in chunks, to bound the memory)."""
    s = np.linspace(0.0, 1.0, samples)
    b0, d = b[:-1], np.diff(b, axis=0)  # [m-1, 3]
    rows = []
    for start in range(0, len(a) - 1, 64):
        part = a[start:start + 65]
        pa = part[:-1, None, :] + s[None, :, None] * np.diff(part, axis=0)[:, None, :]  # [k, K, 3]
        rel = pa[:, :, None, :] - b0[None, None]  # [k, K, m-1, 3]
        t = np.clip((rel * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
        rows.append(np.linalg.norm(rel - t[..., None] * d, axis=-1).min(axis=1))
    return np.vstack(rows)


def segment_distances(a, b, radius, pieces=8, samples=50):
    """Distance between the curves of every segment of strand a [n, 3] and of strand b [m, 3]
    (curve_polyline: what strand contact keeps apart; a bent strand's chords cut its corners):
    [n-1, m-1], the smallest distance between their pieces."""
    d = polyline_distances(curve_polyline(a, radius, pieces), curve_polyline(b, radius, pieces), samples)
    return d.reshape(len(a) - 1, pieces, len(b) - 1, pieces).min(axis=(1, 3))


def self_distance(x, gap, radius):
    """Smallest distance between segments of one polyline at least `gap` apart along it."""
    d = segment_distances(x, x, radius)
    i, j = np.indices(d.shape)
    return d[np.abs(i - j) >= gap].min()


def crossing_ropes(n=31, span=0.3):
    s = np.linspace(-span / 2, span / 2, n)
    sag = -0.04 * (1 - (2 * s / span) ** 2)
    lower = np.stack([s, np.zeros(n), sag], axis=1)
    upper = np.stack([np.zeros(n), s, sag + 0.02], axis=1)
    return th.Groom.from_polylines(np.stack([lower, upper]))


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_crossed_ropes_pressed_together_never_interpenetrate():
    """Two sagging ropes at right angles, each pinned at both ends; the upper one's pins are
    lowered 4 cm, so it presses down on the lower one. Every 50 steps the closest segment pair
    stays at least (1 - tolerance) of the diameter apart, and the upper rope does rest on the
    lower one (it would hang 2 cm lower without it)."""
    groom = crossing_ropes()
    contact = th.StrandContact(tolerance=0.05)
    sim = simulator(groom, ROPE, dt=1e-3, root="free", drag=0.5, strand_contact=contact)
    ids = sim.add_pin([0, 0, 1, 1], [0, -1, 0, -1])
    sim.move_pin(ids[2:], groom.strand(1)[[0, -1]] - [0.0, 0.0, 0.04])
    sim.step(100)
    closest = []
    for _ in range(12):
        sim.step(50)
        x = sim.positions()
        closest.append(segment_distances(x[0], x[1], ROPE.radius).min())
    assert min(closest) >= (1 - contact.tolerance) * 2 * ROPE.radius
    x = sim.positions()
    middle = len(x[0]) // 2
    assert x[1, middle, 2] - x[0, middle, 2] == pytest.approx(2 * ROPE.radius, rel=0.05)
    assert sim.strand_contact_depth() <= contact.tolerance * 2 * ROPE.radius


def coil(radius=0.03, pitch=0.014, turns=3.0, n=61):
    """A helix about the vertical axis, its lowest point 1 cm above the floor z = 0."""
    angle = np.linspace(0.0, 2 * np.pi * turns, n)
    x = np.stack([radius * np.cos(angle), radius * np.sin(angle),
                  0.01 + pitch * angle / (2 * np.pi)], axis=1)
    return th.Groom.from_polylines(x[None])


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
@pytest.mark.parametrize("contact", [True, False])
def test_coil_dropped_on_a_floor_does_not_pass_through_itself(contact):
    """A loose helix of 3 turns (pitch 14 mm, cord 5 mm thick: 4 mm between turns) falls onto a
    plane, its turns landing on each other. With strand contact no two segments that may touch
    come closer than (1 - tolerance) of the diameter; without it the turns pass into each other
    (the check would fail), which is what makes this test able to fail."""
    groom = coil()
    cord = th.Material(youngs_modulus=1e6, shear_modulus=1e6 / 3, radius=0.0025, density=1000.0)
    floor = th.Plane(point=(0, 0, 0), normal=(0, 0, 1), margin=cord.radius, friction=0.3,
                     attached="world")
    settings = th.StrandContact(friction=0.3, tolerance=0.05) if contact else None
    sim = simulator(groom, cord, dt=1e-3, root="free", drag=0.05, colliders=[floor], strand_contact=settings)
    segment = np.linalg.norm(np.diff(groom.strand(0), axis=0), axis=1).mean()
    gap = 1 + int(np.ceil(0.8 * np.pi * cord.radius / segment))
    closest = []
    for _ in range(8):
        sim.step(25)
        closest.append(self_distance(sim.positions()[0], gap, cord.radius))
    if contact:
        assert min(closest) >= 0.95 * 2 * cord.radius
        assert sim.positions()[0, :, 2].min() >= 0.95 * cord.radius  # on the floor, not in it
    else:
        assert min(closest) < 0.8 * 2 * cord.radius


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_frictionless_collision_creates_no_energy_and_keeps_momentum():
    """No gravity, no drag, no friction: a straight free strand thrown at 1 m/s across another
    at rest. Contact is inelastic along its normal, so the total energy can only fall; the
    contact pushes are equal and opposite, so momentum is kept."""
    n = 21
    s = np.linspace(-0.1, 0.1, n)
    a = np.stack([s, np.zeros(n), np.zeros(n)], axis=1)
    b = np.stack([np.zeros(n), s, np.full(n, 0.03)], axis=1)
    groom = th.Groom.from_polylines(np.stack([a, b]))
    sim = simulator(groom, ROPE, dt=2e-4, root="free", gravity=(0, 0, 0),
                    strand_contact=th.StrandContact())
    v = np.zeros((2, n, 3))
    v[1, :, 2] = -1.0
    sim.set_velocities(v)
    mass = sim.model.mass.to_numpy()
    momentum0 = (mass[..., None] * sim.velocities()).sum((0, 1))
    energies = [sim.total_energy()]
    for _ in range(30):
        sim.step(5)
        energies.append(sim.total_energy())
    x = sim.positions()
    assert x[1, n // 2, 2] - x[0, n // 2, 2] >= 0.95 * 2 * ROPE.radius  # they met and did not pass
    # up to a sixth of it goes into bending and back; the total never rises above the start
    assert max(energies) <= energies[0] * (1 + 1e-9)
    assert energies[-1] < energies[0]
    momentum = (mass[..., None] * sim.velocities()).sum((0, 1))
    assert np.abs(momentum - momentum0).max() < 1e-9 * np.abs(momentum0).max()


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_friction_holds_a_strand_resting_across_another():
    """A short strand lying across a taut strand at a slant is pushed along the taut one by a
    sideways force below friction x the normal force: with friction 0.6 it holds, without
    friction it slides."""
    n = 11
    s = np.linspace(-0.1, 0.1, n)
    taut = np.stack([s, np.zeros(n), np.zeros(n)], axis=1)
    resting = np.stack([np.full(n, 0.02), s * 0.5, np.full(n, 2 * ROPE.radius + 1e-4)], axis=1)
    groom = th.Groom.from_polylines(np.stack([taut, resting]))
    travel = {}
    for friction in (0.0, 0.6):
        sim = simulator(groom, ROPE, dt=1e-3, root="free", drag=0.2,
                        strand_contact=th.StrandContact(friction=friction))
        sim.add_pin([0, 0], [0, -1])
        weight = sim.model.mass.to_numpy()[1].sum() * 9.81
        push = np.zeros((2, n, 3))
        push[1, :, 0] = 0.3 * weight / n  # along the taut strand: half what friction 0.6 holds
        sim.set_user_forces(push)
        sim.step(200)
        travel[friction] = sim.positions()[1, :, 0].mean() - 0.02
    assert abs(travel[0.6]) < 0.1 * abs(travel[0.0])
    assert travel[0.0] > 0.01


def test_bad_strand_contact_input_names_the_parameter():
    with pytest.raises(ValueError, match="friction"):
        th.StrandContact(friction=-1.0)
    with pytest.raises(ValueError, match="radius"):
        th.StrandContact(radius=0.0)
    with pytest.raises(ValueError, match="iterations"):
        th.StrandContact(iterations=0)
    with pytest.raises(ValueError, match="tolerance"):
        th.StrandContact(tolerance=1.5)
    with pytest.raises(ValueError, match="strand_contact"):
        simulator(crossing_ropes(), ROPE, strand_contact="yes")
    with pytest.raises(ValueError, match="strand_contact"):
        simulator(crossing_ropes(), ROPE, strand_contact=th.StrandContact(), integrator="implicit")


def test_strand_contact_leaves_a_margin_on_the_explicit_bound():
    """With strand contact the bound's default factor is 0.4, not 0.5 (contact pushes pumped
    energy into the stiffest bending mode at 0.5: test_cosseratbench's pile); a factor the
    scene names is taken as it is."""
    groom = crossing_ropes()
    plain = simulator(groom, ROPE)
    touching = simulator(groom, ROPE, strand_contact=th.StrandContact())
    named = simulator(groom, ROPE, strand_contact=th.StrandContact(), stability_factor=0.5)
    assert (plain.stability_factor, touching.stability_factor, named.stability_factor) == (0.5, 0.4, 0.5)
    assert touching.stable_dt == pytest.approx(0.8 * plain.stable_dt, rel=1e-12)
    assert named.stable_dt == pytest.approx(plain.stable_dt, rel=1e-12)


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_fused_contact_steps_match_the_staged_one():
    """Three drivers run the same passes and give the same positions: many steps per launch on
    one thread (a small scene), a launch per step (step.contact.advance_with_strand_contact, forced by
    small_contact_nodes = 0), and a launch per stage and per contact pass (with timers)."""
    import contextlib
    groom = crossing_ropes(n=21)
    results = []
    for driver in ("small", "fused", "staged"):
        sim = simulator(groom, ROPE, dt=1e-3, root="free", drag=0.5,
                        strand_contact=th.StrandContact(friction=0.2))
        if driver == "fused":
            sim.small_contact_nodes = 0
        ids = sim.add_pin([0, 0, 1, 1], [0, -1, 0, -1])
        sim.move_pin(ids[2:], groom.strand(1)[[0, -1]] - [0.0, 0.0, 0.04])
        timers = (lambda name: contextlib.nullcontext()) if driver == "staged" else None
        for _ in range(15):
            sim.step(10, timers=timers)
        results.append(sim.positions())
        assert sim.stats()["strand_contact_depth_max"] > 0  # they touched
    # parallel atomic sums round in a different order each run, and contact amplifies that over
    # 150 steps: agreement to 1e-7 m (a missing or reordered pass moves nodes by millimetres)
    assert np.abs(results[0] - results[2]).max() < 1e-7
    assert np.abs(results[1] - results[2]).max() < 1e-7


def test_strand_contact_code_compiles_only_when_a_scene_asks_for_it():
    """In a fresh process: a scene without strand contact compiles no contact kernel and no
    clip stage; one with it compiles the fused contact step once."""
    import json
    import subprocess
    import sys
    import textwrap
    code = textwrap.dedent("""
        import json, warnings, numpy as np, taichi_hair as th
        from taichi_hair.solver import strand_contact
        from taichi_hair.solver.step import contact, fused
        warnings.simplefilter("ignore")
        th.init(precision="float64")
        groom = th.Groom.straight(length=0.1, n_nodes=11, roots=[[0, 0, 0.1], [0.01, 0, 0.1]],
                                  directions=[[0, 0, 1], [0, 0, 1]])
        def compiled():
            return {"contact_step": len(contact.advance_with_strand_contact._primal.mapper.mapping)
                                    + len(contact.advance_small_with_strand_contact._primal.mapper.mapping),
                    "contact_pass": len(strand_contact._contact_pass._primal.mapper.mapping),
                    "clips": any(v["clips"] for v in fused.compiled_variants())}
        th.Simulator(groom, th.Material()).step(3)
        bare = compiled()
        th.Simulator(groom, th.Material(), strand_contact=th.StrandContact()).step(3)
        print(json.dumps({"bare": bare, "contact": compiled()}))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout[out.stdout.index("{"):])
    assert result["bare"] == {"contact_step": 0, "contact_pass": 0, "clips": False}
    assert result["contact"]["contact_step"] == 1


def test_strand_contact_beside_hair_interaction():
    """Guides of a bundle with the volumetric hair-hair grid and strand contact together (the
    staged step runs both): the guides stay a diameter apart while the bundle swings."""
    roots = [[0.0, 0.004 * i, 0.1 + 0.0025 * i] for i in range(4)]  # stacked, 2.5 mm apart in z
    tilt = [[1, 0.1 if i % 2 else -0.1, 0] for i in range(4)]  # crossing their neighbours
    groom = th.Groom.straight(length=0.1, n_nodes=11, roots=roots, directions=tilt)
    hair = th.Material(radius=1e-3, youngs_modulus=1e7, shear_modulus=3e6)
    sim = simulator(groom, hair, dt=1e-3, drag=1e-3, hair_interaction=th.HairInteraction(cell_size=0.01),
                    strand_contact=th.StrandContact(friction=0.2))
    for _ in range(10):
        sim.step(10)
        assert sim.strand_contact_depth() <= 0.05 * 2 * hair.radius
    assert sim.stats()["strand_contact_depth_max"] > 0  # they did press on each other
    x = sim.positions()
    assert np.all(np.isfinite(x)) and x[:, -1, 2].max() < 0.1 - 0.03  # they fell and swung
