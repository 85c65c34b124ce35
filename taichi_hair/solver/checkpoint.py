"""Checkpoints: a simulator's dynamic state (positions, velocities, material angles, root
frames, time, step count, head pose) in an .npz file, written atomically, read back checked.
Functions of a Simulator (they read and restore its clock and head pose).

Everything the next step reads is in the record, so a resumed simulator continues bit for bit
as the uninterrupted one: besides the state proper, the frames the last step left (Bishop and
material frames, curvature binormals: recomputing them in another kernel differs in the last
bits) and the implicit step's history (previous velocities, displacements, elastic forces,
tensions) with the step it was made for."""

import math
import os

import numpy as np

from ..rods import arrays


# state arrays beyond x, v, theta and the root frames that the next step reads
CARRIED = ("bishop_u", "bishop_v", "m1", "m2", "kb", "history", "tension")


def pose_rows(rotation, translation):
    """[4, 3]: rows of R, then t."""
    return np.vstack([rotation, translation])


def save_state(sim, path, extra=None) -> None:
    """Write the dynamic state (positions, velocities, material angles, time, step count,
    head pose) to `path` as .npz, atomically (a temporary file renamed into place), so a
    crash mid-write leaves the previous checkpoint intact. `extra`: a dict of numbers or
    arrays stored alongside as `extra_<name>` (the runner's frame count), part of the same
    atomic record; `load_state` ignores them."""
    path = os.fspath(path)
    tmp = path + ".tmp.npz"
    np.savez(tmp, **{f"extra_{k}": v for k, v in (extra or {}).items()},
             x=sim.state.x.to_numpy(), v=sim.state.v.to_numpy(),
             theta=sim.state.theta.to_numpy(), root_t=sim.state.root_t.to_numpy(),
             root_u=sim.state.root_u.to_numpy(), time=sim.time, steps=sim.steps_taken,
             head=pose_rows(*sim._head), head_prev=pose_rows(*sim._head_prev),
             shape=np.array([sim.groom.n_strands, sim.groom.max_nodes]),
             **{name: getattr(sim.state, name).to_numpy() for name in CARRIED},
             history_h=math.nan if sim._history_h is None else sim._history_h)
    os.replace(tmp, path)


def load_state(sim, path) -> None:
    """Restore a state written by `save_state` for this same groom; ValueError if the file
    does not fit (other strand or node counts, missing arrays, non-finite values)."""
    try:
        with np.load(path) as data:
            saved = {k: data[k] for k in ("x", "v", "theta", "time", "steps", "head", "head_prev", "shape")}
            # older files lack them: frames are then recomputed and the implicit history reseeded
            saved.update({k: data[k] for k in ("root_t", "root_u", "history_h", *CARRIED) if k in data})
    except (OSError, KeyError, ValueError) as err:
        raise ValueError(f"{path}: not a taichi_hair state file ({err})") from None
    expected = [sim.groom.n_strands, sim.groom.max_nodes]
    if list(saved["shape"]) != expected:
        raise ValueError(f"{path}: state of {list(saved['shape'])} strands x nodes, this groom has {expected}")
    if not all(np.all(np.isfinite(saved[k])) for k in ("x", "v", "theta")):
        raise ValueError(f"{path}: the saved state has non-finite values")
    sim.state.x.from_numpy(saved["x"].astype(np.float64))
    sim.state.v.from_numpy(saved["v"].astype(arrays.np_float()))
    sim.state.theta.from_numpy(saved["theta"].astype(arrays.np_float()))
    sim.time, sim.steps_taken = float(saved["time"]), int(saved["steps"])
    sim._head = (saved["head"][:3].astype(np.float64), saved["head"][3].astype(np.float64))
    sim._head_prev = (saved["head_prev"][:3].astype(np.float64), saved["head_prev"][3].astype(np.float64))
    sim._orient_roots()
    for k in ("root_t", "root_u"):
        if k in saved:
            getattr(sim.state, k).from_numpy(saved[k].astype(arrays.np_float()))
    sim.update_frames()
    now = {k: getattr(sim.state, k).to_numpy() for k in CARRIED}
    if all(k in saved and saved[k].shape == now[k].shape for k in CARRIED):
        for k in CARRIED:
            getattr(sim.state, k).from_numpy(saved[k].astype(now[k].dtype))
        h = float(saved["history_h"])
        sim._history_h = None if math.isnan(h) else h
    else:
        sim._history_h = None
