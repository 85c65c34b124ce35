"""`taichi-hair bench --against REV`: this tree's bench against an older commit's, in one run.

The older commit is checked out in a temporary `git worktree` and both trees run the same bench
command (`python -m taichi_hair bench --json ...`, each with its own tree first on PYTHONPATH),
alternating round by round so that a machine that speeds up or slows down during the run weighs
on both alike. Each row's figure is the median over the rounds of that row's ms per frame; the
ratio is this tree's over the older one's (below 1: faster now). Only options that every commit
of the bench understands are passed on (strands, repeats, integrator, precision, full-head
guides).
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
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


def run_tree(tree: Path, bench_args: list) -> list:
    """The bench's JSON results ([one dict per precision]) run from `tree`'s sources."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, "-m", "taichi_hair", "bench", "--json", *bench_args], cwd=tree,
                          env=env, capture_output=True, text=True)
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


def compare(rev: str, bench_args: list, rounds: int, progress=None) -> dict:
    """Both trees' medians per row and their ratio (this tree / rev)."""
    commit = resolve(rev)
    samples = {"this": {}, "against": {}}
    with checked_out(commit) as old_tree:
        trees = {"this": REPOSITORY, "against": old_tree}
        for k in range(rounds):
            for name in ("this", "against") if k % 2 == 0 else ("against", "this"):
                if progress:
                    progress(f"round {k + 1}/{rounds}: {name}")
                for row, ms in row_times(run_tree(trees[name], bench_args)).items():
                    samples[name].setdefault(row, []).append(ms)
    rows = []
    for row, times in samples["this"].items():
        old = samples["against"].get(row)
        this_ms = statistics.median(times)
        old_ms = statistics.median(old) if old else None
        rows.append({"row": row, "this_ms": this_ms, "against_ms": old_ms,
                     "ratio": this_ms / old_ms if old_ms else None})
    return {"this": _git("rev-parse", "--short", "HEAD"), "dirty": bool(_git("status", "--porcelain")),
            "against": commit[:7], "rounds": rounds, "bench_args": bench_args, "rows": rows}


def format_comparison(result: dict) -> str:
    this = result["this"] + (" + uncommitted changes" if result["dirty"] else "")
    lines = [f"bench: this tree ({this}) against {result['against']}, {result['rounds']} alternating rounds, "
             f"medians of ms per simulated frame",
             f"{'row':<48} {'this ms':>10} {'against ms':>11} {'ratio':>7}"]
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
