"""Head collisions, wind, touch, hair-hair interaction and stage selection."""

import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

import taichi_hair as th
from helpers import rotation_matrix
from taichi_hair.solver.step.plan import STALL_BELOW

RADII = np.array([0.08, 0.1, 0.115])


def ellipsoid_groom(n_strands, n_nodes=32, length=0.25, seed=0, droop=0.0):
    """Straight strands from the upper half of the RADII ellipsoid, growing along the surface
    normal (tilted down by `droop`), their root a hair's breadth above the surface."""
    k = np.arange(n_strands) + 0.5
    z = 1.0 - 0.95 * k / n_strands  # the upper cap
    phi = np.pi * (1 + 5**0.5) * k + seed
    r = np.sqrt(1 - z * z)
    unit = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    roots = unit * RADII
    normals = roots / RADII**2
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    directions = normals + droop * np.array([0, 0, -1.0])
    roots = roots + 0.003 * normals
    return th.Groom.straight(roots=roots, directions=directions, length=length, n_nodes=n_nodes)


def quiet(factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return factory()


def shake(t):
    """3 Hz, +-60 degrees about the vertical: a violent head shake."""
    return rotation_matrix([0, 0, 1], np.radians(60) * np.sin(2 * np.pi * 3.0 * t)), np.zeros(3)


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_violent_shake_never_enters_the_head_and_roots_follow():
    groom = ellipsoid_groom(200)
    head = th.Head.ellipsoid(radii=tuple(RADII), margin=0.002, friction=0.3)
    scene = th.Scene(groom=groom, head=head, motion=shake, drag=5e-4)
    sim = quiet(lambda: th.Simulator.from_scene(scene, dt=1e-3))
    rest_roots = groom.positions[:, :1]  # the clamped root node
    deepest, root_error = np.inf, 0.0
    for _ in range(2000):
        sim.step(1)
        rotation, translation = shake(sim.time)
        x = sim.positions()
        local = (x - translation) @ rotation  # head coordinates: R^T (x - t)
        implicit = np.sum((local / RADII) ** 2, axis=2)  # < 1 inside the ellipsoid
        deepest = min(deepest, implicit[:, 1:].min())
        root_error = max(root_error, np.abs(x[:, :1] - (rest_roots @ rotation.T + translation)).max())
    print(f"\nshake: smallest (x/a)^2+(y/b)^2+(z/c)^2 over free nodes {deepest:.4f} (1 = surface); "
          f"root error {root_error:.1e} m; stats {sim.stats()}")
    assert deepest >= 1.0  # outside the surface itself, not only within the margin
    assert root_error < 1e-12


def hang_and_measure(interaction, seconds=1.2):
    groom = ellipsoid_groom(250, n_nodes=20, length=0.25, droop=2.0)  # combed down the head
    scene = th.Scene(groom=groom, head=th.Head.ellipsoid(radii=tuple(RADII)), drag=3e-3,
                     hair_interaction=interaction)
    sim = quiet(lambda: th.Simulator.from_scene(scene, dt=1e-3))
    sim.run(seconds, progress=False)
    x = sim.positions()
    # volume measures: mean distance of free nodes from the head's surface (implicit radius),
    # and the number of occupied 1 cm voxels
    local = np.linalg.norm(x[:, 1:] / RADII, axis=2)
    voxels = len({tuple(v) for v in np.floor(x.reshape(-1, 3) / 0.01).astype(int)})
    return float(local.mean()), voxels


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_hair_interaction_keeps_volume():
    off = hang_and_measure(None)
    on = hang_and_measure(th.HairInteraction(cell_size=0.02, repulsion=2.0, friction=5.0))
    print(f"\nmean implicit radius of free nodes: off {off[0]:.4f}, on {on[0]:.4f}; "
          f"occupied 1 cm voxels: off {off[1]}, on {on[1]}")
    assert on[0] > off[0] + 0.01
    assert on[1] > 1.05 * off[1]


def hanging_curtain(n=9, spacing=0.05, n_nodes=16, length=0.3):
    roots = np.stack([spacing * (np.arange(n) - (n - 1) / 2), np.zeros(n), np.zeros(n)], axis=1)
    return th.Groom.straight(roots=roots, directions=np.tile([0, 0, -1.0], (n, 1)), length=length,
                             n_nodes=n_nodes)


def tip_offsets(**scene_options):
    groom = hanging_curtain()
    sim = quiet(lambda: th.Simulator.from_scene(th.Scene(groom=groom, **scene_options), dt=1e-3))
    samples = []
    for _ in range(60):
        sim.step(25)
        samples.append(sim.positions()[:, -1] - groom.positions[:, -1])
    return np.array(samples[20:])  # after the first 0.5 s


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_wind_deflects_hair_downwind_more_at_higher_speed():
    gentle = tip_offsets(wind=(2.0, 0.0, 0.0), drag=1e-5)
    strong = tip_offsets(wind=(5.0, 0.0, 0.0), drag=1e-5)
    print(f"\nmean downwind tip offset: 2 m/s {gentle[..., 0].mean():.4f} m, "
          f"5 m/s {strong[..., 0].mean():.4f} m")
    assert gentle[..., 0].mean() > 0.005
    assert strong[..., 0].mean() > 1.5 * gentle[..., 0].mean()
    gusty = tip_offsets(wind=th.Wind(velocity=(3.0, 0, 0), gust_amplitude=0.8, gust_frequency=1.0),
                        drag=3e-5)
    steady = tip_offsets(wind=(3.0, 0.0, 0.0), drag=3e-5)
    variation = gusty[..., 0].std(axis=0).mean(), steady[..., 0].std(axis=0).mean()
    print(f"tip offset std in time: gusty {variation[0]:.4f} m, steady {variation[1]:.4f} m")
    assert variation[0] > 2 * variation[1]


def test_turbulence_field_is_divergence_free_and_has_its_rms():
    wind = th.Wind(velocity=(1.0, 0, 0), turbulence=0.5, turbulence_scale=0.1, seed=3)
    rng = np.random.default_rng(0)
    p = rng.uniform(-0.3, 0.3, (2000, 3))
    u = wind.at(p, 0.7) - np.array([1.0, 0, 0])
    rms = np.sqrt(np.mean(np.sum(u**2, axis=1)))
    h = 1e-5
    div = sum((wind.at(p + h * e, 0.7)[:, k] - wind.at(p - h * e, 0.7)[:, k]) / (2 * h)
              for k, e in enumerate(np.eye(3)))
    print(f"\nturbulence rms {rms:.3f} m/s (asked 0.5); max |div u| {np.abs(div).max():.2e} 1/s")
    assert 0.35 < rms < 0.65
    assert np.abs(div).max() < 1e-6 * np.abs(u).max() / 0.1


def hand_path(t):
    """Sweeps along +y through the curtain's middle strands, 10 cm below the roots."""
    return np.array([0.0, -0.15 + 0.5 * t, -0.15])


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_hand_moves_the_hair_it_touches_and_no_other():
    groom = hanging_curtain()
    baseline = quiet(lambda: th.Simulator(groom, th.Material(), drag=5e-4))
    touched = quiet(lambda: th.Simulator(groom, th.Material(), drag=5e-4,
                                         touch=(th.Hand(path=hand_path, radius=0.03),)))
    inside = 0.0
    for _ in range(40):
        baseline.step(15)
        touched.step(15)
        x = touched.positions()
        inside = max(inside, 0.03 - np.linalg.norm(x[:, 1:] - hand_path(touched.time), axis=2).min())
    moved = np.abs(touched.positions() - baseline.positions()).max(axis=(1, 2))
    print(f"\nhand: displacement per strand vs untouched run [m]: {np.round(moved, 4)}; "
          f"deepest node inside the hand {inside:.2e} m")
    assert moved[4] > 0.02  # the middle strand was pushed
    assert moved[0] < 1e-9 and moved[-1] < 1e-9  # 20 cm away: untouched
    assert inside <= 0.0


def test_grab_pulls_nearby_nodes_toward_a_moving_point():
    groom = hanging_curtain()
    point = lambda t: np.array([0.0, 0.05 * t, -0.28]) + np.array([0.0, 0.0, 0.0])
    tool = th.Grab(path=point, radius=0.04, stiffness=0.02)
    sim = quiet(lambda: th.Simulator(groom, th.Material(), drag=5e-4, touch=(tool,)))
    # the same substeps as the grab's bound gives the grabbing run: untouched strands step alike
    free = quiet(lambda: th.Simulator(groom, th.Material(), drag=5e-4, dt=sim.dt / sim.substeps))
    sim.run(1.0, progress=False)
    free.run(1.0, progress=False)
    moved = np.abs(sim.positions() - free.positions()).max(axis=(1, 2))
    tip = sim.positions()[4, -1]
    print(f"\ngrab: middle tip {tip}, grab point {point(sim.time)}; per-strand change {np.round(moved, 4)}")
    assert tip[1] > 0.01  # followed the point along +y
    assert moved[0] < 1e-9 and moved[-1] < 1e-9


def test_unused_stages_are_not_compiled():
    """In a fresh process: a bare scene compiles the fused kernel without contact, wind-field or
    touch code and never compiles the interaction kernels; a full scene compiles them."""
    code = textwrap.dedent("""
        import json, warnings, numpy as np, taichi_hair as th
        from taichi_hair.solver.step import fused as step
        from taichi_hair.solver import interaction
        warnings.simplefilter("ignore")
        th.init(precision="float64")
        groom = th.Groom.straight(length=0.1, n_nodes=11, roots=[[0, 0, 0.1]], directions=[[0, 0, 1]])
        th.Simulator(groom, th.Material(), gravity=(0, 0, 0)).step(3)
        bare = step.compiled_variants()
        bare_grid = len(interaction.splat._primal.mapper.mapping)
        scene = th.Scene(groom=groom, head=th.Head.sphere(radius=0.09), wind=th.Wind(turbulence=0.2),
                         touch=(th.Hand(path=lambda t: np.array([0.0, 0, 0.3])),),
                         hair_interaction=th.HairInteraction())
        full = th.Simulator.from_scene(scene)
        full.step(2)
        th.Simulator.from_scene(th.Scene(groom=groom, head=th.Head.sphere(radius=0.09))).step(2)
        print(json.dumps({"bare": bare, "bare_grid": bare_grid, "all": step.compiled_variants(),
                          "grid": len(interaction.splat._primal.mapper.mapping)}))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    import json
    result = json.loads(out.stdout[out.stdout.index("{"):])
    assert result["bare"] and all(not v["contacts"] and not v["wind_field"] and not v["touch"]
                                  and not v["external"] for v in result["bare"])
    assert result["bare_grid"] == 0
    assert any(v["contacts"] for v in result["all"]) and result["grid"] == 1


def test_scene_validation_names_the_parameter():
    groom = hanging_curtain()
    with pytest.raises(ValueError, match="motion"):
        th.Scene(groom=groom, motion="shake")
    with pytest.raises(ValueError, match="wind"):
        th.Scene(groom=groom, wind=(1.0, 2.0))
    with pytest.raises(ValueError, match="touch"):
        th.Scene(groom=groom, touch=("hand",))
    with pytest.raises(ValueError, match="radius"):
        th.Hand(path=hand_path, radius=-1.0)
    with pytest.raises(ValueError, match="radii"):
        th.Ellipsoid(radii=(0.1, 0.0, 0.1))
    with pytest.raises(ValueError, match="drag"):
        th.Simulator(groom, th.Material(), wind=(1.0, 0, 0))
    with pytest.raises(ValueError, match="cell_size"):
        th.HairInteraction(cell_size=0.0)


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_default_head_mesh_keeps_hair_out_while_shaking():
    """The mesh head (distance grid) against the exact distance to its triangles."""
    from taichi_hair.world.motion import Shake
    from taichi_hair.hair.roots import scalp_groom
    from taichi_hair.world.sdf import mesh_signed_distance
    head = th.Head.default()
    model = head.model
    groom = scalp_groom(model, 40, style="wavy", length=0.2, n_nodes=24,
                        collider=head.colliders[0].grid, seed=2)
    motion = Shake(amplitude_deg=60, frequency_hz=3)
    sim = quiet(lambda: th.Simulator.from_scene(th.Scene(groom=groom, head=head, motion=motion), dt=1e-3))
    closest = np.inf
    for _ in range(6):
        sim.step(50)
        rotation, translation = sim.head_transform
        local = (sim.positions()[:, 1:].reshape(-1, 3) - translation) @ rotation
        closest = min(closest, mesh_signed_distance(local, model.vertices, model.faces).min())
    print(f"\nmesh head: closest free node to the exact surface {closest * 1e3:.2f} mm (margin 2 mm)")
    assert closest > 0.0


@pytest.mark.parametrize("friction", [0.3, 0.7])
def test_strand_on_an_inclined_plane_slides_at_coulombs_rate_or_holds(friction):
    """A free straight strand lying across a plane tilted by 30 degrees: with friction below
    tan 30 = 0.577 it slides down the slope at g (sin a - friction cos a) (2.36 m/s^2 at 0.3;
    within 2 % over 0.3 s), above it it stays put (under a micrometre)."""
    tilt = np.radians(30.0)
    normal = np.array([-np.sin(tilt), 0.0, np.cos(tilt)])
    down = np.array([-np.cos(tilt), 0.0, -np.sin(tilt)])  # along the slope
    margin = 0.002
    nodes = np.stack([np.zeros(11), np.linspace(0.0, 0.1, 11), np.zeros(11)], axis=1) + margin * normal
    plane = th.Plane(point=(0.0, 0.0, 0.0), normal=tuple(normal), margin=margin, friction=friction)
    sim = quiet(lambda: th.Simulator(th.Groom.from_polylines(nodes[None]), th.Material(), root="free",
                                     colliders=(plane,), dt=1e-3))
    seconds = 0.3
    sim.step(int(round(seconds / sim.dt)))
    travelled = (sim.positions()[0] - nodes) @ down
    expected = 0.5 * 9.81 * max(0.0, np.sin(tilt) - friction * np.cos(tilt)) * seconds ** 2
    if expected > 0:
        assert np.allclose(travelled, expected, rtol=2e-2)
    else:
        assert np.abs(travelled).max() < 1e-6
    assert np.abs((sim.positions()[0] - nodes) @ normal).max() < 1e-6  # on the plane, at the margin


# ---- a root on or inside a collider's surface ------------------------------------------------

@pytest.mark.parametrize("head", [th.Head.sphere(radius=0.1), th.Head.ellipsoid(radii=(0.1, 0.1, 0.1))],
                         ids=["sphere", "ellipsoid"])
@pytest.mark.parametrize("root", ["clamped", "pinned"])
def test_root_on_the_surface_keeps_the_head_collider(head, root):
    groom = th.Groom.straight(roots=[[0, 0, 0.1]], directions=[[1, 0, 0]], length=0.3, n_nodes=31)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no collider is skipped, so nothing to warn about
        sim = th.Simulator.from_scene(th.Scene(groom=groom, head=head), dt=1e-3, root=root)
    sim.run(0.5, progress=False)
    free = sim.positions()[0, 2 if root == "clamped" else 1:]
    depth = np.linalg.norm(free, axis=1) - 0.1
    # a root on the surface that dropped the head as a collider lets 11 (clamped) / 13 (pinned)
    # nodes sink 1.5 / 3.5 cm into it in 1 s
    assert np.count_nonzero(depth < 0) == 0, f"{np.count_nonzero(depth < 0)} nodes inside, deepest {depth.min():.3g} m"
    # and out to the margin, less what the length-only iterations that finish a projection in
    # contact may move a node: STALL_BELOW x its edge (1e-5 m here; measured 4e-8 / 2.1e-7 m)
    assert depth.min() > 0.002 - STALL_BELOW * 0.01
    assert sim.skipped_colliders == []


def test_root_deep_inside_a_collider_skips_it_with_a_warning():
    """A groom rooted 5 mm inside a neck capsule (margin 2 mm) does not collide with the capsule,
    and says so; a root 1 mm inside (within the margin) keeps it."""
    groom = th.Groom.straight(roots=[[0, 0, 0.045], [0.02, 0, 0.045]], directions=[[1, 0, 0], [1, 0, 0]],
                              length=0.1, n_nodes=11)
    neck = th.Capsule(p0=(0, 0, 0), p1=(0, 0, -0.2), radius=0.05, margin=0.002)
    with pytest.warns(RuntimeWarning, match=r"inside Capsule \(colliders\[0\]\) by more than its margin"):
        sim = th.Simulator(groom, th.Material(), colliders=(neck,), gravity=(0, 0, 0))
    assert sim.skipped_colliders == [(0, 0)]


# ---- touch tools compile cleanly -------------------------------------------------------------

def test_touch_tools_compile_without_division_warnings():
    script = textwrap.dedent("""
        import taichi_hair as th
        th.init(arch="cpu", precision="float64", offline_cache=False)  # compile for real
        groom = th.Groom.straight(roots=[[0, 0, 0]], directions=[[0, 0, -1]], length=0.1, n_nodes=11)
        tools = (th.Grab(path=lambda t: (0.0, 0.02, -0.05)), th.Hand(path=lambda t: (0.0, -0.05, -0.05)))
        sim = th.Simulator(groom, th.Material(), dt=2e-4, touch=tools)
        sim.step(2)
        print(sim.time)
        """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert float(done.stdout.split()[-1]) == pytest.approx(4e-4)
    # a hand sent through the ellipsoid branch with zero radii compiles 12 "Potential division by 0" warnings
    assert done.stderr.count("division by 0") == 0, done.stderr[-3000:]
