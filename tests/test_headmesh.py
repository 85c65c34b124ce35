"""The default head: closed, outward, head-sized, with a scalp above the ears; OBJ I/O."""

import math

import numpy as np
import pytest

from taichi_hair.world.headmesh import (SEMI_AXES, HeadModel, default_head, icosphere, mesh_volume,
                                  read_obj_mesh, write_obj_mesh)


@pytest.fixture(scope="module")
def head():
    return default_head(4)


def directed_edges(faces):
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


@pytest.mark.parametrize("resolution", [2, 4])
def test_watertight_with_opposite_orientation(resolution):
    h = default_head(resolution)
    e = directed_edges(h.faces)
    keys = {tuple(x) for x in e.tolist()}
    assert len(keys) == len(e)  # no directed edge used twice (a twice would mean a flipped face)
    assert all((b, a) in keys for a, b in keys)  # every edge has its opposite: closed 2-manifold
    assert len(h.vertices) - len(e) // 2 + len(h.faces) == 2  # Euler characteristic of a sphere


def test_volume_against_closed_forms(head):
    a, b, c = SEMI_AXES
    u, f = icosphere(5)
    ellipsoid = mesh_volume(u * [a, b, c], f)
    assert ellipsoid == pytest.approx(4.0 / 3.0 * math.pi * a * b * c, rel=2e-3)  # divergence theorem
    assert head.volume() > 0
    assert head.volume() == pytest.approx(ellipsoid, rel=0.05)  # features add and take ~2 %


def test_normals_point_outward(head):
    centroids = head.vertices[head.faces].mean(axis=1)
    # the head is star-shaped about its centre: every outward normal faces away from it
    assert np.all(np.einsum("ij,ij->i", head.face_normals(), centroids) > 0)
    assert np.all(np.einsum("ij,ij->i", head.vertex_normals(), head.vertices) > 0)


def test_head_dimensions_and_face_direction(head):
    size = head.vertices.max(axis=0) - head.vertices.min(axis=0)
    assert 0.16 <= size[0] <= 0.20  # ear to ear, ears included
    assert 0.20 <= size[1] <= 0.24  # back of the head to the nose tip
    assert size[2] == pytest.approx(0.23, abs=0.005)
    nose = head.vertices[np.argmax(head.vertices[:, 1])]
    assert nose[1] > 0.11 and abs(nose[0]) < 0.005 and -0.05 < nose[2] < 0.0  # the face looks along +y


def test_scalp_covers_top_and_back_above_the_ears(head):
    s = head.vertices[head.scalp]
    assert 0.2 < head.scalp.mean() < 0.7
    assert np.mean(s[:, 2] > -0.02) > 0.85  # mostly above ear level
    assert head.vertices[np.argmax(head.vertices[:, 2])] in s  # the crown
    face = (head.vertices[:, 1] > 0.06) & (head.vertices[:, 2] < 0.04)
    assert face.any() and not np.any(head.scalp & face)  # no hair on the face
    area = head.face_areas()[head.scalp_faces()].sum()
    assert 0.04 < area < 0.07  # m^2; an adult scalp is ~0.06


def test_the_neck_capsule_hangs_below_the_head(head):
    (p0, p1, r), = head.capsules
    assert p1[2] < head.vertices[:, 2].min() < p0[2] and r > 0.04


def test_obj_round_trip_is_exact(head, tmp_path):
    path = tmp_path / "head.obj"
    write_obj_mesh(path, head.vertices, head.faces)
    v, f = read_obj_mesh(path)
    np.testing.assert_array_equal(v, head.vertices)
    np.testing.assert_array_equal(f, head.faces)
    assert f.dtype == np.int32


def test_obj_reader_polygons_negative_indices_and_ignored_lines(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text("# a quad and a triangle\nmtllib x.mtl\no thing\nv 0 0 0\nv 1 0 0\nv 1 1 0 1.0\n"
                    "v 0 1 0 0.5 0.5 0.5\nvt 0 0\nvn 0 0 1\ng group\ns off\nf 1/1/1 2/1/1 3//1 4\n"
                    "v 0 0 1\nf -1 -5 -4  # relative\n")
    v, f = read_obj_mesh(path)
    assert v.shape == (5, 3)
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3], [4, 0, 1]])


@pytest.mark.parametrize("text, match", [
    ("v 0 0\nf 1 1 1\n", ":1: a vertex needs three"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", ":4: a face needs at least 3"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", ":4: vertex index 4 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", ":4: vertex index 0 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", ":4: bad vertex index 'x'"),
    ("v 0 0 0\nv 1 0 nan\n", ":2: a vertex needs three finite"),
    ("v 0 0 0\nbogus 1\n", ":2: unknown OBJ statement 'bogus'"),
    ("v 0 0 0\n", "no faces"),
])
def test_obj_reader_names_the_bad_line(tmp_path, text, match):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_obj_mesh(path)


def test_bad_inputs_name_the_parameter(head):
    with pytest.raises(ValueError, match="resolution"):
        default_head(9)
    with pytest.raises(ValueError, match="scalp"):
        HeadModel(vertices=head.vertices, faces=head.faces, scalp=np.ones(3, bool))
    with pytest.raises(ValueError, match="faces"):
        HeadModel(vertices=head.vertices, faces=head.faces + 10**6, scalp=head.scalp)
    with pytest.raises(ValueError, match=r"capsules\[0\]: radius"):
        HeadModel(vertices=head.vertices, faces=head.faces, scalp=head.scalp, capsules=[((0, 0, 0), (0, 0, 1), -1)])
