"""Where a report's rows run: in this process when its Taichi has (or can take) the precision
the rows need, else in a worker subprocess (`python -m taichi_hair.app.reports KIND --worker
--precision P`, its JSON answer after REPORT_MARK on stdout), or over a Dask cluster
(--workers N / --scheduler ADDR, taichi_hair.app.cluster). Taichi fixes its precision at init,
so float32 and float64 rows never share a process."""

import contextlib
import json
import subprocess
import sys

from .. import runtime
from . import cluster

REPORT_MARK = "-- taichi_hair report json --"
WORKER_MODULE = "taichi_hair.app.reports"  # the command line whose `KIND --worker` runs rows


def log_line(text: str) -> None:
    """A progress line on stderr (stdout holds the table or the JSON)."""
    print(text, file=sys.stderr, flush=True)


def in_process(precision: str, arch: str) -> bool:
    """Run `precision` here if Taichi is not initialised yet (then initialise it) or already is so."""
    if not runtime.taichi_is_initialized():
        runtime.init(arch=arch, precision=precision)
        return True
    return runtime.precision() == precision and runtime.arch() == arch


def subprocess_worker(kind: str, precision: str, arch: str, options: list, stdin=None, log=None):
    """`python -m taichi_hair.app.reports KIND --worker ...` in `precision`; its JSON answer.
    Progress lines pass through to our stderr when logging, else are kept for the error message."""
    cmd = [sys.executable, "-m", WORKER_MODULE, kind, "--worker", "--arch", arch, "--precision", precision, *options]
    done = subprocess.run(cmd, input=stdin, stdout=subprocess.PIPE, stderr=None if log else subprocess.PIPE,
                          text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{kind} worker ({precision}) failed (exit {done.returncode}):\n"
                           f"{(done.stderr or '')[-4000:]}")
    return json.loads(done.stdout[done.stdout.index(REPORT_MARK) + len(REPORT_MARK):])


def worker_answer(part) -> None:
    """A worker's answer on stdout, after REPORT_MARK (Taichi may print before it)."""
    print(REPORT_MARK + json.dumps(part))


def cluster_client(args):
    """A dask client for --workers / --scheduler (taichi_hair.app.cluster), else a context of None."""
    return cluster.client_from_args(args) if cluster.wanted(args) else contextlib.nullcontext()

