"""`taichi-hair report implicit`: the implicit step against the explicit one on a scene (default
scenes/shake_curly.py, as it is), in one process and one run:

  speed     simulation ms per frame of the whole scene, explicit (substepped to its bound) and
            implicit at the shot's dt; median over frames after the first (which compiles).
  accuracy  a subset of the scene's guides (every k-th) for `seconds` of its motion: the tips'
            deviation from a tiny-step explicit reference (dt = reference_dt, substepped to the
            bound) at the end, RMS and max over strands / strand length, for each integrator at
            dt = 1, 2, 4, 8, 16 ms, with the stepping wall time (after a warm-up run of each
            integrator, so compilation is excluded), the substeps, the largest strain and the
            deepest node below the head's surface.

  cantilever  the first bending mode of a real hair (human hair, round, L 10 cm, 40 segments,
            no gravity, no drag), started in the clamped beam's first mode shape at 1 % of L:
            its frequency (zero crossings over CANTILEVER_PERIODS periods) against the beam
            formula 1.875^2 / (2 pi L^2) sqrt(EI / rho A), and the amplitude it loses per period
            (the step's numerical damping: no physical damping is set), for both integrators at
            dt = 0.25 to 16 ms.

Everything printed is measured here; the JSON goes to --out.
"""

import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import runtime
from ..rods.groom import Groom
from ..rods.materials import Material
from ..rods.references import cantilever_first_frequency, first_mode_slope
from ..solver.simulator import Simulator
from ..solver.stability import SimulationDiverged
from ..validation import cli_int, cli_real
from .accuracy_report import amplitude_loss_per_period, clamped_beam, oscillation_frequency, sample_tip_z
from .runner import load_scene_module
from .stamp import stamp

STEPS_MS = (1, 2, 4, 8, 16)
CANTILEVER_MS = (0.25, 0.5, 1, 2, 4, 8, 16)
CANTILEVER_LENGTH, CANTILEVER_SEGMENTS, CANTILEVER_PERIODS = 0.1, 40, 5


def _quiet_simulator(scene, dt, integrator):
    return Simulator.from_scene(scene, dt=dt, integrator=integrator)


def subset(scene, every: int):
    """The scene with every `every`-th guide of its groom (same head, material and motion)."""
    keep = range(0, scene.groom.n_strands, every)
    groom = Groom.from_polylines([scene.groom.strand(s) for s in keep])
    materials = scene.material
    if isinstance(materials, (list, tuple)):
        materials = [materials[s] for s in keep]
    return replace(scene, groom=groom, material=materials)


def head_depth(sim, head_field) -> float:
    """The deepest free node's signed distance from the head's surface [m] (negative: inside),
    in head coordinates; head_field: Head.distance_field()."""
    rotation, translation = sim.head_transform
    x = sim.positions()[:, 1:].reshape(-1, 3)
    return float(head_field.sample((x - translation) @ rotation).min())


def _head_field(scene):
    return None if scene.head is None else scene.head.distance_field()


def max_strain(sim) -> float:
    x = sim.positions()
    rest = sim.model.rest_length.to_numpy()
    edges = np.linalg.norm(np.diff(x, axis=1), axis=2)
    valid = rest > 0
    return float(np.abs(edges[valid] / rest[valid] - 1).max())


def run_for(sim, seconds: float, frame_s: float, head_field=None):
    """Step `seconds` in chunks of about a frame; returns (per-chunk wall times [s], the deepest
    node's distance from the head's surface [m] (head_depth; inf without head_field), the
    largest strain)."""
    per_frame = max(1, round(frame_s / sim.dt))
    total = max(1, round(seconds / sim.dt))
    walls, depth, strain = [], float("inf"), 0.0
    done = 0
    while done < total:
        k = min(per_frame, total - done)
        start = time.perf_counter()
        sim.step(k)
        walls.append(time.perf_counter() - start)
        done += k
        if head_field is not None:
            depth = min(depth, head_depth(sim, head_field))
        strain = max(strain, max_strain(sim))
    return walls, depth, strain


