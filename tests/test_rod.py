"""Discrete elastic rod: energy, exact forces (holonomy included), frames and twist updates."""

import json
import subprocess
import sys

import numpy as np
import pytest

import taichi_hair as th
from helpers import central_difference_gradient, perturbed, rotation_matrix


def mixed_groom():
    """A curly strand (rest curvature + rest twist when elliptic) and a shorter wavy strand,
    loaded together so the per-strand node counts differ."""
    curly = th.Groom.curly(length=0.1, n_nodes=10, curl_radius=0.01, curl_pitch=0.02)
    wavy = th.Groom.wavy(roots=[[0.02, 0.0, 0.0]], length=0.06, n_nodes=7, amplitude=0.005,
                         wavelength=0.03)
    return th.Groom.concatenate([curly, wavy])


def real_nodes(groom):
    return [(s, i) for s in range(groom.n_strands) for i in range(groom.node_counts[s])]


def relative_error(force, minus_grad, groom):
    mask = np.zeros(force.shape[:2], bool)
    for s, i in real_nodes(groom):
        mask[s, i] = True
    scale = np.abs(force[mask]).max()
    assert scale > 1e-7, "vacuous check: the forces are ~0"
    return np.abs(force[mask] - minus_grad[mask]).max() / scale


STRAINS = ("rotation", "der")  # the strain measures (rods/rod.py): every energy check runs both


@pytest.mark.parametrize("strain", STRAINS)
@pytest.mark.parametrize("ellipticity", [1.0, 1.6])
def test_forces_are_minus_energy_gradient_at_fixed_angles(ellipticity, strain):
    groom = mixed_groom()
    sim = th.Simulator(groom, th.Material(ellipticity=ellipticity), twist="none", strain=strain)
    x0 = perturbed(sim.positions(), 2e-3, seed=1)  # random: bends, twists and stretches edges
    rng = np.random.default_rng(2)
    sim.set_material_angles(sim.material_angles() + 0.4 * rng.standard_normal(sim.material_angles().shape))
    sim.set_positions(x0)
    force = sim.elastic_forces()

    def energy(x):
        sim.set_positions(x)
        return sim.elastic_energy()

    grad = central_difference_gradient(energy, x0, real_nodes(groom))
    err = relative_error(force, -grad, groom)
    print(f"{strain}, fixed angles, ellipticity {ellipticity}: max relative error {err:.2e}")
    assert err < 1e-6


@pytest.mark.parametrize("strain", STRAINS)
@pytest.mark.parametrize("ellipticity", [1.0, 1.6])
def test_total_force_at_quasistatic_twist_equilibrium(ellipticity, strain):
    groom = mixed_groom()
    sim = th.Simulator(groom, th.Material(ellipticity=ellipticity), twist="quasistatic", strain=strain)
    x0 = perturbed(sim.positions(), 2e-3, seed=3)
    sim.set_positions(x0)
    sim.update_twist()
    force = sim.elastic_forces()

    def energy(x):
        sim.set_positions(x)
        report = sim.update_twist()
        assert report["residual"] < 1e-9
        return sim.elastic_energy()

    grad = central_difference_gradient(energy, x0, real_nodes(groom))
    err = relative_error(force, -grad, groom)
    print(f"{strain}, twist equilibrium, ellipticity {ellipticity}: max relative error {err:.2e}")
    assert err < 1e-6


@pytest.mark.parametrize("strain", STRAINS)
def test_theta_gradient_matches_finite_differences(strain):
    groom = mixed_groom()
    sim = th.Simulator(groom, th.Material(ellipticity=1.4), twist="none", strain=strain)
    sim.set_positions(perturbed(sim.positions(), 2e-3, seed=4))
    theta0 = sim.material_angles() + 0.3
    sim.set_material_angles(theta0)
    analytic = sim.theta_gradient()
    h = 1e-6
    for s in range(groom.n_strands):
        for j in range(groom.node_counts[s] - 1):
            values = []
            for sign in (1, -1):
                theta = theta0.copy()
                theta[s, j] += sign * h
                sim.set_material_angles(theta)
                values.append(sim.elastic_energy())
            fd = (values[0] - values[1]) / (2 * h)
            assert abs(fd - analytic[s, j]) <= 1e-6 * np.abs(analytic).max() + 1e-14


@pytest.mark.parametrize("strain", STRAINS)
def test_rest_shape_has_zero_energy_and_force(strain):
    groom = mixed_groom()
    for ellipticity in (1.0, 1.6):
        sim = th.Simulator(groom, th.Material(ellipticity=ellipticity), twist="quasistatic", strain=strain)
        bend_scale = sim.model.materials[0].bending_stiffness[0] / 0.01
        assert sim.elastic_energy() < 1e-20
        assert np.abs(sim.elastic_forces()).max() < 1e-12 * bend_scale
        sim.update_twist()  # the rest angles are the equilibrium: nothing moves
        assert sim.elastic_energy() < 1e-20


