"""Each strand steps within its own stability bound (Simulator.strand_substeps): a strand moves
as it would stepped alone at its own step, any grouping of steps into calls ends in the same
state, and tight elliptic curls on a shaking head move as they do with every strand at the
smallest step."""

import warnings

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.solver.stability import strand_substeps


def simulator(groom, material, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # substepping notices
        return th.Simulator(groom, material, **options)


def test_each_strand_takes_a_divisor_of_the_substeps_within_its_own_bound():
    rng = np.random.default_rng(4)
    for _ in range(50):
        bounds = 10.0 ** rng.uniform(-4.5, -3.0, size=int(rng.integers(1, 40)))
        dt = 10.0 ** rng.uniform(-3.5, -2.5)
        total, per_strand = strand_substeps(dt, bounds, 1000)
        need = np.maximum(1, np.ceil(dt / bounds - 1e-9))
        assert np.all(total % per_strand == 0)
        assert np.all(dt / per_strand <= bounds * (1 + 1e-9))
        assert total >= need.max() and per_strand.sum() <= need.max() * len(bounds)


def two_strand_groom():
    """A tight curl (a small bound) and a horizontal straight strand (a large one), rooted apart."""
    curl = th.Groom.curly(length=0.06, n_nodes=16, curl_radius=0.004, curl_pitch=0.008).positions[0]
    straight = np.stack([np.linspace(0.05, 0.2, 12), np.zeros(12), np.zeros(12)], axis=1)
    return th.Groom.from_polylines([curl, straight])


MATERIALS = [th.Material(ellipticity=4.0, youngs_modulus=3e9, shear_modulus=1e9, radius=5e-5),
             th.Material(radius=5e-5)]


def test_a_strand_moves_as_it_would_stepped_alone_at_its_own_step():
    groom = two_strand_groom()
    dt = 2e-3
    both = simulator(groom, MATERIALS, dt=dt, drag=5e-4)
    per_strand = both.strand_substeps
    assert per_strand is not None and per_strand[0] > per_strand[1], (both.substeps, per_strand)
    both.step(30)
    for s, n in enumerate(groom.node_counts):
        # the step as the kernel forms it, (dt / substeps) x stride, to the last bit
        own_step = dt / both.substeps * int(both.substeps // per_strand[s])
        alone = simulator(th.Groom.from_polylines([groom.positions[s, :n]]), [MATERIALS[s]],
                          dt=own_step, drag=5e-4)
        assert alone.substeps == 1
        alone.step(30 * int(per_strand[s]))
        gap = np.abs(both.positions()[s, :n] - alone.positions()[0]).max()
        moved = np.abs(alone.positions()[0] - groom.positions[s, :n]).max()
        # the kernel with strides is compiled apart: under fast math its last bits differ, and the
        # projection's stopping rule (strain 1e-6) turns that into ~1e-11 m a step
        assert gap < 1e-8 and moved > 1e-4, (s, gap, moved)


def test_step_grouping_and_resume_with_strands_at_their_own_steps(tmp_path):
    groom = two_strand_groom()
    options = dict(dt=2e-3, drag=5e-4, motion=th.Nod(amplitude_deg=20.0, frequency_hz=2.0),
                   wind=th.Wind(velocity=(1.0, 0.0, 0.0), gust_amplitude=0.5, turbulence=0.5, seed=2))
    whole = simulator(groom, MATERIALS, **options)
    assert whole.strand_substeps is not None and len(set(whole.strand_substeps)) == 2
    whole.step(7)
    split = simulator(groom, MATERIALS, **options)
    split.step(3)
    split.save_state(tmp_path / "part.npz")
    split.step(4)
    resumed = simulator(groom, MATERIALS, **options)
    resumed.load_state(tmp_path / "part.npz")
    resumed.step(4)
    for other in (split, resumed):
        assert np.array_equal(whole.positions(), other.positions())
        assert np.array_equal(whole.velocities(), other.velocities())
        assert np.array_equal(whole.material_angles(), other.material_angles())


def rotation_about_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.slow  # a long run: 150 steps of two simulators, 20-40 s each on 2 cores
@pytest.mark.parametrize("ellipticity", [1.0, 4.0])
def test_shaken_tight_curls_move_as_with_every_strand_at_the_smallest_step(ellipticity):
    """Tight curls and straight strands on a shaking head: each strand at its own step against
    every strand at the scene's smallest, 0.15 s of a 3 Hz shake. They differ by the time
    discretisation only: well under the strands' motion, and both runs keep lengths and
    stay out of the head."""
    radius = 0.1
    roots = radius * np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [-0.6, 0.0, 0.8]])
    curls = th.Groom.curly(roots[:2], roots[:2] / radius, length=0.1, n_nodes=30, curl_radius=0.004,
                           curl_pitch=0.008)
    lines = [curls.positions[0], curls.positions[1]]
    for root in roots[2:]:
        lines.append(root + np.outer(np.linspace(0.0, 0.12, 13), root / radius))
    groom = th.Groom.from_polylines(lines)
    materials = [th.Material(ellipticity=ellipticity)] * 2 + [th.Material()] * 2

    def shake(t):
        return rotation_about_z(0.6 * np.sin(2 * np.pi * 3.0 * t)), np.zeros(3)

    runs = {}
    for own in (True, False):
        sim = simulator(groom, materials, dt=1e-3, drag=5e-4, root_motion=shake, strand_steps=own,
                        colliders=[th.Sphere(radius=radius, margin=1e-3)])
        if own:
            assert sim.strand_substeps is not None and sim.strand_substeps.min() < sim.substeps
        sim.step(150)
        x = sim.positions()
        rest = sim.model.rest_length.to_numpy()
        counts = groom.node_counts
        strain = max(np.abs(np.linalg.norm(np.diff(x[s, :n], axis=0), axis=1) / rest[s, :n - 1] - 1).max()
                     for s, n in enumerate(counts))
        depth = min((np.linalg.norm(x[s, 1:n], axis=1) - radius).min() for s, n in enumerate(counts))
        assert strain < 1e-4 and depth > -1e-4, (own, strain, depth)
        runs[own] = x
    moved = max(np.abs(runs[False][s, :n] - groom.positions[s, :n]).max() for s, n in enumerate(groom.node_counts))
    gap = max(np.abs(runs[True][s, :n] - runs[False][s, :n]).max() for s, n in enumerate(groom.node_counts))
    print(f"\nellipticity {ellipticity}: strands moved {moved * 1e3:.1f} mm, own steps vs smallest "
          f"{gap * 1e3:.3f} mm")
    assert moved > 0.02 and gap < 0.02 * moved
