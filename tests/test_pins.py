"""Pins and clips on any node, and the pinned root: pendulum and catenary references, energy
across adding and releasing, moving and head-attached pins, compiled variants, bad input."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import taichi_hair as th
from helpers import rotation_matrix

# a thick, nearly limp strand: EI / (rho A g L^3) ~ 4e-7, so it behaves as a chain
CHAIN = th.Material(youngs_modulus=1e3, shear_modulus=3e2, radius=1e-3, density=1000.0)
LENGTH = 0.4
G = 9.81


def hanging(n_nodes=21, length=LENGTH):
    """One straight strand hanging from the origin along -z."""
    z = -np.linspace(0.0, length, n_nodes)
    return th.Groom.from_polylines(np.stack([np.zeros(n_nodes), np.zeros(n_nodes), z], axis=1))


def chain_modes(masses, links):
    """Small oscillations of a hanging chain: point masses masses[k] at the end of massless
    rigid links links[k] (k = 0 from the pivot down). With link angles phi, the horizontal
    displacement of mass i is sum_{k <= i} l_k phi_k, so T = 1/2 phi^T M phi with
    M_kl = l_k l_l sum_{i >= max(k, l)} m_i and V = 1/2 sum_k g l_k (sum_{i >= k} m_i) phi_k^2.
    Returns (angular frequencies [rad/s] ascending, link-angle mode shapes as columns)."""
    below = np.cumsum(masses[::-1])[::-1]  # mass hanging from link k
    n = len(masses)
    idx = np.maximum.outer(np.arange(n), np.arange(n))
    mass = np.outer(links, links) * below[idx]
    stiff = np.diag(G * links * below)
    w2, shapes = np.linalg.eig(np.linalg.solve(mass, stiff))
    order = np.argsort(w2.real)
    return np.sqrt(w2.real[order]), shapes.real[:, order]


def chain_shape(links, angles):
    """Node positions [n + 1, 3] (the pivot at the origin first) of links at angles from -z in x-z."""
    steps = links[:, None] * np.stack([np.sin(angles), np.zeros_like(angles), -np.cos(angles)], axis=1)
    return np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])


def pendulum(n_nodes=21, tip_angle_deg=5.0, **options):
    """A pinned-root limp strand displaced along its first chain mode (tip at tip_angle from
    the vertical), at rest. Returns (sim, reference period [s])."""
    sim = th.Simulator(hanging(n_nodes), CHAIN, dt=1e-3, root="pinned", twist="none", **options)
    masses = sim.model.mass.to_numpy()[0, 1:]
    links = sim.model.rest_length.to_numpy()[0]
    omega, shapes = chain_modes(masses, links)
    mode = shapes[:, 0] / np.sum(links * shapes[:, 0]) * LENGTH  # tip displacement = LENGTH * phi
    x = sim.positions()
    x[0] = chain_shape(links, np.radians(tip_angle_deg) * mode)
    sim.set_positions(x)
    return sim, 2 * np.pi / omega[0]


def crossing_times(t, signal):
    """Times of upward zero crossings of signal(t), linearly interpolated."""
    k = np.flatnonzero((signal[:-1] < 0) & (signal[1:] >= 0))
    return t[k] - signal[k] * (t[k + 1] - t[k]) / (signal[k + 1] - signal[k])


def test_pinned_root_swings_with_the_hanging_chain_period():
    sim, reference = pendulum()
    continuous = 2 * np.pi / (1.2024 * np.sqrt(G / LENGTH))  # J0's first zero 2.4048 / 2
    times, tip = [], []
    while sim.time < 3.2 * reference:
        sim.step(2)
        times.append(sim.time)
        tip.append(sim.positions()[0, -1, 0])
    up = crossing_times(np.array(times), np.array(tip))
    period = np.diff(up).mean()
    error = abs(period - reference) / reference
    print(f"\npendulum period {period:.5f} s, chain reference {reference:.5f} s (error {100 * error:.3f} %), "
          f"continuous chain {continuous:.5f} s")
    assert len(up) >= 3
    assert error < 0.02
    assert sim.stats()["projection_residual_max"] < 1e-5
    assert abs(sim.positions()[0, 0]).max() < 1e-12  # the root node stayed on its point


def catenary_sag(span, length, x):
    """z(x) [m] of the inextensible catenary of `length` hung between (0, 0) and (span, 0):
    a from length = 2 a sinh(span / (2 a)) by bisection."""
    lo, hi = 1e-4 * span, 1e4 * span  # the length grows as a shrinks
    for _ in range(200):
        a = 0.5 * (lo + hi)
        lo, hi = (a, hi) if 2 * a * np.sinh(span / (2 * a)) > length else (lo, a)
    return a * np.cosh((x - span / 2) / a) - a * np.cosh(span / (2 * a))


def test_strand_pinned_at_both_ends_hangs_as_the_catenary():
    n, span = 41, 0.3
    rho_a = CHAIN.linear_density
    sim = th.Simulator(hanging(n), CHAIN, dt=1e-3, root="pinned", twist="none",
                       drag=2 * rho_a * 6.0)  # damps the slowest mode (omega ~ 6 rad/s) at its rate
    # start as a V of the right length between the two pins, then pin the tip where it is
    half = (n - 1) // 2
    links = sim.model.rest_length.to_numpy()[0]
    slope = np.arccos(span / LENGTH)  # of each arm of the V below the horizontal
    x = sim.positions()
    x[0] = chain_shape(links, np.where(np.arange(n - 1) < half, np.pi / 2 - slope, np.pi / 2 + slope))
    sim.set_positions(x)
    assert np.allclose(x[0, -1], [span, 0, 0], atol=1e-12)
    sim.add_pin(0, n - 1)
    sim.step(6000)
    assert sim.kinetic_energy() < 1e-12, "not at rest yet"
    p = sim.positions()[0]
    error = np.abs(p[:, 2] - catenary_sag(span, LENGTH, p[:, 0])).max() / span
    print(f"\ncatenary: max node distance from the curve {100 * error:.4f} % of the span "
          f"(sag {-p[:, 2].min():.4f} m)")
    assert error < 0.01
    assert np.allclose(p[-1], [span, 0, 0], atol=1e-12)


def energy_steps(sim, steps, energies):
    for _ in range(steps):
        sim.step(1)
        energies.append(sim.total_energy())


def event_jump(energies, k, window=10):
    """(|change across step k|, max |change| of the `window` steps either side of it) [J]."""
    d = np.abs(np.diff(energies))
    return d[k], max(d[k - window:k].max(), d[k + 1:k + 1 + window].max())


def test_adding_and_releasing_a_pin_leaves_no_energy_jump():
    """Without drag the swing keeps its energy up to the integrator's own per-step change (the
    projection dissipates a little, more while a kink is sharp). A pin added where its node is
    still (the swing's turning point) and released later must not change the energy across
    that step more than the steps around it change it (1.5x their largest change), nor by 1 %
    of one node's kinetic energy at the swing's peak speed (a node gaining or losing its
    motion at the event would show as that whole amount). Added mid-swing a pin stops a moving
    node: the energy may drop, never rise. The steps after the release dissipate more than the
    smooth swing did: the kink left at the released node is where the projection loses energy."""
    sim, period = pendulum(tip_angle_deg=10.0)
    mid = 10
    energies, vx = [sim.total_energy()], [0.0]
    while not (len(vx) > 20 and vx[-1] * vx[-2] < 0):  # the tip turns back (after half a period)
        sim.step(1)
        energies.append(sim.total_energy())
        vx.append(sim.velocities()[0, -1, 0])
    added = len(energies) - 1  # the change across step `added` is the first with the pin
    pid = sim.add_pin(0, mid)
    energy_steps(sim, 300, energies)
    released = len(energies) - 1
    sim.release_pin(pid)
    energy_steps(sim, 100, energies)
    node_scale = 0.5 * sim.model.mass.to_numpy()[0, mid] * (np.radians(10) * LENGTH * 2 * np.pi / period) ** 2
    jumps = {name: event_jump(energies, k) for name, k in (("add", added), ("release", released))}
    print("\nenergy change across the step / largest of its neighbours' [J]: "
          + ", ".join(f"{n} {a:.3e} / {b:.3e}" for n, (a, b) in jumps.items())
          + f"; one node's peak kinetic energy {node_scale:.3e} J")
    for jump, neighbours in jumps.values():
        assert jump <= 1.5 * neighbours
        assert jump < 1e-2 * node_scale
    assert sim.velocities()[0, mid, 0] != 0.0  # free again

    moving, _ = pendulum(tip_angle_deg=10.0)
    moving.step(int(0.25 * period / moving.dt))  # mid-swing
    change = [moving.total_energy()]
    energy_steps(moving, 1, change)
    moving.add_pin(0, mid)
    energy_steps(moving, 1, change)
    print(f"pinned mid-swing: energy change {change[2] - change[1]:.3e} J (free step before: "
          f"{change[1] - change[0]:.3e} J)")
    assert change[2] - change[1] <= abs(change[1] - change[0])


def test_move_pin_drives_a_node_along_a_path():
    groom = hanging(11, length=0.2)
    sim = th.Simulator(groom, th.Material(), dt=1e-3, drag=5e-4)
    tip = sim.positions()[0, -1]
    pid = sim.add_pin(0, -1)
    (listed,) = sim.pins()
    assert listed["id"] == pid and listed["node"] == 10 and np.allclose(listed["target"], tip)
    assert listed["strand"] == 0 and listed["clamp"] is False and listed["attach"] == "world"
    worst = 0.0
    for k in range(1, 201):
        t = k * 4e-3
        target = tip + 0.02 * np.array([np.sin(2 * np.pi * t), 0.0, 1 - np.cos(2 * np.pi * t)])
        sim.move_pin(pid, target)
        sim.step(4)
        worst = max(worst, np.linalg.norm(sim.positions()[0, -1] - target))
    stats = sim.stats()
    print(f"\nmoved pin: max |x - target| {worst:.2e} m, "
          f"projection residual {stats['projection_residual_max']:.2e}")
    assert worst < 1e-12
    assert stats["projection_residual_max"] < 1e-2
    speed = np.linalg.norm(sim.velocities()[0, -1])
    assert 0.1 < speed < 0.2  # 2 pi * 0.02 m * 1 Hz = 0.126 m/s along the circle
    sim.release_pin(pid)
    assert sim.pins() == []
    sim.step(5)
    assert np.linalg.norm(sim.positions()[0, -1] - target) > 1e-6  # free again


def test_head_pins_and_clips_follow_the_head():
    groom = hanging(11, length=0.2)
    sim = th.Simulator(groom, th.Material(), dt=1e-3, drag=5e-4)
    rest = sim.positions()[0]
    sim.add_pin(0, 6, attach="head")
    sim.add_pin(0, 3, clamp=True, attach="head")
    rotation, translation = rotation_matrix([0, 0, 1], 0.3), np.array([0.01, 0.0, 0.005])
    sim.set_root_transform(rotation, translation)
    sim.step(5)
    x = sim.positions()[0]
    for node in (3, 4, 6):
        assert np.allclose(x[node], rotation @ rest[node] + translation, atol=1e-12)
    assert [p["clamp"] for p in sim.pins()] == [False, True]

    def nod(t):
        return rotation_matrix([1, 0, 0], 0.4 * np.sin(3 * t)), np.array([0.0, 0.01 * t, 0.0])
    moving = th.Simulator(groom, th.Material(), dt=1e-3, drag=5e-4, root_motion=nod)
    start = moving.positions()[0]
    rot0, t0 = nod(0.0)
    local = rot0.T @ (start[5] - t0)
    moving.add_pin(0, 5, attach="head")
    for _ in range(10):
        moving.step(7)
        rot, trans = nod(moving.time)
        assert np.allclose(moving.positions()[0, 5], rot @ local + trans, atol=1e-12)


def test_bulk_pins_and_a_pinned_tie():
    roots = np.stack([np.linspace(-0.02, 0.02, 5), np.zeros(5), np.zeros(5)], axis=1)
    groom = th.Groom.straight(roots=roots, directions=[[0, 0, -1]] * 5, length=0.2, n_nodes=11)
    sim = th.Simulator(groom, th.Material(), dt=1e-3, drag=5e-4)
    ids = sim.add_pin(np.arange(5), 4, attach="head")
    assert isinstance(ids, np.ndarray) and list(ids) == [0, 1, 2, 3, 4]
    # gather the five strands towards a point behind and above their node 4 (a straight strand
    # pushed exactly along itself would be a perfect column: the projection cannot buckle it)
    tie = np.array([0.0, 0.01, -0.07])
    sim.move_pin(ids, np.repeat(tie[None], 5, axis=0) + roots * 0.2)
    sim.step(50)
    assert np.allclose(sim.positions()[:, 4], tie + roots * 0.2, atol=1e-12)
    sim.release_pin(ids[:2])
    assert [p["id"] for p in sim.pins()] == [2, 3, 4]


def test_bad_pin_input_names_the_parameter():
    sim = th.Simulator(hanging(11, length=0.2), th.Material(), dt=1e-3)
    with pytest.raises(ValueError, match="strand"):
        sim.add_pin(1, 5)
    with pytest.raises(ValueError, match="node"):
        sim.add_pin(0, 11)
    with pytest.raises(ValueError, match="node"):
        sim.add_pin(0, 0)  # the root node rides on the head
    with pytest.raises(ValueError, match="node"):
        sim.add_pin(0, 10, clamp=True)  # no edge past the tip
    with pytest.raises(ValueError, match="target"):
        sim.add_pin(0, 5, [0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="attach"):
        sim.add_pin(0, 5, attach="hat")
    with pytest.raises(ValueError, match="pin_id"):
        sim.release_pin(7)
    pid = sim.add_pin(0, 5)
    with pytest.raises(ValueError, match="already held"):
        sim.add_pin(0, 4, clamp=True)
    with pytest.raises(ValueError, match="target"):
        sim.move_pin(pid, [1.0, 2.0])
    with pytest.raises(ValueError, match="pin_id"):
        sim.move_pin(pid + 1, [0.0, 0.0, 0.0])
    sim.release_pin(pid)
    with pytest.raises(ValueError, match="pin_id"):
        sim.release_pin(pid)
    with pytest.raises(ValueError, match="root"):
        th.Simulator(hanging(11, length=0.2), th.Material(), root="loose")
    pinned = th.Simulator(hanging(11, length=0.2), th.Material(), root="pinned")
    with pytest.raises(ValueError, match="node"):
        pinned.add_pin(0, 0)
    pinned.add_pin(0, 1)  # node 1 is free under a pinned root


def test_pin_code_compiles_only_when_pins_are_used():
    """In a fresh process: a pinless scene's fused kernel has no pin stage; adding a pin
    compiles one variant with it, and releasing and re-adding compiles nothing more."""
    code = textwrap.dedent("""
        import json, warnings, numpy as np, taichi_hair as th
        from taichi_hair.solver.step import fused as step
        warnings.simplefilter("ignore")
        th.init(precision="float64")
        groom = th.Groom.straight(length=0.1, n_nodes=11, roots=[[0, 0, 0.1]], directions=[[0, 0, 1]])
        sim = th.Simulator(groom, th.Material())
        sim.step(3)
        bare = step.compiled_variants()
        for node in (5, 6, 7):
            pid = sim.add_pin(0, node)
            sim.step(2)
            sim.release_pin(pid)
            sim.step(2)
        print(json.dumps({"bare": bare, "all": step.compiled_variants()}))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout[out.stdout.index("{"):])
    assert result["bare"] and not any(v["pins"] or v["root_mode"] != 0 for v in result["bare"])
    assert len(result["all"]) == 2 and sum(v["pins"] for v in result["all"]) == 1


