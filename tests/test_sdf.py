"""Signed-distance grids against an analytic sphere, the exact brute-force distance, a linear
field (layout and trilinear weights) and the default head."""

import time

import numpy as np
import pytest

from taichi_hair.world.headmesh import default_head, icosphere
from taichi_hair.world.sdf import SignedDistanceGrid, mesh_signed_distance

R = 0.1
SPACING = 0.008


@pytest.fixture(scope="module")
def sphere():
    v, f = icosphere(4)
    v = v * R
    return v, f, SignedDistanceGrid.from_mesh(v, f, spacing=SPACING, padding=0.03)


def test_sphere_values_and_signs(sphere):
    v, f, grid = sphere
    p = np.random.default_rng(0).uniform(grid.origin, grid.upper, (20000, 3))
    exact = np.linalg.norm(p, axis=1) - R
    got = grid.sample(p)
    assert np.abs(got - exact).max() < SPACING / 2
    assert np.abs(got - exact).mean() < SPACING / 20
    away = np.abs(exact) > SPACING
    assert np.all(np.sign(got[away]) == np.sign(exact[away]))
    assert (exact[away] < 0).sum() > 1000 and (exact[away] > 0).sum() > 1000  # both sides tested


def test_grid_points_match_brute_force_distance(sphere):
    v, f, grid = sphere
    rng = np.random.default_rng(1)
    idx = np.stack([rng.integers(0, n, 2000) for n in grid.shape], axis=1)
    points = grid.origin + grid.spacing * idx
    exact = mesh_signed_distance(points, v, f)
    # the brute force is exact: only the polygon's sagitta separates it from the sphere, at most
    # R minus the smallest distance from the centre to a face plane
    a, n = v[f[:, 0]], np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    sagitta = R - np.min(np.abs(np.einsum("ij,ij->i", a, n)) / np.linalg.norm(n, axis=1))
    assert 0 < sagitta < 2e-4
    assert np.abs(exact - (np.linalg.norm(points, axis=1) - R)).max() <= sagitta + 1e-12
    got = grid.values[tuple(idx.T)]
    assert np.all(np.sign(got) == np.sign(exact))
    band = np.abs(exact) < SPACING  # exact nearest triangle within a cell of the surface
    assert band.sum() > 100
    np.testing.assert_allclose(got[band], exact[band], atol=1e-12)
    # farther out the propagated triangle may not be the nearest: |value| never below the truth
    assert np.all(np.abs(got) >= np.abs(exact) - 1e-12)
    assert np.abs(got - exact).max() < 0.2 * SPACING and np.abs(got - exact).mean() < 0.01 * SPACING


def test_gradient_is_radial_away_from_the_surface(sphere):
    v, f, grid = sphere
    p = np.random.default_rng(2).uniform(grid.origin, grid.upper, (5000, 3))
    r = np.linalg.norm(p, axis=1)
    keep = (np.abs(r - R) > 2 * SPACING) & (r > 3 * SPACING)  # off the surface band and the centre
    g = grid.gradient(p[keep])
    err = np.linalg.norm(g - p[keep] / r[keep, None], axis=1)
    assert np.median(err) < 0.05 and np.quantile(err, 0.99) < 0.2  # O(spacing / radius)
    far = np.array([[1.0, 0.0, 0.0]])  # beyond the box: value and gradient keep growing outward
    assert grid.sample(far)[0] == pytest.approx(1.0 - R, abs=0.01)
    np.testing.assert_allclose(grid.gradient(far)[0], [1.0, 0.0, 0.0], atol=0.05)


def test_layout_and_trilinear_weights_on_a_linear_field():
    origin, h, shape = np.array([-0.1, 0.2, 0.05]), 0.01, (5, 7, 4)
    a, b = np.array([0.3, -0.7, 1.1]), 0.02
    ijk = np.stack(np.meshgrid(*(np.arange(n) for n in shape), indexing="ij"), axis=-1)
    grid = SignedDistanceGrid(values=(origin + h * ijk) @ a + b, origin=origin, spacing=h)
    np.testing.assert_allclose(grid.sample(origin + h * np.array([[2, 3, 1]])), grid.values[2, 3, 1], atol=1e-15)
    p = np.random.default_rng(3).uniform(grid.origin, grid.upper, (500, 3))
    np.testing.assert_allclose(grid.sample(p), p @ a + b, atol=1e-14)  # trilinear is exact on linear fields
    np.testing.assert_allclose(grid.gradient(p), np.tile(a, (500, 1)), atol=1e-12)


def test_default_head_grid_signs_volume_and_build_time(monkeypatch):
    monkeypatch.setenv("TAICHI_HAIR_CACHE", "off")  # the build itself, not a cached entry
    head = default_head(4)
    start = time.perf_counter()
    grid = SignedDistanceGrid.from_mesh(head.vertices, head.faces, spacing=0.004, padding=0.02)
    assert time.perf_counter() - start < 20.0
    assert grid.sample(np.zeros((1, 3)))[0] < -0.06
    far = np.array([[0.3, 0, 0], [0, -0.3, 0], [0, 0, 0.3], [0.2, 0.2, -0.2]])
    assert np.all(grid.sample(far) > 0.1)
    inside_volume = (grid.values < 0).sum() * grid.spacing ** 3
    assert inside_volume == pytest.approx(head.volume(), rel=0.03)  # voxel count vs divergence theorem
    on_surface = grid.sample(head.vertices)
    assert np.abs(on_surface).max() < 0.5 * grid.spacing


def test_open_or_inconsistent_meshes_are_refused():
    v, f = icosphere(1)
    with pytest.raises(ValueError, match="closed"):
        SignedDistanceGrid.from_mesh(v, f[1:])
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]
    with pytest.raises(ValueError, match="orientation"):
        SignedDistanceGrid.from_mesh(v, flipped)
    with pytest.raises(ValueError, match="spacing"):
        SignedDistanceGrid.from_mesh(v, f, spacing=0.0)
    with pytest.raises(ValueError, match="padding"):
        SignedDistanceGrid.from_mesh(v, f, padding=-1.0)
    with pytest.raises(ValueError, match="points"):
        SignedDistanceGrid.from_mesh(v, f, spacing=0.5).sample(np.zeros(3))
