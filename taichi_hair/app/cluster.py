"""Runs, sweeps and reports on a Dask cluster: `--workers N` (a LocalCluster of N worker
processes on this machine) or `--scheduler tcp://HOST:8786` (an existing `dask scheduler` with
`dask worker` processes, or dask-jobqueue). Needs the optional extra `cluster`
(`pip install 'taichi_hair[cluster]'`, i.e. dask[distributed]); dask is imported here, inside
functions, and nowhere else, so the core and the serial paths never need it.

A cluster run: the client process simulates (the simulation is sequential), saves each frame's
guides to guides/frame_NNNNN.npz, checkpoints, and submits the frame to the cluster at once. A
worker interpolates the dense hair and renders the PNG; it returns the PNG's bytes and the client
writes them (temporary file, then rename) and drops the frame's guides. So a frame is written
once, by one process, whole; a worker that dies mid-frame has its task rerun elsewhere by the
scheduler; workers need no shared folder with the client, only the scene script (and its
assets) at the same path. Each worker process initialises Taichi once, in the scene's precision,
on its first task, and keeps the prepared scene (interpolator, frame writer) for the run's later
frames. The PNGs equal a serial run's byte for byte when Taichi runs single-threaded on both
sides (TI_CPU_MAX_NUM_THREADS=1): the renderer adds far fragments and shadow opacity with float
atomics, whose order follows the threads, so multi-threaded runs, serial ones included, can
differ from each other in a few pixels. Local workers get the machine's cores divided among them
(`worker_environment`).
"""

import contextlib
import logging
import os
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

EXTRA = "pip install 'taichi_hair[cluster]'"


def require_distributed(option: str = "--workers"):
    """The `distributed` module, or ValueError (a one-line CLI error) naming the extra."""
    try:
        import distributed
    except ImportError:
        raise ValueError(f"{option} needs the optional extra 'cluster' (dask[distributed]), which is not "
                         f"installed: {EXTRA}") from None
    return distributed


def add_arguments(parser) -> None:
    """--workers N | --scheduler ADDR on a subcommand's parser."""
    from ..validation import cli_int
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--workers", type=cli_int("--workers", 1, 256), default=None, metavar="N",
                       help="spread the work over a local Dask cluster of N worker processes (extra 'cluster'; "
                            "default: no cluster, this process)")
    group.add_argument("--scheduler", default=None, metavar="ADDR",
                       help="spread the work over the Dask cluster at ADDR, e.g. tcp://HOST:8786 (extra 'cluster'; "
                            "default: none)")


def wanted(args) -> bool:
    """True when the command line asks for a cluster."""
    return getattr(args, "workers", None) is not None or getattr(args, "scheduler", None) is not None


@contextlib.contextmanager
def connect(workers: int | None = None, scheduler: str | None = None):
    """A dask Client: to a LocalCluster of `workers` processes (one thread each; the workers
    inherit this process's environment) or to the scheduler at `scheduler`. Closed on exit."""
    distributed = require_distributed("--scheduler" if scheduler else "--workers")
    if (workers is None) == (scheduler is None):
        raise ValueError("give one of --workers N or --scheduler ADDR")
    if scheduler is not None:
        try:
            client = distributed.Client(scheduler, timeout="30s")
        except OSError as err:
            raise ValueError(f"--scheduler {scheduler}: cannot connect ({err})") from None
        with client:
            yield client
        return
    if not (isinstance(workers, int) and workers >= 1):
        raise ValueError(f"--workers must be an integer >= 1, got {workers!r}")
    with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=logging.ERROR,
                                  env=worker_environment(workers)) as cluster:
        with distributed.Client(cluster) as client:
            yield client


