"""`taichi-hair bench --against REV`: this tree's bench against an older commit's, in one run;
with `--scene SCRIPT`, a scene's run (the main job: scenes/wind_straight.py) instead of the table.

The older commit is checked out in a temporary `git worktree` and both trees run the same bench
command (`python -m taichi_hair bench --json ...`, each with its own tree first on PYTHONPATH),
alternating round by round so that a machine that speeds up or slows down during the run weighs
on both alike. Each row's figure is the median over the rounds of that row's ms per frame; the
ratio is this tree's over the older one's (below 1: faster now). Only options that every commit
of the bench understands are passed on (strands, repeats, integrator, precision, full-head
guides). A scene runs as `python -m taichi_hair run SCRIPT --frames N --no-progress` into a
fresh folder, after one untimed frame in each tree (its kernels compiled into Taichi's offline
cache); its rows are the run's wall time, its CPU time (all threads; steadier than wall time
when the machine's speed drifts, blind to what parallel work gains) and the medians per frame
its summary line prints.
"""

import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parents[2]


def _git(*args, cwd=REPOSITORY) -> str:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout.strip()


def resolve(rev: str) -> str:
    """The full commit hash of `rev`, or ValueError naming --against."""
    try:
        return _git("rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}")
    except (subprocess.CalledProcessError, FileNotFoundError):
        raise ValueError(f"--against must name a commit of this repository ({REPOSITORY}), got {rev!r}") from None


@contextmanager
def checked_out(commit: str):
    """A temporary worktree of `commit`, removed afterwards."""
    with tempfile.TemporaryDirectory(prefix="taichi_hair_against_") as tmp:
        tree = Path(tmp) / "tree"
        _git("worktree", "add", "--detach", "--quiet", str(tree), commit)
        try:
            yield tree
        finally:
            _git("worktree", "remove", "--force", str(tree))


def tree_env(tree: Path) -> dict:
    """This process's environment with `tree` first on PYTHONPATH: a child runs that tree's sources."""
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]))


def run_tree(tree: Path, bench_args: list) -> list:
    """The bench's JSON results ([one dict per precision]) run from `tree`'s sources."""
    done = subprocess.run([sys.executable, "-m", "taichi_hair", "bench", "--json", *bench_args], cwd=tree,
                          env=tree_env(tree), capture_output=True, text=True)
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise RuntimeError(f"the bench failed in {tree}: {tail}")
    return json.loads(done.stdout[done.stdout.index("["):])


def row_times(results: list) -> dict:
    """{row name: ms per frame} of one bench run."""
    rows = {}
    for result in results:
        for case in result["cases"]:
            rows[f"{result['precision']} {case.get('integrator', 'explicit')} {case['strands']} guides"] = \
                case["ms_per_frame"]
        for row in result.get("full_head", {}).get("rows", []):
            interaction = "hair-hair" if row["hair_interaction"] else ""
            name = f"{result['precision']} {row.get('integrator', 'explicit')} full head {row['guides']} " \
                   f"{row.get('style', 'straight')} {interaction}".rstrip()
            rows[name] = row["ms_per_frame"]
    return rows


def scene_times(tree: Path, script: str, frames: int) -> dict:
    """{row: value} of one run of `script` (a path inside the tree) from `tree`'s sources: its
    wall time [s], its CPU time [s] (all its threads, user + system; where the platform
    reports children's CPU time) and the median ms per frame of simulation, interpolation and
    rendering. CPU time is steadier than wall time on a machine whose speed drifts under other
    load, but it misses what more parallel work gains: the two rows answer different questions."""
    with tempfile.TemporaryDirectory(prefix="taichi_hair_scene_") as out:
        start, cpu_start = time.perf_counter(), _children_cpu()
        done = subprocess.run([sys.executable, "-m", "taichi_hair", "run", script, "--frames", str(frames),
                               "--no-progress", "--out", out], cwd=tree, env=tree_env(tree), capture_output=True,
                              text=True)
        wall = time.perf_counter() - start
        cpu = None if cpu_start is None else _children_cpu() - cpu_start
    found = re.search(r"median ms per frame: simulation ([0-9.]+), interpolation ([0-9.]+), "
                      r"rendering ([0-9.]+)", done.stdout)
    if done.returncode != 0 or found is None:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise RuntimeError(f"`taichi-hair run {script}` failed in {tree}: {tail}")
    sim, interp, render = map(float, found.groups())
    rows = {f"{script} wall s ({frames} frames)": wall}
    if cpu is not None:
        rows[f"{script} CPU s ({frames} frames)"] = cpu
    rows.update({"simulation ms per frame": sim, "interpolation ms per frame": interp,
                 "rendering ms per frame": render})
    return rows


