"""What a run leaves in its output folder, and how a run resumes from it: frame paths, the guides
a cluster run simulated but has not rendered yet, the MP4, the USD curves, the checkpoint
(state.npz + progress.json) and the resume point read back from it, and the run's summary.
Shared by the serial run (runner.py) and the cluster run (cluster.py)."""

import json
import os
import sys
from pathlib import Path

import numpy as np

from .outdir import STATE_FILE, naming_file

PROGRESS_FILE = "progress.json"
GUIDES_DIR = "guides"  # frames simulated by a cluster run and not yet rendered


def log_frame(frame, total, t, times, simulated=True, stream=None) -> None:
    """One line on stderr for a finished frame (the progress report of --no-progress): frame
    number, simulated time [s] at its end and the wall time [ms] of its simulation,
    interpolation and rendering (a frame a cluster run simulated: rendered only)."""
    ms = {k: 1e3 * v[-1] if v else 0.0 for k, v in times.items()}
    sim = f"sim {ms['simulation']:8.1f} ms" if simulated else "sim (cluster)"
    print(f"frame {frame + 1:>{len(str(total))}}/{total}  t = {t:.4f} s  {sim}  interpolation "
          f"{ms['interpolation']:7.1f} ms  render {ms['rendering']:7.1f} ms", file=stream or sys.stderr, flush=True)


def frame_path(out, frame) -> Path:
    """out/frames/frame_NNNNN.png: frame `frame` (0-based) of the run in `out`."""
    return Path(out) / "frames" / f"frame_{frame:05d}.png"


def guides_path(out, frame) -> Path:
    """out/guides/frame_NNNNN.npz: a frame's guides, simulated and not yet rendered."""
    return Path(out) / GUIDES_DIR / f"frame_{frame:05d}.npz"


