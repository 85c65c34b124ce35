"""Extensible strands (Simulator(extensible=True)): each edge a compliant constraint of axial
stiffness EA inside the projection. Checked against Hooke's law on a hanging rope (the tension
of each edge is the weight below it, known without the simulator), against energy (a free
stretch oscillation and falling elliptic curls never gain energy) and for its input checks."""

import numpy as np
import pytest

import taichi_hair as th
from helpers import energy_rise

LENGTH, N_NODES = 1.0, 21
ROPE = th.Material(youngs_modulus=1e6, shear_modulus=1e6 / 3, radius=0.005, density=1000.0)


def hanging_rope():
    x = np.zeros((1, N_NODES, 3))
    x[0, :, 2] = -np.linspace(0.0, LENGTH, N_NODES)
    return th.Groom.from_polylines(x)


def edge_weights(sim, gravity=9.81):
    """The weight [N] each edge carries: the masses of the nodes below it (the tension of a
    rope hanging at rest), from the simulator's lumped masses."""
    mass = sim.model.mass.to_numpy()[0].astype(np.float64)
    return gravity * np.cumsum(mass[::-1])[::-1][1:]


@pytest.mark.parametrize("projection", ["fast", "shake"])
def test_hanging_rope_stretches_by_hookes_law(projection):
    """A rope of EA = 78.5 N pinned at its top, settled under gravity with drag (3 s): each
    edge's strain is its weight / EA (up to 0.96 % at the top) within 1e-3 of the top strain,
    and the tension the projection reports is that weight within 1e-3."""
    sim = th.Simulator(hanging_rope(), ROPE, dt=1e-3, drag=0.5, root="pinned", extensible=True,
                       projection=projection)
    sim.step(3000)
    assert sim.kinetic_energy() < 1e-10, "not at rest yet"
    weight = edge_weights(sim)
    expected = weight / ROPE.axial_stiffness
    lengths = np.linalg.norm(np.diff(sim.positions()[0], axis=0), axis=1)
    strain = lengths / (LENGTH / (N_NODES - 1)) - 1.0
    tension = sim.state.tension.to_numpy()[0].astype(np.float64)
    error = np.abs(strain - expected).max() / expected[0]
    print(f"\n{projection}: top strain {strain[0]:.5e} (Hooke {expected[0]:.5e}), worst error "
          f"{error:.1e} of it; tension error {np.abs(tension - weight).max() / weight[0]:.1e}")
    assert expected[0] > 5e-3  # a stretch worth measuring
    assert error < 1e-3
    assert np.abs(tension - weight).max() < 1e-3 * weight[0]
    # the stretch energy is what Hooke's law stores, and counts in the total
    stored = np.sum(ROPE.axial_stiffness * (lengths - LENGTH / (N_NODES - 1)) ** 2 / (2 * LENGTH / (N_NODES - 1)))
    assert sim.stretch_energy() == pytest.approx(stored, rel=1e-12)


def test_free_stretch_oscillation_never_gains_energy():
    """Undamped: the rope released unstretched falls into its stretch and bounces; total energy
    (kinetic + gravity + stretch) never rises above its start by more than 1e-3 of the energy
    in play (the compliant projection is backward-Euler-like on the stretch: it only loses)."""
    sim = th.Simulator(hanging_rope(), ROPE, dt=1e-3, root="pinned", extensible=True)
    rise, in_play = energy_rise(sim, 100, 5, lambda sim: sim.kinetic_energy() + sim.stretch_energy())
    print(f"\nfree stretch: energy rise {rise / in_play:.1e} of the energy in play ({in_play:.2e} J)")
    assert in_play > 1e-3
    assert rise / in_play < 1e-3


def test_soft_elliptic_curls_stretch_without_gaining_energy():
    """The hard case: undamped curls (5 mm curl radius, 2.5 mm segments, ellipticity 4,
    quasistatic twist) of a soft material (E = 1e6 Pa, strain under their own fall ~1e-4 to
    1e-3) falling from horizontal for 0.2 s: finite, stretched (not held inextensible), and
    total energy with the stretch energy never rises by more than 1e-3 of the energy in play."""
    roots = np.array([[0.0, 0.0, 0.0], [0.0, 0.05, 0.0]])
    groom = th.Groom.curly(roots=roots, directions=[[1.0, 0.0, 0.0]] * 2, length=0.1, n_nodes=41,
                           curl_radius=0.005, curl_pitch=0.01)
    material = th.Material(youngs_modulus=1e6, shear_modulus=1e6 / 3, radius=1e-3, density=1300.0,
                           ellipticity=4.0)
    sim = th.Simulator(groom, material, dt=1e-3, extensible=True)
    start = sim.total_energy()
    rise, in_play, strain = 0.0, 0.0, 0.0
    rest = np.linalg.norm(np.diff(groom.positions, axis=1), axis=2)
    for _ in range(20):
        sim.step(10)
        rise = max(rise, sim.total_energy() - start)
        in_play = max(in_play, sim.kinetic_energy() + sim.elastic_energy() + sim.stretch_energy())
        lengths = np.linalg.norm(np.diff(sim.positions(), axis=1), axis=2)
        strain = max(strain, np.abs(lengths / rest - 1).max())
    print(f"\nextensible curls, e 4: {sim.substeps} substeps, energy rise {rise / in_play:.1e} of the "
          f"energy in play, max strain {strain:.1e}")
    assert np.all(np.isfinite(sim.positions()))
    assert strain > 1e-5
    assert rise / in_play < 1e-3


def test_extensible_is_checked():
    with pytest.raises(ValueError, match="extensible=True runs with integrator='explicit'"):
        th.Simulator(hanging_rope(), ROPE, integrator="implicit", extensible=True)
    with pytest.raises(ValueError, match="extensible must be True or False"):
        th.Scene(groom=hanging_rope(), extensible="yes")