def worker_environment(workers: int) -> dict:
    """Environment for local worker processes: Taichi's CPU thread pool cut to this machine's
    cores shared among the workers (TI_CPU_MAX_NUM_THREADS, unless already set): N workers each
    running a pool as wide as the machine oversubscribe it (measured on 2 cores, 2 workers:
    1.6 s per frame of wind_straight instead of 1.06 s). Images do not depend on it."""
    if os.environ.get("TI_CPU_MAX_NUM_THREADS"):
        return {}
    return {"TI_CPU_MAX_NUM_THREADS": str(max(1, (os.cpu_count() or 1) // workers))}


def client_from_args(args):
    """connect(...) for the command line's --workers / --scheduler."""
    return connect(workers=args.workers, scheduler=args.scheduler)


def map_unordered(client, function, items, *, name: str, retries: int = 2):
    """Submit function(item) for every item; yield (index, result) as tasks finish. A task whose
    worker dies is rerun by the scheduler; an exception in a task is raised here."""
    distributed = require_distributed()
    token = uuid.uuid4().hex[:8]
    futures = {client.submit(function, item, key=f"taichi-hair-{name}-{token}-{k}", retries=retries,
                             pure=False): k for k, item in enumerate(items)}
    for future in distributed.as_completed(futures):
        yield futures[future], future.result()


# ---- frames of a run ------------------------------------------------------------------------------
@dataclass(frozen=True)
class RenderJob:
    """What a worker needs to draw a run's frames: the scene script's path (readable there),
    the sweep settings and the Shot overrides, as sorted ((name, value), ...) pairs."""

    script: str
    settings: tuple = ()
    overrides: tuple = ()


_prepared: dict = {}  # per worker process: repr(RenderJob) -> PreparedRun


def _prepared_run(job: RenderJob):
    """The job's scene prepared in this process (first call: Taichi initialised in the scene's
    precision, the interpolator and frame writer built), kept for the job's later frames."""
    from .runner import prepare_run
    key = repr(job)
    if key not in _prepared:
        _prepared.clear()  # one run at a time per worker: free the previous run's buffers
        _prepared[key] = prepare_run(job.script, settings=dict(job.settings), overrides=dict(job.overrides))
    return _prepared[key]


def render_task(job: RenderJob, frame: int, guides, pose, directors=None) -> dict:
    """On a worker: interpolate and render one frame; its PNG bytes and the wall times [s]."""
    from .runner import render_frame
    run = _prepared_run(job)
    times = {"interpolation": [], "rendering": []}
    with tempfile.TemporaryDirectory(prefix="taichi_hair_frame_") as tmp:
        path = Path(tmp) / f"frame_{frame:05d}.png"
        render_frame(path, frame, guides, pose, directors, run, times)
        png = path.read_bytes()
    return {"frame": frame, "png": png, "interpolation": times["interpolation"][0],
            "rendering": times["rendering"][0], "worker_pid": os.getpid()}


def write_atomically(path, data: bytes) -> None:
    """Write bytes to path through a temporary file in the same folder and a rename."""
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def run_scene(client, script, out_dir, *, frames=None, resume=False, progress=True, overrides=None,
              settings=None, usd=None) -> dict:
    """`runner.run_scene` with the frames interpolated and rendered on the cluster (module
    docstring). Same files (PNGs, MP4, state.npz, progress.json, with usd the guides' USD file:
    the client has the guides, not the dense hair, so Shot.usd must be "guides") and the same
    summary, plus "workers" and "frames_rendered" (PNGs written by this call, each once)."""
    from ..progress import ProgressBar
    from .run_output import (check_usd, checkpoint, frame_path, load_guides, open_usd_writer, remove_guides,
                             resume_point, run_summary, save_guides, write_usd_frame, write_video)
    from .runner import prepare_run, simulate_frame
    from .outdir import claim_out_dir
    distributed = require_distributed()
    if usd is not None:
        check_usd(usd)
    out, lock = claim_out_dir(out_dir, script, frames=frames, resume=resume, usd=usd)  # held until return
    run = prepare_run(script, overrides=overrides, settings=settings, draw=False)
    shot, sim = run.shot, run.sim
    if usd is not None and shot.usd != "guides":
        raise ValueError(f"--usd with --workers / --scheduler writes the guides only; this shot asks for "
                         f"usd={shot.usd!r} (the dense hair exists on the workers): run it serially")
    total = shot.frames if frames is None else frames
    done, pending = resume_point(out, sim, shot, total) if resume else (0, [])
    usd_writer = open_usd_writer(out / f"{Path(script).stem}.{usd}", shot, run.scene, resume, done) if usd else None
    job = RenderJob(script=str(Path(script).resolve()), settings=tuple(sorted((settings or {}).items())),
                    overrides=tuple(sorted((overrides or {}).items())))
    token, tasks, written = uuid.uuid4().hex[:8], distributed.as_completed(), []
    times = {"simulation": [], "interpolation": [], "rendering": []}

    def submit(frame, guides, pose, directors):
        tasks.add(client.submit(render_task, job, frame, guides, pose, directors, pure=False,
                                key=f"taichi-hair-frame-{token}-{frame:05d}"))

    def write(future):
        result = future.result()
        write_atomically(frame_path(out, result["frame"]), result["png"])
        remove_guides(out, result["frame"])
        times["interpolation"].append(result["interpolation"])
        times["rendering"].append(result["rendering"])
        written.append(result["frame"])
        bar.update(1)

    with ProgressBar(total, f"{Path(script).stem}", enabled=progress, done=done - len(pending)) as bar:
        for frame in pending:
            submit(frame, *load_guides(out, frame))
        for frame in range(done, total):
            # the workers' interpolators may turn dense edges with the guides' material frames;
            # this process builds none to ask, so every frame carries the directors
            guides, pose, directors = simulate_frame(sim, shot, times, directors=True)
            save_guides(out, frame, guides, pose, directors)
            if usd_writer is not None:
                write_usd_frame(usd_writer, frame, shot, sim, guides, None, pose)
            checkpoint(out, sim, shot, frame + 1)
            submit(frame, guides, pose, directors)
            while tasks.has_ready():
                write(next(tasks))
        for future in tasks:
            write(future)
    video = write_video(out, script, shot, total)
    summary = run_summary(script, total, done, times, video, sim)
    summary.update(workers=len(client.scheduler_info()["workers"]), frames_rendered=len(written))
    if usd_writer is not None:
        summary["usd"] = str(usd_writer.path)
    if len(set(written)) != len(written):  # cannot happen: one task per frame; checked all the same
        raise RuntimeError(f"{out}: a frame was written twice: {sorted(written)}")
    lock.close()
    return summary


# ---- timing --------------------------------------------------------------------------------------
def bench_rendering(script, *, frames: int = 48, workers: int = 2, rounds: int = 3, overrides=None,
                    log=None) -> dict:
    """The rendering part of a shot, serial against a LocalCluster of `workers`: simulate
    `frames` frames here (kept in memory), then time interpolating and rendering all of them in
    this process and on the cluster, alternately, `rounds` times (so both sides see the same
    drift in the machine's load), each side warmed up first (Taichi start-up and compiling
    excluded). Returns the wall times [s] per round, their ratios and the median ratio."""
    import statistics
    from .runner import needs_directors, prepare_run, render_frame, simulate_frame
    run = prepare_run(script, overrides=overrides)
    times = {"simulation": [], "interpolation": [], "rendering": []}
    shot_frames = [(k, *simulate_frame(run.sim, run.shot, times, needs_directors(run))) for k in range(frames)]
    serial, spread = [], []
    with connect(workers=workers) as client, tempfile.TemporaryDirectory(prefix="taichi_hair_bench_") as tmp:
        render_frame(Path(tmp) / "warm.png", *shot_frames[0], run, times)
        warm_up(client, script, shot_frames[0], overrides=overrides)
        for r in range(rounds):
            start = time.perf_counter()
            for k, guides, pose, directors in shot_frames:
                render_frame(Path(tmp) / f"frame_{k:05d}.png", k, guides, pose, directors, run, times)
            serial.append(time.perf_counter() - start)
            spread.append(time_rendering(client, script, shot_frames, overrides=overrides))
            if log:
                log(f"round {r}: serial {serial[-1]:.2f} s, {workers} workers {spread[-1]['wall_s']:.2f} s")
    ratios = [s / c["wall_s"] for s, c in zip(serial, spread)]
    return {"scene": str(script), "frames": frames, "overrides": dict(overrides or {}), "workers": workers,
            "serial_s": serial, "cluster_s": [c["wall_s"] for c in spread],
            "cluster_task_s": [c["task_s"] for c in spread], "speedup": ratios,
            "median_speedup": statistics.median(ratios)}


def warm_up(client, script, item, *, overrides=None) -> None:
    """One frame on every worker: Taichi started, the scene prepared, the kernels compiled."""
    distributed = require_distributed()
    job = RenderJob(script=str(Path(script).resolve()), overrides=tuple(sorted((overrides or {}).items())))
    distributed.wait([client.submit(render_task, job, *item, workers=[w], pure=False)
                      for w in client.scheduler_info()["workers"]])


def time_rendering(client, script, shot_frames, *, overrides=None) -> dict:
    """Wall time [s] to interpolate and render [(frame, guides, pose), ...] on the (warm)
    cluster, and the workers' seconds summed over the frames."""
    job = RenderJob(script=str(Path(script).resolve()), overrides=tuple(sorted((overrides or {}).items())))
    start = time.perf_counter()
    results = client.gather([client.submit(render_task, job, *item, pure=False) for item in shot_frames])
    wall = time.perf_counter() - start
    return {"workers": len(client.scheduler_info()["workers"]), "frames": len(results), "wall_s": wall,
            "task_s": float(sum(r["interpolation"] + r["rendering"] for r in results))}


def _main(argv=None) -> int:
    """python -m taichi_hair.app.cluster SCENE [--frames 48] [--workers 2] [--rounds 3] [--width W --height H
    --dense D]: `bench_rendering`, JSON on stdout."""
    import json
    import sys
    from ..validation import cli_int, one_line_parser_class
    from .runner import add_image_arguments
    parser = one_line_parser_class()(prog="python -m taichi_hair.app.cluster", description=bench_rendering.__doc__)
    parser.add_argument("scene")
    parser.add_argument("--frames", type=cli_int("--frames", 1, 100_000), default=48)
    parser.add_argument("--workers", type=cli_int("--workers", 1, 256), default=2)
    parser.add_argument("--rounds", type=cli_int("--rounds", 1, 1000), default=3)
    add_image_arguments(parser)
    args = parser.parse_args(argv)
    overrides = {k: v for k, v in (("width", args.width), ("height", args.height), ("dense_strands", args.dense))
                 if v is not None}
    from taichi_hair.app import cluster  # this module by its name: run as __main__, dask would pickle
    # render_task by value, with an empty cache of prepared scenes in every task
    result = cluster.bench_rendering(args.scene, frames=args.frames, workers=args.workers, rounds=args.rounds,
                                     overrides=overrides, log=lambda text: print(text, file=sys.stderr, flush=True))
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