def save_guides(out, frame, guides, pose, directors=None) -> None:
    """Write a simulated frame's guides [S, N, 3] m, head pose (R [3, 3], t [3] m) and, when
    not None, the guides' material directors [S, N-1, 3] to
    guides/frame_NNNNN.npz atomically (temporary file, then rename): what a cluster run renders
    from, kept until the frame's PNG exists, so --resume can render it."""
    path = guides_path(out, frame)
    path.parent.mkdir(exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    extra = {} if directors is None else {"directors": directors}
    np.savez(tmp, guides=guides, rotation=pose[0], translation=pose[1], **extra)
    os.replace(tmp, path)


def load_guides(out, frame) -> tuple:
    """(guides [S, N, 3], (R, t), directors [S, N-1, 3] or None) saved by `save_guides`."""
    with np.load(guides_path(out, frame)) as data:
        directors = data["directors"] if "directors" in data.files else None
        return data["guides"], (data["rotation"], data["translation"]), directors


def remove_guides(out, frame) -> None:
    """Drop a frame's guides once its PNG is in place (and the folder once it is empty)."""
    guides_path(out, frame).unlink(missing_ok=True)
    try:
        guides_path(out, frame).parent.rmdir()
    except OSError:  # other frames still pending, or already gone
        pass


def write_video(out, script, shot, total) -> Path:
    """The MP4 of frames 0..total-1 (read back from their PNGs), <out>/<scene>.mp4."""
    import render
    path = Path(out) / f"{Path(script).stem}.mp4"
    with naming_file(path):
        return render.write_mp4(path, (render.read_png(frame_path(out, k)) for k in range(total)), fps=shot.fps)


def check_usd(kind):
    """ValueError (a one-line CLI error) for a bad --usd format or a missing usd-core."""
    from ..hair.usd import require_pxr
    if kind not in ("usdc", "usda"):
        raise ValueError(f"--usd must be usdc or usda, got {kind!r}")
    try:
        require_pxr()
    except ImportError as exc:
        raise ValueError(f"--usd: {exc}") from None


def open_usd_writer(path, shot, scene, resume, done):
    """The run's UsdCurvesWriter: time code k + 1 is frame k (simulated time (k + 1) / fps); on
    --resume the file is reopened and keeps the frames the checkpoint counts."""
    from ..hair import usd
    mesh = scene.head.mesh if scene.head is not None else None
    if resume and (done > 0 or path.exists()):
        return usd.UsdCurvesWriter(path, shot.fps, resume=done)
    return usd.UsdCurvesWriter(path, shot.fps, head_mesh=mesh)


def write_usd_frame(writer, frame, shot, sim, guides, hair, pose):
    """Frame `frame` into the UsdCurvesWriter: the guides [S, N, 3] m and/or the dense hair (a
    list of [n, 3] m polylines), as shot.usd asks, with the head pose (R, t)."""
    counts = sim.groom.node_counts
    sets = {}
    if shot.usd in ("guides", "both"):
        sets["Guides"] = [guides[s, : counts[s]] for s in range(sim.n_strands)]
    if shot.usd in ("dense", "both"):
        sets["Dense"] = hair
    for name in sets:
        if name not in writer.counts:
            writer.define(name, [len(x) for x in sets[name]], widths=shot.hair_width,
                              colours=shot.hair_colour)
    writer.write_frame(frame + 1, sets, head_pose=pose)


def checkpoint(out, sim, shot, frames_done):
    """One atomic record: the state file holds the frame count and frame step with the state
    (written to a temporary file and renamed); progress.json is a copy for people and monitors,
    also replaced atomically, never read back."""
    with naming_file(out / STATE_FILE):
        sim.save_state(out / STATE_FILE, extra={"frames_done": frames_done, "frame_dt": shot.frame_dt,
                                                 "fps": shot.fps})
    tmp = out / (PROGRESS_FILE + ".tmp")
    with naming_file(tmp):
        tmp.write_text(json.dumps({"frames_done": frames_done, "time": sim.time}))
    tmp.replace(out / PROGRESS_FILE)


def resume_point(out, sim, shot, total=None) -> tuple:
    """(frames simulated, frames of those still to render): restore the simulator from the last
    checkpoint, after checking that the record is whole and agrees with itself and this shot
    (ValueError naming the file). A frame below the count may lack its PNG only if its guides
    are in guides/ (a cluster run renders behind the simulation)."""
    state = out / STATE_FILE
    if not state.exists():
        return 0, []
    try:
        with np.load(state) as data:
            done, frame_dt, fps, t = (int(data["extra_frames_done"]), float(data["extra_frame_dt"]),
                                      int(data["extra_fps"]), float(data["time"]))
    except KeyError:
        raise ValueError(f"{state}: the checkpoint holds no frame count (written by an older taichi_hair?); "
                         f"delete {out} to start over") from None
    except Exception as err:  # a damaged zip or array: numpy raises several types
        raise ValueError(f"{state}: not a readable checkpoint ({type(err).__name__}: {err}); "
                         f"delete {out} to start over") from None
    if (fps, frame_dt) != (shot.fps, shot.frame_dt):
        raise ValueError(f"{state}: the checkpoint was made at fps {fps} with step {frame_dt:.6g} s, this shot "
                         f"runs at fps {shot.fps} with step {shot.frame_dt:.6g} s; delete {out} to start over")
    if not (0 <= done and abs(t - done / fps) <= 1e-6 * max(1.0, t)):
        raise ValueError(f"{state}: inconsistent checkpoint: {done} frames done at fps {fps} is "
                         f"{done / fps:.6g} s, but its state is at t = {t:.6g} s; delete {out} to start over")
    if total is not None and done > total:
        raise ValueError(f"{out}: {done} frames are already finished, more than the {total} asked for "
                         f"(--resume would cut the video short): ask for {done} frames or more")
    pending = [k for k in range(done) if not frame_path(out, k).exists()]
    missing = [k for k in pending if not guides_path(out, k).exists()]
    if missing:
        raise ValueError(f"{out}: checkpoint says {done} frames are done but frame {missing[0]} is missing; "
                         f"delete {out} to start over")
    sim.load_state(state)
    return done, pending


def run_summary(script, total, resumed_from, times, video, sim) -> dict:
    """The run's summary: scene, frames, where it resumed, the video, median ms per frame of each
    part ({part: [s per frame]} in `times`), simulated seconds and the simulator's stats."""
    per_frame = {k: (1e3 * float(np.median(v)) if v else 0.0) for k, v in times.items()}
    return {"scene": str(script), "frames": total, "resumed_from": resumed_from, "video": str(video),
            "ms_per_frame": per_frame, "simulated_s": sim.time, "stats": sim.stats()}


def format_summary(summary: dict) -> str:
    """The two lines `taichi-hair run` prints for a run_summary (cluster runs add their workers)."""
    ms = summary["ms_per_frame"]
    usd = f" + {summary['usd']}" if summary.get("usd") else ""
    if "workers" in summary:
        usd += f" ({summary['frames_rendered']} frames rendered on {summary['workers']} Dask workers)"
    resumed = f" (resumed from {summary['resumed_from']})" if summary["resumed_from"] else ""
    return (f"{summary['scene']}: {summary['frames']} frames{resumed}, "
            f"{summary['simulated_s']:.3f} s simulated -> {summary['video']}{usd}\n"
            f"median ms per frame: simulation {ms['simulation']:.1f}, interpolation "
            f"{ms['interpolation']:.1f}, rendering {ms['rendering']:.1f}")