def speed_rows(scene, dt: float, frames: int, frame_s: float, log=print) -> list:
    """Simulation ms per frame of the whole scene for both integrators, same run."""
    rows = []
    for integrator in ("explicit", "implicit"):
        sim = _quiet_simulator(scene, dt, integrator)
        walls, depth, strain = run_for(sim, frames * frame_s, frame_s, _head_field(scene))
        row = {"integrator": integrator, "dt": dt, "substeps": sim.substeps, "guides": scene.groom.n_strands,
               "ms_per_frame": 1e3 * statistics.median(walls[1:] if len(walls) > 1 else walls),
               "first_frame_ms": 1e3 * walls[0], "head_depth_mm": 1e3 * depth, "max_strain": strain}
        rows.append(row)
        log(f"speed {integrator}: {row['ms_per_frame']:.0f} ms/frame ({row['substeps']} substeps)")
    return rows


def tips(sim) -> np.ndarray:
    x = sim.positions()
    return x[np.arange(sim.n_strands), sim.groom.node_counts - 1]


def accuracy_rows(scene, seconds: float, reference_dt: float, frame_s: float, log=print,
                  steps_ms=STEPS_MS) -> dict:
    """Tip deviation from the tiny-step explicit reference for both integrators at each of
    steps_ms [ms]."""
    lengths = scene.groom.lengths()
    reference = _quiet_simulator(scene, reference_dt, "explicit")
    start = time.perf_counter()
    run_for(reference, seconds, frame_s)
    result = {"reference_dt": reference_dt, "reference_substeps": reference.substeps,
              "reference_wall_s": time.perf_counter() - start, "rows": []}
    target = tips(reference)
    for integrator in ("explicit", "implicit"):
        # warm-up, not timed: a frame's launches and a single step's, another kernel variant with
        # a moving head, which a timed run takes where a frame's steps do not divide its own;
        # compiled there, the implicit step's tens of seconds would count as stepping
        warm = _quiet_simulator(scene, max(steps_ms) * 1e-3, integrator)
        run_for(warm, 3 * frame_s, frame_s)
        warm.step(1)
        for ms in steps_ms:
            sim = _quiet_simulator(scene, ms * 1e-3, integrator)
            row = {"integrator": integrator, "dt": ms * 1e-3, "substeps": sim.substeps}
            try:
                walls, depth, strain = run_for(sim, seconds, frame_s, _head_field(scene))
                error = np.linalg.norm(tips(sim) - target, axis=1) / lengths
                row.update(wall_s=sum(walls), tip_rms=float(np.sqrt(np.mean(error ** 2))),
                           tip_max=float(error.max()), head_depth_mm=1e3 * depth, max_strain=strain)
            except SimulationDiverged as err:
                row.update(outcome=f"diverged: {err}")
            result["rows"].append(row)
            log(f"accuracy {integrator} dt {ms:g} ms: {row.get('tip_rms', row.get('outcome'))}")
    return result


def cantilever_row(dt: float, integrator: str, periods: float = CANTILEVER_PERIODS) -> dict:
    """The real-hair cantilever's first mode (module doc) at `dt` [s] with `integrator`, over
    `periods` periods; wall_s [s] is the stepping time (compilation included on a first run)."""
    material = Material()
    expected = cantilever_first_frequency(CANTILEVER_LENGTH, material.bending_stiffness[0], material.linear_density)
    bent = clamped_beam(CANTILEVER_SEGMENTS, length=CANTILEVER_LENGTH,
                        slope=lambda s: 0.01 * CANTILEVER_LENGTH * first_mode_slope(s, CANTILEVER_LENGTH))
    sim = Simulator(clamped_beam(CANTILEVER_SEGMENTS, length=CANTILEVER_LENGTH), material, dt=dt,
                    gravity=(0.0, 0.0, 0.0), integrator=integrator)
    sim.set_positions(bent.positions)
    start = time.perf_counter()
    t, z = sample_tip_z(sim, periods / expected, 0.01 / expected)
    frequency = oscillation_frequency(t, z)
    return {"integrator": integrator, "dt": dt, "substeps": sim.substeps, "wall_s": time.perf_counter() - start,
            "frequency_hz": frequency, "expected_hz": expected, "frequency_error": frequency / expected - 1,
            "loss_per_period": amplitude_loss_per_period(t, z)}


