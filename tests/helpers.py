"""Independent numpy references shared by tests (no taichi_hair imports of physics), and the
command-line drivers the scene tests share."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np


def rotation_matrix(axis, angle):
    """Rodrigues rotation [3, 3] about unit `axis` by `angle` radians."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def central_difference_gradient(energy, x0, nodes, h=1e-6):
    """dE/dx [S, N, 3] by central differences over the listed (strand, node) pairs."""
    grad = np.zeros_like(x0)
    for s, i in nodes:
        for k in range(3):
            for sign in (1.0, -1.0):
                x = x0.copy()
                x[s, i, k] += sign * h
                grad[s, i, k] += sign * energy(x) / (2 * h)
    return grad


def force_jacobian(system, x0, dofs, h=1e-7):
    """-d force / d x [len(dofs), len(dofs)] of strand 0 by central differences (float64) over
    the listed (node, axis) pairs, rows and columns in that order; `system` is a Simulator or a
    RodSystem (set_positions, update_twist, elastic_forces), its free material angles re-solved
    at every probe (the forces at twist equilibrium). Leaves the system at x0."""
    nodes, axes = [i for i, _ in dofs], [a for _, a in dofs]
    columns = []
    for i, a in dofs:
        forces = []
        for sign in (1.0, -1.0):
            x = x0.copy()
            x[0, i, a] += sign * h
            system.set_positions(x)
            system.update_twist()
            forces.append(system.elastic_forces()[0, nodes, axes])
        columns.append(-(forces[0] - forces[1]) / (2 * h))
    system.set_positions(x0)
    system.update_twist()
    return np.array(columns).T


def perturbed(x, scale, seed, keep_root=True):
    """x plus Gaussian noise of `scale` metres; the clamped root node stays where it is."""
    rng = np.random.default_rng(seed)
    out = x + scale * rng.standard_normal(x.shape)
    if keep_root:
        out[:, 0] = x[:, 0]
    return out


def run_cli(args, cwd, timeout=900, python_options=()):
    """`python [python_options] -m taichi_hair run ARGS --no-progress` in cwd; the
    CompletedProcess (text)."""
    return subprocess.run([sys.executable, *python_options, "-m", "taichi_hair", "run", *args, "--no-progress"],
                          cwd=cwd, capture_output=True, text=True, timeout=timeout)


def kill_run_after(args, out, cwd, frames, timeout):
    """Start `taichi-hair run ARGS` writing to `out`, SIGKILL its process group once its
    progress.json reports at least `frames` frames done (or after `timeout` s), and return the
    frames it reports done then."""
    proc = subprocess.Popen([sys.executable, "-m", "taichi_hair", "run", *args, "--no-progress"],
                            cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    progress, deadline = out / "progress.json", time.time() + timeout
    while time.time() < deadline:
        try:
            if json.loads(progress.read_text())["frames_done"] >= frames:
                break
        except (OSError, ValueError, KeyError):  # not written yet, or mid-replace
            pass
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    return json.loads(progress.read_text())["frames_done"]


def energy_rise(sim, chunks, steps, in_play):
    """(max rise of sim.total_energy() above its start [J], max of in_play(sim) [J]) over
    `chunks` calls of sim.step(steps): an undamped, undriven scene's energy may only fall."""
    start = sim.total_energy()
    rise, played = 0.0, 0.0
    for _ in range(chunks):
        sim.step(steps)
        rise = max(rise, sim.total_energy() - start)
        played = max(played, in_play(sim))
    return rise, played