@pytest.mark.parametrize("strain", STRAINS)
def test_energy_invariant_under_rigid_motion(strain):
    groom = mixed_groom()
    sim = th.Simulator(groom, th.Material(ellipticity=1.6), twist="quasistatic", strain=strain)
    x = perturbed(sim.positions(), 2e-3, seed=5)
    sim.set_positions(x)
    sim.update_twist()
    e0 = sim.elastic_energy()
    assert e0 > 1e-9
    rotation = rotation_matrix([0.3, -1.0, 0.5], 1.1)
    translation = np.array([0.4, -0.2, 1.3])
    sim.set_root_transform(rotation, translation)
    sim.set_positions(x @ rotation.T + translation)
    assert abs(sim.elastic_energy() - e0) < 1e-10 * e0
    sim.update_twist()
    assert abs(sim.elastic_energy() - e0) < 1e-10 * e0


def arc_positions(radius, length, n_segments):
    phi = np.linspace(0.0, length / radius, n_segments + 1)
    return np.stack([radius * np.sin(phi), np.zeros_like(phi), radius * (1 - np.cos(phi))], axis=1)


def test_circular_arc_bending_energy_converges():
    """A straight rest strand bent into an arc of radius R stores 1/2 EI L / R^2."""
    material = th.Material(youngs_modulus=1e9, radius=1e-4)
    ei = material.bending_stiffness[0]
    radius, length = 0.2, 0.3
    exact = 0.5 * ei * length / radius**2
    errors = []
    print("\nsegments  E_discrete [J]   E_exact [J]   rel. error")
    for n in (8, 16, 32, 64, 128):
        groom = th.Groom.straight(directions=[[1.0, 0.0, 0.0]], length=length, n_nodes=n + 1)
        sim = th.Simulator(groom, material, twist="none")
        sim.set_positions(arc_positions(radius, length, n)[None])
        energy = sim.elastic_energy()
        errors.append(abs(energy - exact) / exact)
        print(f"{n:8d}  {energy:.6e}   {exact:.6e}   {errors[-1]:.2e}")
    assert all(b < a for a, b in zip(errors, errors[1:])), "error must fall with refinement"
    assert errors[-1] < 0.01


def test_bishop_frames_orthonormal_adapted_and_parallel_transported():
    groom = mixed_groom()
    sim = th.Simulator(groom, th.Material(ellipticity=1.6), twist="quasistatic")
    sim.set_positions(perturbed(sim.positions(), 2e-3, seed=6))
    sim.update_twist()
    f = sim.frames()
    theta = sim.material_angles()
    for s in range(groom.n_strands):
        ne = groom.node_counts[s] - 1
        u, v, t, m1, m2 = (f[k][s, :ne] for k in ("u", "v", "t", "m1", "m2"))
        for a, b in ((u, t), (v, t), (u, v), (m1, t), (m2, t), (m1, m2)):
            assert np.abs(np.sum(a * b, axis=1)).max() < 1e-12
        for a in (u, v, m1, m2):
            assert np.abs(np.linalg.norm(a, axis=1) - 1).max() < 1e-12
        assert np.abs(np.cross(t, u) - v).max() < 1e-12
        c, sn = np.cos(theta[s, :ne])[:, None], np.sin(theta[s, :ne])[:, None]
        assert np.abs(m1 - (c * u + sn * v)).max() < 1e-12
        assert np.abs(m2 - (-sn * u + c * v)).max() < 1e-12
        for j in range(1, ne):  # u^j is u^{j-1} turned by the rotation taking t^{j-1} to t^j
            axis = np.cross(t[j - 1], t[j])
            angle = np.arctan2(np.linalg.norm(axis), t[j - 1] @ t[j])
            expected = rotation_matrix(axis, angle) @ u[j - 1]
            assert np.abs(expected - u[j]).max() < 1e-10


def test_quasistatic_twist_reaches_equilibrium():
    groom = mixed_groom()
    sim = th.Simulator(groom, th.Material(ellipticity=1.6), twist="quasistatic")
    sim.set_positions(perturbed(sim.positions(), 3e-3, seed=7))
    before = np.abs(sim.theta_gradient()[:, 1:]).max()
    report = sim.update_twist()
    after = sim.theta_gradient()
    assert report["iterations"] < sim.twist_iterations
    for s in range(groom.n_strands):
        free = after[s, 1: groom.node_counts[s] - 1]
        assert np.abs(free).max() < 1e-9 * before


def stiff_axis_bending_energy(sim):
    """sum_i 1/(4 l_i) sum_j EI1 (w1 - wbar1)^2, w1 = kb . m2, from numpy copies of the frames."""
    f = sim.frames()
    rest = sim.model.rest_kappa.to_numpy()
    voronoi = sim.model.voronoi.to_numpy()
    ei1 = sim.model.materials[0].bending_stiffness[0]
    total = 0.0
    for s in range(sim.n_strands):
        for i in range(1, sim.groom.node_counts[s] - 1):
            w_prev = f["kb"][s, i] @ f["m2"][s, i - 1] - rest[s, i, 0]
            w_next = f["kb"][s, i] @ f["m2"][s, i] - rest[s, i, 2]
            total += ei1 * (w_prev**2 + w_next**2) / (4 * voronoi[s, i])
    return total