def _children_cpu() -> float | None:
    """User + system CPU seconds of this process's finished children, None where the platform
    has no `resource` module (Windows)."""
    try:
        import resource
    except ImportError:
        return None
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def check_scene(script: str) -> str:
    """The scene path for --scene, or ValueError naming it: a .py file inside this repository
    (each tree runs its own copy)."""
    path = Path(script)
    inside = (REPOSITORY / path).resolve() if not path.is_absolute() else path.resolve()
    try:
        relative = inside.relative_to(REPOSITORY)
    except ValueError:
        raise ValueError(f"--scene must be a scene script inside this repository ({REPOSITORY}), got {script!r}") from None
    if inside.suffix != ".py" or not inside.is_file():
        raise ValueError(f"--scene must be an existing .py scene script (e.g. scenes/wind_straight.py), got {script!r}")
    return str(relative)


def compare(rev: str, bench_args: list, rounds: int, progress=None, scene=None, frames: int = 24) -> dict:
    """Both trees' medians per row and their ratio (this tree / rev): the bench table's rows, or
    with `scene` (check_scene's path) that scene's run of `frames` frames (scene_times)."""
    commit = resolve(rev)
    samples = {"this": {}, "against": {}}
    with checked_out(commit) as old_tree:
        trees = {"this": REPOSITORY, "against": old_tree}
        if scene is not None:
            if not (old_tree / scene).is_file():
                raise ValueError(f"--scene {scene} does not exist at {rev}")
            for name in trees:  # one untimed frame each: the kernels compiled into the offline cache
                if progress:
                    progress(f"warm-up: {name}")
                scene_times(trees[name], scene, 1)
        for k in range(rounds):
            for name in ("this", "against") if k % 2 == 0 else ("against", "this"):
                if progress:
                    progress(f"round {k + 1}/{rounds}: {name}")
                measured = (scene_times(trees[name], scene, frames) if scene is not None
                            else row_times(run_tree(trees[name], bench_args)))
                for row, value in measured.items():
                    samples[name].setdefault(row, []).append(value)
    rows = []
    for row, times in samples["this"].items():
        old = samples["against"].get(row)
        this_ms = statistics.median(times)
        old_ms = statistics.median(old) if old else None
        rows.append({"row": row, "this_ms": this_ms, "against_ms": old_ms,
                     "ratio": this_ms / old_ms if old_ms else None})
    return {"this": _git("rev-parse", "--short", "HEAD"), "dirty": bool(_git("status", "--porcelain")),
            "against": commit[:7], "rounds": rounds, "bench_args": bench_args, "scene": scene,
            "frames": frames if scene is not None else None, "rows": rows}


def format_comparison(result: dict) -> str:
    this = result["this"] + (" + uncommitted changes" if result["dirty"] else "")
    what = ("medians of ms per simulated frame" if not result.get("scene")
            else f"medians of `taichi-hair run {result['scene']} --frames {result['frames']}`")
    lines = [f"bench: this tree ({this}) against {result['against']}, {result['rounds']} alternating rounds, {what}",
             f"{'row':<48} {'this':>10} {'against':>11} {'ratio':>7}"]
    for r in result["rows"]:
        old = f"{r['against_ms']:11.2f}" if r["against_ms"] is not None else f"{'-':>11}"
        ratio = f"{r['ratio']:7.2f}" if r["ratio"] is not None else f"{'-':>7}"
        lines.append(f"{r['row']:<48} {r['this_ms']:10.2f} {old} {ratio}")
    lines.append("ratio < 1: this tree is faster")
    return "\n".join(lines)


def bench_args_of(args) -> list:
    """The bench options every commit understands, from parsed `taichi-hair bench` arguments."""
    strands = args.strands if isinstance(args.strands, str) else ",".join(map(str, args.strands))
    return ["--strands", strands, "--repeats", str(args.repeats), "--integrator", args.integrator,
            "--precision", args.precision, "--head-guides", str(args.head_guides), "--dense", "0",
            "--stage-steps", "1"]
