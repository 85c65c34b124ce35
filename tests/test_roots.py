"""Scalp roots are blue noise on the scalp triangles; grooms grown from them leave the head."""

import math

import numpy as np
import pytest

from taichi_hair.rods.groom import Groom
from taichi_hair.world.headmesh import default_head
from taichi_hair.hair.roots import sample_scalp, scalp_groom
from taichi_hair.world.sdf import SignedDistanceGrid, mesh_signed_distance


@pytest.fixture(scope="module")
def head():
    return default_head(3)


@pytest.fixture(scope="module")
def collider(head):
    return SignedDistanceGrid.from_mesh(head.vertices, head.faces, spacing=0.008)


def distance_to_triangles(points, tri):
    """Smallest distance [M] from points to the planes of the triangles tri [T, 3, 3] that
    contain their projection (inf when none does): a brute force independent of the sampler."""
    a, ab, ac = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(ab, ac)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    w = points[:, None] - a[None]  # [M, T, 3]
    m = np.stack([ab, ac], axis=2)  # [T, 3, 2]
    coef = np.einsum("tij,mtj->mti", np.linalg.pinv(m), w)  # least-squares barycentrics
    inside = (coef >= -1e-9).all(axis=2) & (coef.sum(axis=2) <= 1 + 1e-9)
    plane = np.abs(np.einsum("mtk,tk->mt", w, n))
    return np.where(inside, plane, np.inf).min(axis=1)


def test_points_lie_on_scalp_triangles_with_outward_normals(head):
    p, n = sample_scalp(head, 150, seed=3)
    tri = head.vertices[head.faces[head.scalp_faces()]]
    assert distance_to_triangles(p, tri).max() < 1e-12
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    # outward: the nearest face normal agrees, and a step along n leaves the head
    centroids = head.vertices[head.faces].mean(axis=1)
    nearest = np.argmin(((p[:, None] - centroids[None]) ** 2).sum(axis=2), axis=1)
    assert np.all(np.einsum("ij,ij->i", n, head.face_normals()[nearest]) > 0.8)
    assert np.all(mesh_signed_distance(p + 0.002 * n, head.vertices, head.faces) > 0.001)


def test_blue_noise_spacing_and_determinism(head):
    n = 200
    p, _ = sample_scalp(head, n, seed=7)
    area = head.face_areas()[head.scalp_faces()].sum()
    mean_spacing = math.sqrt(area / n)
    d = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(n)
    assert d.min() > 0.5 * mean_spacing  # no clumps
    # white noise of the same size would put some pair far closer: the check is not vacuous
    rng = np.random.default_rng(0)
    tri = head.vertices[head.faces[head.scalp_faces()]]
    pick = rng.choice(len(tri), n, p=head.face_areas()[head.scalp_faces()] / area)
    white = tri[pick].mean(axis=1)
    dw = np.linalg.norm(white[:, None] - white[None], axis=2) + np.eye(n)
    assert dw.min() < 0.5 * mean_spacing
    q, _ = sample_scalp(head, n, seed=7)
    np.testing.assert_array_equal(p, q)
    r, _ = sample_scalp(head, n, seed=8)
    assert not np.allclose(p, r)
    with pytest.raises(ValueError, match="min_distance"):
        sample_scalp(head, n, seed=7, min_distance=2 * mean_spacing)
    sample_scalp(head, n, seed=7, min_distance=0.5 * mean_spacing)


