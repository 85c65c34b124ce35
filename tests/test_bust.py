"""The default head's bust: a closed, outward mesh, the collider it draws, and hair resting on it
while the head turns above it."""

import warnings

import numpy as np
import pytest

import taichi_hair as th
from helpers import rotation_matrix
from taichi_hair.world.bust import BASE, NECK_TOP, default_bust, default_bust_grid
from taichi_hair.world.colliders import MeshCollider
from taichi_hair.world.headmesh import default_head, mesh_volume
from taichi_hair.world.sdf import mesh_signed_distance


def test_bust_is_closed_outward_and_bust_sized():
    vertices, faces = default_bust()
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    keys = {tuple(x) for x in e.tolist()}
    assert len(keys) == len(e)  # no directed edge twice: no flipped face
    assert all((b, a) in keys for a, b in keys)  # closed 2-manifold
    assert len(vertices) - len(e) // 2 + len(faces) == 2  # a sphere's Euler characteristic
    assert mesh_volume(vertices, faces) > 0.0  # outward
    width = np.ptp(vertices[:, 0])
    assert 0.33 < width < 0.42  # shoulder to shoulder [m], an adult's 0.36-0.41


def test_collider_is_the_drawn_bust_and_stays_in_the_world():
    head = th.Head.default()
    vertices, faces = head.body
    np.testing.assert_array_equal(vertices, default_bust()[0])
    grids = [c for c in head.colliders if isinstance(c, MeshCollider) and c.attached == "world"]
    assert len(grids) == 1 and grids[0].grid is default_bust_grid()
    # the grid's zero level is the drawn surface, away from the two end discs (whose rims a
    # trilinear grid rounds off: the top one is inside the neck capsule, the base out of reach)
    side = (vertices[:, 2] < NECK_TOP - 0.005) & (vertices[:, 2] > BASE + 0.01)
    gap = np.abs(grids[0].grid.sample(vertices[side]))
    print(f"\nbust grid at the drawn vertices: max |d| {gap.max() * 1e3:.2f} mm")
    assert gap.max() < 1e-3  # half the collision margin (2 mm)


@pytest.mark.parametrize("degrees", [0.0, 25.0, -40.0])
def test_the_head_shakes_on_the_bust_without_showing_a_seam(degrees):
    """The head's neck capsule turns with the head on the still bust: turned about the scenes'
    neck pivot by up to the shipped shakes' 40 degrees, the capsule's surface below z = -0.17 m
    lies inside the bust, and the bust's top inside the capsule: neither shows an edge."""
    (p0, p1, radius), = default_head().capsules
    p0, p1 = np.asarray(p0), np.asarray(p1)
    vertices, faces = default_bust()
    turn = rotation_matrix([0, 0, 1], np.radians(degrees))
    pivot = np.array([0.0, -0.01, -0.10])
    angles = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    ring = np.concatenate([p0 + t * (p1 - p0) + radius * np.stack([np.cos(angles), np.sin(angles), 0 * angles], 1)
                           for t in np.linspace(0.55, 1.0, 10)])
    capsule = (ring - pivot) @ turn.T + pivot
    capsule_out = mesh_signed_distance(capsule[capsule[:, 2] < -0.17], vertices, faces).max()
    top = (vertices[vertices[:, 2] > -0.15] - pivot) @ turn + pivot  # in the turned head's frame
    axis = p1 - p0
    t = np.clip((top - p0) @ axis / (axis @ axis), 0.0, 1.0)
    top_out = (np.linalg.norm(top - (p0 + t[:, None] * axis), axis=1) - radius).max()
    print(f"\nturned {degrees:.0f} deg: the capsule {-capsule_out * 1e3:.2f} mm inside the bust, "
          f"the bust's top {-top_out * 1e3:.2f} mm inside the capsule")
    assert capsule_out < 0.0 and top_out < 0.0


@pytest.mark.parametrize("turning", [pytest.param(False, marks=pytest.mark.slow), True])  # still: a long run
def test_hair_rests_on_the_shoulder_while_the_head_turns(turning):
    """Strands hanging from above the right shoulder fall onto it and stay outside the bust's
    exact surface, the head's grid colliding in the same pass (two distance grids); with the head
    turning, their roots sweep across the shoulder and the bust stays where it is drawn."""
    head = th.Head.default()
    x = np.linspace(0.08, 0.14, 4)
    roots = np.stack([x, np.full_like(x, -0.02), np.full_like(x, -0.16)], axis=1)
    groom = th.Groom.straight(roots=roots, directions=np.tile([0.3, 0.0, -1.0], (4, 1)),
                              length=0.16, n_nodes=17)
    motion = None
    if turning:
        motion = th.Shake(amplitude_deg=25, frequency_hz=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sim = th.Simulator.from_scene(th.Scene(groom=groom, head=head, motion=motion), dt=1e-3)
    vertices, faces = head.body
    closest, resting = np.inf, 0
    for _ in range(8):
        sim.step(60)
        free = sim.positions()[:, 1:].reshape(-1, 3)
        distance = mesh_signed_distance(free, vertices, faces)
        closest = min(closest, distance.min())
        resting = max(resting, int(np.sum(distance < 4e-3)))
    print(f"\nturning={turning}: closest free node to the bust {closest * 1e3:.2f} mm (margin 2 mm), "
          f"{resting} nodes resting on it")
    assert closest > 0.0
    assert resting >= 8  # they lie on the shoulder: without the bust they hang through it