def cantilever_rows(log=print) -> list:
    rows = []
    for integrator in ("explicit", "implicit"):
        cantilever_row(CANTILEVER_MS[-1] * 1e-3, integrator, periods=0.05)  # compiles: not timed
        for ms in CANTILEVER_MS:
            rows.append(cantilever_row(ms * 1e-3, integrator))
            r = rows[-1]
            log(f"cantilever {integrator} dt {ms:g} ms: frequency {r['frequency_error']:+.2e}, "
                f"loss per period {r['loss_per_period']:.2e}")
    return rows


def format_cantilever(rows: list) -> str:
    if not rows:
        return ""
    lines = [f"real-hair cantilever (L {CANTILEVER_LENGTH * 100:g} cm, {CANTILEVER_SEGMENTS} segments, "
             f"first mode {rows[0]['expected_hz']:.4g} Hz by the beam formula, no damping set), "
             f"{CANTILEVER_PERIODS} periods:",
             f"  {'integrator':10} {'dt ms':>6} {'substeps':>8} {'wall s':>7} {'frequency Hz':>12} "
             f"{'f / f_beam - 1':>14} {'amplitude lost / period':>23}"]
    for r in rows:
        lines.append(f"  {r['integrator']:10} {1e3 * r['dt']:6.2f} {r['substeps']:8d} {r['wall_s']:7.2f} "
                     f"{r['frequency_hz']:12.5g} {r['frequency_error']:+14.2e} {r['loss_per_period']:23.2e}")
    return "\n".join(lines)


def implicit_report(script="scenes/shake_curly.py", *, frames: int = 12, every: int = 10,
                    seconds: float = 0.5, reference_dt: float = 1e-4, out_dir="out/reports", log=print,
                    scene_rows: bool = True, cantilever: bool = True, steps_ms=STEPS_MS) -> dict:
    """scene_rows: the scene's speed and accuracy rows (at steps_ms [ms]); cantilever: the
    cantilever rows. Writes implicit.json, and implicit.png (tip error against wall time, both
    integrators, log-log) when there are accuracy rows."""
    module = load_scene_module(script) if scene_rows else None  # the cantilever alone needs no scene
    runtime.init(precision=getattr(module, "PRECISION", "float32"))
    result = {"report": "implicit", "stamp": None, "scene": str(script), "precision": runtime.precision(),
              "speed": [], "accuracy": None, "every": every, "seconds": seconds, "frames": frames,
              "reference_dt": reference_dt, "steps_ms": list(steps_ms), "scene_rows": scene_rows,
              "cantilever": cantilever_rows(log) if cantilever else []}
    if scene_rows:
        scene = module.build()
        shot = module.shot() if callable(getattr(module, "shot", None)) else None
        frame_s = 1.0 / (shot.fps if shot is not None else 24)
        dt = shot.dt if shot is not None else 1e-3
        result["speed"] = speed_rows(scene, dt, frames, frame_s, log) if frames else []
        result["accuracy"] = accuracy_rows(subset(scene, every), seconds, reference_dt, frame_s, log, steps_ms)
    result["stamp"] = stamp()  # when and where it was measured: at the end, as the other reports
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "implicit.json").write_text(json.dumps(result, indent=1))
    if result["accuracy"] is not None:
        from render import write_png  # the renderer loads only where a figure is drawn
        write_png(out / "implicit.png", implicit_figure(result).image)
    return result


def implicit_figure(result: dict):
    """Tip RMS / L against stepping wall time [s], log-log: a line per integrator through its
    steps (marker per step; diverged runs left out)."""
    from render.plot import PALETTE, Series, loglog
    series, legend = [], []
    for k, integrator in enumerate(("explicit", "implicit")):
        rows = [r for r in result["accuracy"]["rows"] if r["integrator"] == integrator and "tip_rms" in r]
        steps = ", ".join(f"{1e3 * r['dt']:.3g}" for r in rows)
        series.append(Series(x=[r["wall_s"] for r in rows], y=[r["tip_rms"] for r in rows], colour=PALETTE[k],
                             marker="o" if k == 0 else "s"))
        legend.append((f"{integrator} dt {steps} ms", PALETTE[k], "o" if k == 0 else "s", True, False))
    acc = result["accuracy"]
    legend.append((f"reference: explicit dt {1e3 * acc['reference_dt']:g} ms", (0, 0, 0), "", False, False))
    return loglog(series, title=f"{Path(result['scene']).stem}: tip error vs wall time",
                  x_label="wall time [s]", y_label="tip RMS / L", legend=legend)


