"""`taichi-hair bench --compile`: the cold compile time of each shipped scene's first frame.

Each cell (scene x integrator) runs in a subprocess of its own with a fresh, empty Taichi offline
cache (TI_OFFLINE_CACHE_FILE_PATH in a new temporary folder), so nothing compiled before is
reused: the time a new user waits on a first run. The child builds the scene as `taichi-hair run`
does (prepare_run, without the renderer), simulates its first frame and then a second one, and
reports per kernel instance (a kernel with one set of template arguments) the time of its first
launch split into Taichi's front end (Python AST to IR) and its back end (IR passes and LLVM),
wall and CPU seconds of the process (all threads; the machine may be shared, CPU time is the
steadier figure). The first frame's own time less the second frame's is the frame's compile
time as a user sees it.
"""

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

SCENES = Path(__file__).resolve().parents[2] / "scenes"


def cpu_seconds() -> float:
    """User + system CPU seconds of this process (every thread) so far."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class _Clock:
    def __init__(self):
        self.wall = time.perf_counter()
        self.cpu = cpu_seconds()

    def since(self) -> tuple:
        return time.perf_counter() - self.wall, cpu_seconds() - self.cpu


class KernelTimes:
    """Times Taichi's front end (Kernel.materialize) and back end (Program.compile_kernel, run
    on a kernel's first launch and answered from the caches after) per kernel instance, while
    installed (a context manager). rows: {name: {"front_s", "front_cpu_s", "back_s",
    "back_cpu_s", "instances"}}."""

    def __init__(self):
        self.rows: dict = {}

    def _add(self, name, wall, cpu, part):
        row = self.rows.setdefault(name, {"front_s": 0.0, "front_cpu_s": 0.0, "back_s": 0.0, "back_cpu_s": 0.0,
                                          "instances": 0})
        row[f"{part}_s"] += wall
        row[f"{part}_cpu_s"] += cpu
        if part == "front":
            row["instances"] += 1

    @contextmanager
    def installed(self):
        from taichi.lang import impl
        from taichi.lang.kernel_impl import Kernel
        materialize, launch = Kernel.materialize, Kernel.launch_kernel
        times = self

        class TimedProgram:  # forwards to Taichi's program, timing compile_kernel
            def __init__(self, prog, name):
                self._prog, self._name = prog, name

            def __getattr__(self, attr):
                return getattr(self._prog, attr)

            def compile_kernel(self, *args):
                clock = _Clock()
                out = self._prog.compile_kernel(*args)
                wall, cpu = clock.since()
                if wall > 1e-3:  # a cache hit answers in microseconds
                    times._add(self._name, wall, cpu, "back")
                return out

        def timed_materialize(kernel, key=None, args=None, arg_features=None):
            fresh = key not in kernel.compiled_kernels
            clock = _Clock()
            materialize(kernel, key=key, args=args, arg_features=arg_features)
            if fresh:
                times._add(kernel.func.__name__, *clock.since(), "front")

        def timed_launch(kernel, t_kernel, *args):
            runtime = impl.get_runtime()
            prog = runtime.prog
            runtime.prog = TimedProgram(prog, kernel.func.__name__)
            try:
                return launch(kernel, t_kernel, *args)
            finally:
                runtime.prog = prog

        Kernel.materialize, Kernel.launch_kernel = timed_materialize, timed_launch
        try:
            yield self
        finally:
            Kernel.materialize, Kernel.launch_kernel = materialize, launch


def measure_cell(script, integrator: str) -> dict:
    """In this process (Taichi not yet initialised): build `script` with `integrator`, simulate
    two frames; the first frame's and the second's wall and CPU seconds and the per-kernel
    compile times of everything the build and the first frame launched."""
    from .runner import prepare_run
    times = KernelTimes()
    with times.installed():
        clock = _Clock()
        run = prepare_run(script, settings={"integrator": integrator}, draw=False)
        build = clock.since()
        clock = _Clock()
        run.sim.step(run.shot.steps_per_frame)
        run.sim.positions()
        first = clock.since()
    clock = _Clock()
    run.sim.step(run.shot.steps_per_frame)
    run.sim.positions()
    second = clock.since()
    return {"scene": Path(script).stem, "integrator": integrator, "strands": run.sim.n_strands,
            "steps_per_frame": run.shot.steps_per_frame,
            "build_s": build[0], "build_cpu_s": build[1], "first_frame_s": first[0], "first_frame_cpu_s": first[1],
            "second_frame_s": second[0], "second_frame_cpu_s": second[1],
            "compile_s": first[0] - second[0], "compile_cpu_s": first[1] - second[1],
            "kernels": times.rows}


def run_cell(script, integrator: str, timeout: float) -> dict:
    """measure_cell in a subprocess with an empty offline cache of its own; a cell that fails or
    runs past `timeout` seconds reports why instead of numbers."""
    with tempfile.TemporaryDirectory(prefix="taichi_hair_cold_cache_") as cache:
        env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache)
        cmd = [sys.executable, "-m", "taichi_hair.app.compiletime", str(script), integrator]
        try:
            done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"scene": Path(script).stem, "integrator": integrator, "error": f"over {timeout:g} s"}
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {"scene": Path(script).stem, "integrator": integrator, "error": tail}
    return json.loads(done.stdout[done.stdout.index("{"):])


def shipped_scenes() -> list:
    return sorted(SCENES.glob("*.py"))


def format_cells(cells: list, kernels: bool = False) -> str:
    """The table: one row per cell; with `kernels` each cell's kernels under it, slowest first."""
    lines = [f"{'scene':16} {'integrator':10} {'strands':>7} {'steps':>5} {'first frame s':>13} "
             f"{'(cpu s)':>8} {'2nd frame s':>11} {'compile s':>9} {'(cpu s)':>8}"]
    for c in cells:
        if "error" in c:
            lines.append(f"{c['scene']:16} {c['integrator']:10} failed: {c['error']}")
            continue
        lines.append(f"{c['scene']:16} {c['integrator']:10} {c['strands']:7d} {c['steps_per_frame']:5d} "
                     f"{c['first_frame_s']:13.1f} {c['first_frame_cpu_s']:8.1f} {c['second_frame_s']:11.1f} "
                     f"{c['compile_s']:9.1f} {c['compile_cpu_s']:8.1f}")
        if kernels:
            rows = sorted(c["kernels"].items(), key=lambda kv: -(kv[1]["front_cpu_s"] + kv[1]["back_cpu_s"]))
            for name, r in rows:
                if r["front_cpu_s"] + r["back_cpu_s"] >= 0.05:
                    lines.append(f"    {name:40} x{r['instances']:<2d} front {r['front_s']:6.1f} s "
                                 f"({r['front_cpu_s']:6.1f} cpu)  back {r['back_s']:6.1f} s "
                                 f"({r['back_cpu_s']:6.1f} cpu)")
    lines.append("first frame: build excluded, simulation only (no interpolation or rendering), cold offline "
                 "cache; compile = first frame - second frame; wall s, (cpu s) = user + system of the process")
    return "\n".join(lines)


def compile_table(scenes, integrators, timeout: float, progress=None) -> list:
    cells = []
    for script in scenes:
        for integrator in integrators:
            cell = run_cell(script, integrator, timeout)
            if progress is not None:
                progress(format_cells([cell]).splitlines()[1])
            cells.append(cell)
    return cells


if __name__ == "__main__":
    print(json.dumps(measure_cell(sys.argv[1], sys.argv[2])))
