"""Bad input is refused at the boundary with a ValueError naming the parameter."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair import validation
from taichi_hair.app.runner import Shot


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


@pytest.mark.parametrize("check, message", [
    (lambda: validation.real("radius", -1.0, "m", low=0.0, low_open=True), "radius must be a finite number > 0 m, got -1.0"),
    (lambda: validation.real("gain", 2.0, low=0.0, high=1.0), "gain must be a finite number >= 0 and <= 1, got 2.0"),
    (lambda: validation.real("dt", float("nan"), "s", low=0.0, low_open=True), "dt must be a finite number > 0 s, got nan"),
    (lambda: validation.real("dt", True, "s"), "dt must be a finite number s, got True"),
    (lambda: validation.real("dt", "1e-3", "s"), "dt must be a finite number s, got '1e-3'"),
    (lambda: validation.integer("n_nodes", 2, low=3), "n_nodes must be an integer >= 3, got 2"),
    (lambda: validation.integer("n_nodes", 3.0, low=3), "n_nodes must be an integer >= 3, got 3.0"),
    (lambda: validation.vector3("centre", [0.0, 1.0], "m"), "centre must be a finite 3-vector [m], got [0.0, 1.0]"),
    (lambda: validation.vector3("radii", (1.0, 0.0, 1.0), positive=True), "radii must be a finite 3-vector with every entry > 0"),
    (lambda: validation.vector3("axis", (0, 0, 0), normalise=True), "axis must be a finite non-zero 3-vector (it is normalised)"),
    (lambda: validation.vector3("axis", "up"), "axis must be a finite 3-vector, got 'up'"),
    (lambda: validation.choice("usd", "all", ("guides", "dense")), "usd must be one of ('guides', 'dense'), got 'all'"),
])
def test_validation_vocabulary_names_the_parameter_and_range(check, message):
    with pytest.raises(ValueError) as err:
        check()
    assert str(err.value).startswith(message)


def test_validation_vocabulary_accepts_and_converts():
    assert validation.real("dt", np.float32(0.5), "s", low=0.0, low_open=True) == 0.5
    assert validation.real("x", 0.0, low=0.0) == 0.0 and validation.real("x", 1.0, high=1.0) == 1.0
    assert type(validation.integer("n", np.int64(4), low=3)) is int
    v = validation.vector3("axis", (0.0, 3.0, 4.0), normalise=True)
    assert v.dtype == np.float64 and np.allclose(v, [0.0, 0.6, 0.8])
    assert validation.choice("mode", "blend", ("blend", "clump")) == "blend"
    with pytest.raises(ValueError):
        validation.real("x", 1.0, high=1.0, high_open=True)


# ---- API inputs: folds, numpy scalars, NaN forces --------------------------------------------

def _hair(n_nodes=21):
    return th.Groom.straight(roots=[[0, 0, 0]], directions=[[1, 0, 0]], length=0.2, n_nodes=n_nodes)


def test_set_positions_rejects_coincident_nodes_and_folds():
    sim = th.Simulator(_hair(6), th.Material(), gravity=(0, 0, 0))
    x = sim.positions()
    coincident = x.copy()
    coincident[0, 3] = coincident[0, 2]
    with pytest.raises(ValueError, match=r"positions: strand 0 segment 2 \(nodes 2-3\) has length 0 m"):
        sim.set_positions(coincident)
    folded = x.copy()
    folded[0, 4] = folded[0, 2]  # node 3 turns back by 180 degrees
    with pytest.raises(ValueError, match=r"positions: strand 0 turns by 180.0 degrees at node 3; turning "
                                         r"angles must be <= 170 degrees"):
        sim.set_positions(folded)
    np.testing.assert_array_equal(sim.positions(), x)  # refused, not half-applied
    assert np.isfinite(sim.elastic_energy())  # an accepted fold makes the energy NaN


def test_numpy_scalars_are_accepted_wherever_numbers_are():
    f32, i64 = np.float32, np.int64
    material = th.Material(youngs_modulus=f32(3e9), radius=f32(4e-5), ellipticity=np.float64(1.2))
    assert type(material.radius) is float and material.radius == pytest.approx(4e-5, rel=1e-6)
    groom = th.Groom.straight(length=f32(0.2), n_nodes=i64(11))
    head = th.Head.sphere(radius=f32(0.05), centre=(0, 0, 0.1), margin=f32(0.002))
    sim = th.Simulator(groom, material, dt=f32(1e-3), drag=f32(1e-4), projection_iterations=i64(50),
                       max_substeps=i64(100), colliders=head.colliders)
    sim.step(i64(2))
    sim.run(f32(0.002), progress=False)
    assert sim.steps_taken == 4 and sim.dt == pytest.approx(1e-3)
    assert Shot(dt=f32(1e-3), fps=24).steps_per_frame == 42
    for bad in (True, "1e-3", None):  # still refused: not real numbers
        with pytest.raises(ValueError, match="dt must be > 0 and < 1 s"):
            th.Simulator(groom, material, dt=bad)


def test_user_forces_with_nan_say_what_is_wrong():
    sim = th.Simulator(_hair(11), th.Material())
    force = np.zeros((1, 11, 3))
    force[0, 7, 2] = np.nan
    with pytest.raises(ValueError, match=r"user forces must be finite; strand 0 node 7 is \[ 0.  0. nan\] N"):
        sim.set_user_forces(force)
    with pytest.raises(ValueError, match=r"must have shape \[1, 11, 3\] \(strands, nodes, xyz\) N, got \[11, 3\]"):
        sim.set_user_forces(force[0])
