"""Bad input is refused at the boundary with a ValueError naming the parameter."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

import taichi_hair as th


@pytest.mark.parametrize("kwargs, name", [
    ({"youngs_modulus": -1.0}, "youngs_modulus"),
    ({"youngs_modulus": 0.0}, "youngs_modulus"),
    ({"shear_modulus": float("nan")}, "shear_modulus"),
    ({"radius": 0.0}, "radius"),
    ({"density": -1300.0}, "density"),
    ({"ellipticity": 0.5}, "ellipticity"),
    ({"ellipticity": float("inf")}, "ellipticity"),
])
def test_material_rejects_bad_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        th.Material(**kwargs)


def test_material_stiffness_of_elliptic_section():
    m = th.Material(youngs_modulus=2e9, shear_modulus=7e8, radius=5e-5, ellipticity=2.0)
    a, b = 5e-5 * np.sqrt(2), 5e-5 / np.sqrt(2)
    ei1, ei2 = m.bending_stiffness
    assert ei1 == pytest.approx(2e9 * np.pi * a**3 * b / 4, rel=1e-12)
    assert ei2 == pytest.approx(2e9 * np.pi * a * b**3 / 4, rel=1e-12)
    assert ei1 / ei2 == pytest.approx(4.0)  # (a/b)^2
    assert m.twist_stiffness == pytest.approx(7e8 * np.pi * a**3 * b**3 / (a**2 + b**2), rel=1e-12)
    round_hair = th.Material(youngs_modulus=2e9, radius=5e-5)
    assert round_hair.bending_stiffness[0] == pytest.approx(2e9 * np.pi * 5e-5**4 / 4, rel=1e-12)


def straight_points(n=5):
    return np.stack([np.zeros(n), np.zeros(n), -0.01 * np.arange(n)], axis=1)


@pytest.mark.parametrize("points, fragment", [
    (np.zeros((1, 2, 3)) + np.arange(2)[None, :, None], "at least 3 nodes"),
    (np.zeros((4, 2)), "shape"),
    ("not an array", "points must be"),
    ([], "at least one strand"),
])
def test_groom_rejects_malformed_polylines(points, fragment):
    with pytest.raises(ValueError, match=fragment):
        th.Groom.from_polylines(points)


def test_groom_rejects_nan_and_inf():
    for bad in (np.nan, np.inf):
        p = straight_points()
        p[3, 1] = bad
        with pytest.raises(ValueError, match="strand 0: node 3 has a non-finite"):
            th.Groom.from_polylines(p)


def test_groom_rejects_zero_length_segment_and_fold():
    p = straight_points()
    p[2] = p[1]
    with pytest.raises(ValueError, match="segment 1 has length 0"):
        th.Groom.from_polylines([straight_points(), p])
    folded = straight_points()
    folded[3] = folded[1]  # goes straight back
    folded[4] = folded[0]
    with pytest.raises(ValueError, match="folds back"):
        th.Groom.from_polylines(folded)


@pytest.mark.parametrize("kwargs, name", [
    ({"curl_radius": 0.0}, "curl_radius"),
    ({"curl_pitch": -0.01}, "curl_pitch"),
    ({"length": -1.0}, "length"),
    ({"n_nodes": 2}, "n_nodes"),
])
def test_procedural_grooms_reject_bad_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        th.Groom.curly(**kwargs)


def test_simulator_rejects_bad_arguments():
    groom = th.Groom.straight(n_nodes=6, length=0.05)
    with pytest.raises(ValueError, match="twist"):
        th.Simulator(groom, th.Material(), twist="sideways")
    with pytest.raises(ValueError, match="material"):
        th.Simulator(groom, [th.Material(), th.Material()])
    sim = th.Simulator(groom, th.Material())
    with pytest.raises(ValueError, match="positions must have shape"):
        sim.set_positions(np.zeros((1, 5, 3)))
    x = sim.positions()
    x[0, 4, 2] = np.nan
    with pytest.raises(ValueError, match="strand 0 node 4"):
        sim.set_positions(x)
    with pytest.raises(ValueError, match="rotation"):
        sim.set_root_transform(np.diag([1.0, 1.0, -1.0]), np.zeros(3))


def test_per_strand_counts_load_together():
    """Strands of different lengths in one groom give the same energies as apart."""
    a = th.Groom.curly(length=0.08, n_nodes=9, curl_radius=0.01, curl_pitch=0.02)
    b = th.Groom.wavy(length=0.05, n_nodes=5, amplitude=0.004, wavelength=0.03)
    both = th.Groom.concatenate([a, b])
    assert list(both.node_counts) == [9, 5]
    rng = np.random.default_rng(0)
    sims = [th.Simulator(g, th.Material(ellipticity=1.3), twist="quasistatic") for g in (a, b, both)]
    xa = sims[0].positions() + 1e-3 * rng.standard_normal((1, 9, 3))
    xb = sims[1].positions() + 1e-3 * rng.standard_normal((1, 5, 3))
    xab = sims[2].positions()
    xab[0] = xa[0]
    xab[1, :5] = xb[0]
    for sim, x in zip(sims, (xa, xb, xab)):
        sim.set_positions(x)
        sim.update_twist()
    energies = [sim.strand_elastic_energy() for sim in sims]
    assert energies[2] == pytest.approx([energies[0][0], energies[1][0]], rel=1e-9)
    assert energies[0][0] > 0 and energies[1][0] > 0


def test_float32_is_the_default_precision():
    """A fresh process without an explicit precision runs float32 (positions excepted: they are
    float64 in both precisions, arrays.Points2) and still keeps a rest curl."""
    code = textwrap.dedent("""
        import numpy as np, taichi_hair as th
        groom = th.Groom.curly(length=0.2, n_nodes=30)
        sim = th.Simulator(groom, th.Material(ellipticity=1.5))
        assert sim.state.v.to_numpy().dtype == np.float32, sim.state.v.to_numpy().dtype
        assert sim.state.x.to_numpy().dtype == np.float64, sim.state.x.to_numpy().dtype
        assert sim.elastic_energy() < 1e-12
        sim.update_twist()
        print("ok", sim.elastic_energy())
    """)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "ok" in result.stdout


def test_init_refuses_a_second_precision():
    with pytest.raises(RuntimeError, match="already initialised"):
        th.init(arch="cpu", precision="float32")
    with pytest.raises(ValueError, match="precision"):
        th.init(precision="float16")