def test_staged_and_fused_steps_agree_with_pins_and_a_pinned_root():
    """The per-stage kernels (benchmark timers, hair interaction) place pins and carry the
    pinned root's frame as the fused kernel does."""
    from contextlib import nullcontext

    def nod(t):
        return rotation_matrix([1, 0, 0], 0.3 * np.sin(4 * t)), np.zeros(3)
    z = np.linspace(0.0, -0.2, 11)
    wavy = th.Groom.from_polylines(np.stack([0.02 * np.sin(np.pi * z / 0.1), 0 * z, z], axis=1))
    runs = []
    for timers in (None, lambda name: nullcontext()):
        sim = th.Simulator(wavy, th.Material(), dt=1e-3, drag=5e-4, root="pinned", root_motion=nod)
        pid = sim.add_pin(0, 5, attach="head")
        clip = sim.add_pin(0, 8, clamp=True)
        for k in range(30):  # the strand is slack between its held points: room to move
            sim.move_pin(clip, sim.pins()[1]["target"] + [0.0, 1e-4, 0.0])
            sim.step(1, timers=timers)
        runs.append((sim.positions(), sim.frames()["m1"], sim.state.root_u.to_numpy()))
        assert pid == 0
    for fused, staged in zip(*runs):  # positions, material frames, the carried root reference
        assert np.abs(fused - staged).max() < 1e-12


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_pinned_root_reference_is_parallel_transported_in_time():
    """Drive the pinned root edge once round a cone of half-angle alpha (node 1 held by a
    moving pin): a reference director parallel-transported in time comes back turned about the
    edge by the cone's solid angle 2 pi (1 - cos alpha) (the holonomy); one that turned with a
    frame attached to the motion, or lagged a step, would not."""
    alpha, steps = np.radians(30.0), 720
    sim = th.Simulator(hanging(11, length=0.2), th.Material(), dt=1e-3, root="pinned",
                       gravity=(0, 0, 0))
    link = sim.model.rest_length.to_numpy()[0, 0]

    def direction(phi):
        return np.array([np.sin(alpha) * np.cos(phi), np.sin(alpha) * np.sin(phi), -np.cos(alpha)])
    x = sim.positions()
    x[0] = np.arange(11)[:, None] * link * direction(0.0)
    sim.set_positions(x)
    sim.step(1)  # the reference now follows the tilted edge
    u_start = sim.state.root_u.to_numpy()[0].astype(np.float64)
    pid = sim.add_pin(0, 1)
    for k in range(1, steps + 1):
        sim.move_pin(pid, link * direction(2 * np.pi * k / steps))
        sim.step(1)
    t = direction(0.0)
    u_end = sim.state.root_u.to_numpy()[0].astype(np.float64)
    turned = np.arctan2(np.cross(u_start, u_end) @ t, u_start @ u_end)
    holonomy = 2 * np.pi * (1 - np.cos(alpha))
    print(f"\nroot reference turned {turned:.5f} rad about the edge; holonomy {holonomy:.5f} rad")
    assert np.allclose(sim.positions()[0, 1], link * t, atol=1e-12)
    assert abs(abs(turned) - holonomy) < 1e-3