def format_implicit(result: dict) -> str:
    lines = [f"scene {result['scene']} ({result['precision']})"]
    if result["speed"]:
        lines.append("whole scene: simulation ms per frame (median over frames after the first)")
        lines.append(f"  {'integrator':10} {'guides':>6} {'dt ms':>6} {'substeps':>8} {'ms/frame':>9} "
                     f"{'head depth mm':>13} {'max strain':>10}")
        for r in result["speed"]:
            lines.append(f"  {r['integrator']:10} {r['guides']:6d} {1e3 * r['dt']:6.2f} {r['substeps']:8d} "
                         f"{r['ms_per_frame']:9.0f} {r['head_depth_mm']:13.3f} {r['max_strain']:10.1e}")
        explicit, implicit = (r["ms_per_frame"] for r in result["speed"])
        lines.append(f"  implicit speed-up: {explicit / implicit:.2f}x")
    acc = result["accuracy"]
    if result.get("cantilever"):
        lines.append(format_cantilever(result["cantilever"]))
    if acc is None:
        return "\n".join(lines)
    lines.append(f"every {result['every']}-th guide, {result['seconds']:g} s: tip deviation / L from explicit at "
                 f"dt {1e3 * acc['reference_dt']:g} ms ({acc['reference_substeps']} substeps, "
                 f"{acc['reference_wall_s']:.1f} s)")
    lines.append(f"  {'integrator':10} {'dt ms':>6} {'substeps':>8} {'wall s':>7} {'tip rms':>9} {'tip max':>9} "
                 f"{'head depth mm':>13} {'max strain':>10}")
    for r in acc["rows"]:
        if "outcome" in r:
            lines.append(f"  {r['integrator']:10} {1e3 * r['dt']:6.3g} {r['substeps']:8d}  {r['outcome'][:90]}")
            continue
        lines.append(f"  {r['integrator']:10} {1e3 * r['dt']:6.3g} {r['substeps']:8d} {r['wall_s']:7.2f} "
                     f"{r['tip_rms']:9.2e} {r['tip_max']:9.2e} {r['head_depth_mm']:13.3f} {r['max_strain']:10.1e}")
    return "\n".join(lines)


def add_parser(sub) -> None:
    p = sub.add_parser("implicit", help="the implicit step against the explicit one: speed and accuracy "
                                        "against a tiny-step reference on a scene")
    p.add_argument("--scene", default="scenes/shake_curly.py")
    p.add_argument("--frames", type=cli_int("--frames", 0, 100_000), default=12, help="frames of the whole scene timed (0: skip)")
    p.add_argument("--every", type=cli_int("--every", 1, 100_000), default=10, help="accuracy on every k-th guide")
    p.add_argument("--seconds", type=cli_real("--seconds", 0.0, 100.0, unit="s"), default=0.5, help="simulated seconds of the accuracy runs")
    p.add_argument("--reference-dt", type=cli_real("--reference-dt", 0.0, 0.1, unit="s"), default=1e-4, help="the explicit reference's dt [s]")
    p.add_argument("--steps-ms", default=",".join(f"{ms:g}" for ms in STEPS_MS),
                   help="comma-separated steps [ms] of the accuracy rows (default %(default)s)")
    p.add_argument("--out", default="out/reports")
    p.add_argument("--json", action="store_true")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--cantilever-only", action="store_true", help="only the real-hair cantilever's "
                       "frequency and damping rows")
    which.add_argument("--no-cantilever", action="store_true", help="only the scene's rows")
    p.set_defaults(func=_main)


def _steps(text: str) -> tuple:
    try:
        steps = tuple(float(v) for v in text.split(","))
    except ValueError:
        steps = ()
    if not steps or not all(0 < v <= 100 for v in steps):
        raise ValueError(f"--steps-ms must be comma-separated steps in (0, 100] ms, got {text!r}")
    return steps


def _main(args) -> int:
    result = implicit_report(args.scene, frames=args.frames, every=args.every, seconds=args.seconds,
                             reference_dt=args.reference_dt, out_dir=args.out,
                             scene_rows=not args.cantilever_only, cantilever=not args.no_cantilever,
                             steps_ms=_steps(args.steps_ms),
                             log=lambda text: print(text, file=sys.stderr, flush=True))
    print(json.dumps(result, indent=1) if args.json else format_implicit(result))
    return 0
