"""Long hair gathered in a ponytail: a tie of head-attached pins at the back of the head, and
a head that turns and nods so the tail swings.

    .venv/bin/taichi-hair run scenes/ponytail.py --out out/ponytail

Every guide is groomed from its root over the scalp to its own point on a small ring behind the
occiput (1 cm across), then down as the tail. `setup` pins, on every strand, the node where it
passes the ring: one head-attached pin each (`Simulator.add_pin` in bulk), so the tie rides on
the head like the roots and the tail swings below it.
"""

import numpy as np

import taichi_hair as th

TIE = np.array([0.0, -0.105, -0.07])  # [m] head coordinates: a low tie, behind the occiput
RING = 0.006  # [m] radius of the gathered bundle at the tie
TAIL = np.array([0.0, -0.2, -1.0]) / np.linalg.norm([0.0, -0.2, -1.0])  # how the tail hangs
N_NODES = 40
PIVOT = (0.0, -0.01, -0.10)  # the neck


def _ring_points(roots):
    """Each strand's point on the tie ring: left roots to the left, front roots to the top."""
    side = roots[:, 0] / np.abs(roots[:, 0]).max()
    front = (roots[:, 1] - roots[:, 1].min()) / np.ptp(roots[:, 1]) * 2 - 1
    offset = np.stack([side, 0.5 * front, np.zeros(len(roots))], axis=1)
    offset /= np.maximum(1.0, np.linalg.norm(offset, axis=1))[:, None]
    return TIE + RING * offset


def _over_the_scalp(root, normal, tie, field, clearance=0.004, samples=120):
    """A dense path from the root (leaving between its normal and the way to the tie) over the
    scalp to the tie point: directions from the head's centre slerped, radius blended, pushed
    out of the head to `clearance` and smoothed (so no node turns sharply)."""
    toward = (tie - root) - ((tie - root) @ normal) * normal
    leave = 0.5 * normal + toward / max(np.linalg.norm(toward), 1e-9)
    start = root + 0.01 * leave / np.linalg.norm(leave)
    a, b = start / np.linalg.norm(start), tie / np.linalg.norm(tie)
    angle = np.arccos(np.clip(a @ b, -1.0, 1.0))
    s = np.linspace(0.0, 1.0, samples)[:, None]
    direction = (np.sin((1 - s) * angle) * a + np.sin(s * angle) * b) / max(np.sin(angle), 1e-9)
    path = np.vstack([root, direction * ((1 - s) * np.linalg.norm(start) + s * np.linalg.norm(tie))])
    for _ in range(4):
        for _ in range(30):  # Laplacian smoothing, root and tie kept
            path[1:-1] = 0.5 * path[1:-1] + 0.25 * (path[:-2] + path[2:])
        push = np.clip(clearance - field.sample(path[1:]), 0.0, None)[:, None]
        path[1:] += push * field.gradient(path[1:])
    path[-1] = tie
    return path


def _tail(path, length, bend=0.08, step=0.001):
    """The tail past the tie: the approach direction turns to TAIL over `bend` [m] (smoothstep),
    then straight on to `length` [m] of tail."""
    approach = path[-1] - path[-2]
    approach /= np.linalg.norm(approach)
    s = np.arange(step, length + step, step)
    w = np.clip(s / bend, 0.0, 1.0)[:, None]
    w = w * w * (3 - 2 * w)
    direction = (1 - w) * approach + w * TAIL
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    return path[-1] + np.cumsum(step * direction, axis=0)


def _resample(path, n, length):
    """n nodes at equal arc-length steps along `path`, continued straight past its end to `length`."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, length, n)
    return np.stack([np.interp(s, arc, path[:, k]) for k in range(3)], axis=1)


def ponytail_groom(head_model, field, n_guides=48, seed=5):
    """(Groom, tie node of every strand): guides of 35-45 cm through the tie ring. field: the
    head mesh's distance grid (without the neck capsule, which holds the nape roots)."""
    roots, normals = th.sample_scalp(head_model, n_guides, seed=seed)
    lengths = np.random.default_rng(seed).uniform(0.35, 0.45, n_guides)
    strands, tie_nodes = [], []
    for root, normal, tie, length in zip(roots, normals, _ring_points(roots), lengths):
        path = _over_the_scalp(root, normal, tie, field)
        to_tie = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
        length = max(length, to_tie + 0.1)
        path = np.vstack([path, _tail(path, length - to_tie + 0.01)])
        # the tie node is the node nearest the ring point (the path reaches it at to_tie)
        strands.append(_resample(path, N_NODES, length))
        tie_nodes.append(int(round(to_tie / length * (N_NODES - 1))))
    return th.Groom.from_polylines(np.array(strands)), np.array(tie_nodes)


def build() -> th.Scene:
    head = th.Head.default()
    groom, _ = ponytail_groom(head.model, head.colliders[0].grid)
    motion = th.compose(th.Shake(amplitude_deg=35, frequency_hz=0.8, pivot=PIVOT, ramp_s=0.4),
                        th.Nod(amplitude_deg=12, frequency_hz=1.1, pivot=PIVOT, ramp_s=0.4))
    return th.Scene(groom=groom, head=head, material=th.Material(), motion=motion, drag=5e-4)


def setup(scene, simulator) -> None:
    """The tie: one head-attached pin per strand, where the strand passes the ring."""
    _, tie_nodes = ponytail_groom(scene.head.model, scene.head.colliders[0].grid)
    simulator.add_pin(np.arange(simulator.n_strands), tie_nodes, attach="head")


def shot() -> th.Shot:
    return th.Shot(frames=96, fps=24, dense_strands=12000, hair_colour=(0.2, 0.12, 0.06),
                view=(0.73, -0.65, 0.20))