@pytest.mark.parametrize("style", ["straight", "wavy", "curly"])
def test_groom_strands_leave_the_head(head, collider, style):
    n_guides, n_nodes, length, variation = 60, 24, 0.2, 0.1
    groom = scalp_groom(head, n_guides, style=style, length=length, length_variation=variation,
                        n_nodes=n_nodes, collider=collider, seed=2)
    assert isinstance(groom, Groom)
    assert groom.n_strands == n_guides and np.all(groom.node_counts == n_nodes)
    lengths = groom.lengths()
    assert np.all(lengths <= length * (1 + variation) + 1e-9)
    assert np.all(lengths >= length * (1 - variation) - 1e-9)
    # every edge of a strand is its length / (n_nodes - 1): the explicit step's bound goes with
    # the shortest edge squared (equal arcs left chords up to 20 % short where the curve turns)
    edges = np.linalg.norm(np.diff(groom.positions, axis=1), axis=2)
    np.testing.assert_allclose(edges, (lengths / (n_nodes - 1))[:, None].repeat(n_nodes - 1, 1), rtol=1e-9)
    assert lengths.std() > 0.01 * length  # the variation is there
    roots, normals = sample_scalp(head, n_guides, seed=2)
    x = groom.positions
    np.testing.assert_allclose(x[:, 0], roots + 0.0005 * normals, atol=1e-12)
    root_edge = x[:, 1] - x[:, 0]
    assert np.all(np.einsum("ij,ij->i", root_edge, normals) > 0.5 * np.linalg.norm(root_edge, axis=1))
    first = x[:, :4].reshape(-1, 3)
    assert np.all(mesh_signed_distance(first, head.vertices, head.faces) > 0)
    # the comb (back, -y) and droop (down) pull the tips behind and below the roots
    assert np.mean(x[:, -1, 1] < x[:, 0, 1]) > 0.9 and np.mean(x[:, -1, 2] < x[:, 0, 2]) > 0.9
    assert np.mean(collider.sample(x.reshape(-1, 3)) < 0) < 0.01  # pushed out of the head


def test_styles_differ_and_are_deterministic(head):
    def turning(groom):
        e = np.diff(groom.positions, axis=1)
        e /= np.linalg.norm(e, axis=2, keepdims=True)
        return np.arccos(np.clip(np.einsum("snk,snk->sn", e[:, 1:], e[:, :-1]), -1, 1)).mean()
    kw = dict(n_nodes=48, seed=4)
    straight, wavy, curly = (scalp_groom(head, 20, style=s, **kw) for s in ("straight", "wavy", "curly"))
    assert turning(straight) < turning(wavy) < turning(curly)
    np.testing.assert_array_equal(curly.positions, scalp_groom(head, 20, style="curly", **kw).positions)


@pytest.mark.parametrize("kwargs, name", [
    (dict(style="frizzy"), "style"), (dict(length=0.0), "length"), (dict(length_variation=1.5), "length_variation"),
    (dict(n_nodes=2), "n_nodes"), (dict(comb=(0, 0, 0)), "comb"), (dict(comb_strength=-1), "comb_strength"),
    (dict(curl_pitch=0.0), "curl_pitch"), (dict(root_offset=-0.001), "root_offset"),
    (dict(collider="sdf"), "collider"), (dict(seed=-1), "seed"),
])
def test_bad_inputs_name_the_parameter(head, kwargs, name):
    with pytest.raises(ValueError, match=name):
        scalp_groom(head, 10, **kwargs)


def test_sample_scalp_bad_inputs(head):
    with pytest.raises(ValueError, match="n must be"):
        sample_scalp(head, 0)
    with pytest.raises(ValueError, match="head"):
        sample_scalp("head", 10)


def test_no_root_grows_under_the_neck(head):
    """Skin the neck capsule covers grows no hair: every root, blue-noise or uniform, lies
    outside each capsule by more than the colliders' default margin (2 mm), so no strand
    starts inside a collider it would then have to ignore."""
    for blue_noise in (True, False):
        points, _ = sample_scalp(head, 3000, seed=2, blue_noise=blue_noise)
        for p0, p1, radius in head.capsules:
            p0, p1 = np.asarray(p0), np.asarray(p1)
            axis = p1 - p0
            t = np.clip((points - p0) @ axis / (axis @ axis), 0.0, 1.0)
            gap = np.linalg.norm(points - (p0 + t[:, None] * axis), axis=1) - radius
            print(f"\nclosest root to a capsule surface: {gap.min() * 1e3:.2f} mm")
            assert gap.min() > 0.002