def test_kmoch_keeps_elliptic_curls_bending_about_the_soft_axis():
    groom = th.Groom.curly(length=0.2, n_nodes=40, curl_radius=0.008, curl_pitch=0.015)
    sim = th.Simulator(groom, th.Material(ellipticity=1.6), twist="kmoch")
    # a deformed curl: stretch it along its axis and shear it sideways
    x = sim.positions()
    depth = x[..., 2] - x[0, 0, 2]
    deformed = x.copy()
    deformed[..., 2] += 0.3 * depth
    deformed[..., 0] += 0.2 * depth
    sim.set_positions(deformed)
    sim.set_material_angles(np.zeros_like(sim.material_angles()))
    at_zero = stiff_axis_bending_energy(sim)
    sim.update_twist()
    with_kmoch = stiff_axis_bending_energy(sim)
    print(f"stiff-axis bending energy: angles at zero {at_zero:.3e} J, kmoch {with_kmoch:.3e} J")
    assert at_zero > 0
    assert with_kmoch <= at_zero
    assert with_kmoch < 0.1 * at_zero


# ---- rotation_scalars' series branch against its closed form, to 50 digits ----------------------
ROTATION_SCALARS_SCRIPT = """
import json, sys
import taichi as ti
import taichi_hair as th
th.init(arch="cpu", precision=sys.argv[1])
from taichi_hair.rods.rod import SERIES_BELOW, rotation_scalars

@ti.kernel
def scalars(args: ti.types.ndarray(dtype=ti.f64, ndim=2), out: ti.types.ndarray(dtype=ti.f64, ndim=2)):
    for k in range(args.shape[0]):
        G, P, Q, Z = rotation_scalars(args[k, 0], args[k, 1], args[k, 2], ti.static(SERIES_BELOW["float64"]))
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = G, P, Q, Z
"""


def closed_form_scalars(a2, sn, c):
    """(G, P, Q, Z) of rods/rod.py rotation_scalars from their closed forms, in 60-digit decimal
    arithmetic (atan by its Taylor series, x = rho / c < 1): free of the cancellation that makes
    the code switch to its series, and of the code's coefficient tables."""
    from decimal import Decimal, getcontext
    getcontext().prec = 60
    a2, sn, c = Decimal(a2), Decimal(sn), Decimal(c)
    rho2 = a2 + sn * sn
    rho = rho2.sqrt()
    x = rho / c
    atan, term, n = Decimal(0), x, 0
    while abs(term) > Decimal(10) ** -58:
        term = x ** (2 * n + 1) / (2 * n + 1) * (-1 if n % 2 else 1)
        atan += term
        n += 1
    G = 2 * atan / rho
    P = (1 - G * c / 2) / rho2
    Q = (c / (rho2 + c * c) - G / 2) / rho2
    Z = (G / 4 - 3 * P * c / 2) / rho2
    return [float(v) for v in (G, P, Q, Z)]


def rotation_scalar_cases(limit):
    """(a2, sn, c) with x = rho / c from 1e-4 to just under `limit` (the series branch)."""
    cases = []
    for x in (1e-4, 1e-2, 0.05, 0.5 * limit, 0.99 * limit):
        for c in (1.0, 0.8):
            for share in (0.0, 0.5, 1.0):  # of rho^2 in the bend (a2) vs the twist (sn^2)
                rho2 = (x * c) ** 2
                sn = np.sqrt((1 - share) * rho2)
                cases.append((share * rho2, float(sn), c))
    return np.array(cases)


def _scalar_errors(values, cases):
    exact = np.array([closed_form_scalars(*row) for row in cases])
    return np.abs(values - exact) / np.abs(exact)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_rotation_scalars_series_branch_matches_closed_form_in_float64(precision, tmp_path):
    """rotation_scalars called with float64 arguments (as the implicit step calls it in both
    precisions) agrees with the closed forms to float64 rounding across its series branch.
    In a float32 build horner started from a literal 0.0 and added literal coefficients, both
    float32, and the branch switched at float32's threshold: the series came out with float32's
    error (measured 5e-8 relative) and Taichi warned "Assign may lose precision". Run in a
    subprocess in each precision; the compile log must not mention precision either."""
    from taichi_hair.rods.rod import SERIES_BELOW
    cases = rotation_scalar_cases(SERIES_BELOW["float64"])
    script = ROTATION_SCALARS_SCRIPT + f"""
import json
import subprocess
import sys

import numpy as np
args = np.array({cases.tolist()!r})
out = np.zeros((len(args), 4))
scalars(args, out)
print(json.dumps(out.tolist()))
"""
    path = tmp_path / "scalars.py"  # a file: Taichi reads a kernel's source
    path.write_text(script)
    done = subprocess.run([sys.executable, str(path), precision], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "warning" not in done.stderr.lower(), done.stderr[-2000:]
    errors = _scalar_errors(np.array(json.loads(done.stdout.strip().splitlines()[-1])), cases)
    print(f"\n{precision} build, float64 call: largest relative error of (G, P, Q, Z) {errors.max(axis=0)}")
    assert errors.max() < 1e-13
