"""`taichi-hair report accuracy`: error against run time on references independent of the code
(taichi_hair.rods.references). Every number is measured on this machine; wall time is the stepping
time of one run after a warm-up run of the same configuration, so compile time is excluded.

  cantilever  static tip of a clamped horizontal beam (L 1 m, r 1 cm, rho 1000, E 1e7, w L^3/EI = 39)
              at rest after damping, vs the elastica (shooting); error = |tip - tip_ref| / L.
  frequency   first vibration frequency of the same beam (no gravity, started in its first mode
              at 1 % of L), from the tip's zero crossings over 2.25 periods, vs the beam formula
              1.875^2 / (2 pi L^2) sqrt(EI / rho A); error = |f / f_ref - 1|.
  helix       a curly elliptic human hair (L 0.2 m, curl radius 1 cm, pitch 2 cm, ellipticity 1.5)
              hanging under gravity, at rest after damping, vs a fine solve of the same strand
              (4x the finest segment count, float64, quasistatic twist); error = |tip - tip_ref| / L.
  curl down / curl horizontal
              a round curled rod (curl radius 5 cm, pitch 5 cm, 3 turns, r 1 cm, E 1e7, G E/3,
              rho 1300) hanging with its helix axis down / horizontal, at rest after damping, vs the
              continuum Kirchhoff rod with intrinsic curvature and twist (references.hanging_curl);
              error = |tip - tip_ref| / |drop|, drop = the reference tip's displacement under
              gravity. Side by side: "curl ..." with the rotation strain measure (strain="rotation",
              the default), "curl ... der" with the DER measure (strain="der"), "curl ... edge" with
              DER and root="edge" (the first edge held rigid instead of the clamp at the root node).
Each precision runs in its own process (Taichi fixes it at init; report_dispatch), and the rows
are merged; with --workers N / --scheduler ADDR one task per row runs over a Dask cluster.
"""

import functools
import json
import math
import statistics
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .. import runtime
from ..rods.groom import Groom
from ..rods.materials import Material
from ..rods.references import (cantilever_elastica_tip, cantilever_first_frequency, first_mode_slope,
                               hanging_curl)
from ..solver.simulator import Simulator
from .cluster import map_unordered
from .report_dispatch import in_process, subprocess_worker
from .stamp import stamp

BEAM_LENGTH = 1.0
HELIX_LENGTH, HELIX_CURL, HELIX_PITCH = 0.2, 0.01, 0.02
HELIX_OMEGA = 10.0  # [rad/s] damping rate of the helix's drag 2 rho A omega (it settles in < 1 s)
CURL_RADIUS, CURL_PITCH, CURL_TURNS = 0.05, 0.05, 3
CURL_LENGTH = CURL_TURNS * math.hypot(2 * math.pi * CURL_RADIUS, CURL_PITCH)
CURL_AXES = {"down": (0.0, 0.0, -1.0), "horizontal": (1.0, 0.0, 0.0)}
CURL_OMEGA, CURL_SETTLED, CURL_MAX_TIME = 12.0, 1e-9, 6.0  # drag rate [rad/s]; tip motion [m] per 0.1 s
CANTILEVER_TIME, HELIX_TIME, FREQUENCY_PERIODS = 6.0, 2.0, 2.25


# ---- the strands ------------------------------------------------------------------------------------
def clamped_beam(n_segments: int, slope=None, length: float = BEAM_LENGTH):
    """Horizontal beam of `length` [m] along +x clamped at its root node at the origin;
    slope(s) [rad] optionally bends it (exact edge lengths)."""
    ds = length / n_segments
    theta = np.zeros(n_segments) if slope is None else slope(ds * (np.arange(n_segments) + 0.5))
    steps = ds * np.stack([np.cos(theta), np.zeros_like(theta), np.sin(theta)], axis=1)
    return Groom.from_polylines(np.vstack([[0.0, 0, 0], np.cumsum(steps, axis=0)]))


def clamped_helix(n_segments: int):
    """The curly test strand hanging along -z: a helix (radius HELIX_CURL, pitch HELIX_PITCH) of
    length HELIX_LENGTH clamped at its root node, nodes at arc length s = k ds (the tip is the
    same material point at every resolution)."""
    ds = HELIX_LENGTH / n_segments
    rise = HELIX_PITCH / (2 * math.pi)
    omega = 1.0 / math.hypot(HELIX_CURL, rise)
    angle = omega * ds * np.arange(n_segments + 1)
    return Groom.from_polylines(np.stack([HELIX_CURL * (np.cos(angle) - 1), HELIX_CURL * np.sin(angle),
                                          -rise * angle], axis=1))


def beam_material() -> Material:
    return Material(youngs_modulus=1e7, shear_modulus=1e7 / 3, radius=0.01, density=1000.0)


def helix_material() -> Material:
    return Material(ellipticity=1.5)  # human hair: E 3 GPa, G 1 GPa, r 40 um, rho 1300


def curl_material() -> Material:
    return Material(youngs_modulus=1e7, shear_modulus=1e7 / 3, radius=0.01, density=1300.0)


def curl_groom(n_segments: int, axis: str) -> Groom:
    """The curled rod of the `curl` rows, its helix axis along CURL_AXES[axis], root at the origin."""
    return Groom.curly(roots=[[0.0, 0.0, 0.0]], directions=[CURL_AXES[axis]], length=CURL_LENGTH,
                       n_nodes=n_segments + 1, curl_radius=CURL_RADIUS, curl_pitch=CURL_PITCH)




@functools.lru_cache(maxsize=None)
def curl_reference(axis: str) -> dict:
    """The continuum's tip [m] under gravity and its drop [m] for the curl rows' rod (hanging_curl)."""
    m = curl_material()
    stiffness = (m.bending_stiffness[0], m.bending_stiffness[1], m.twist_stiffness)
    return hanging_curl(CURL_LENGTH, CURL_RADIUS, CURL_PITCH, CURL_AXES[axis], stiffness, m.linear_density)



# ---- accuracy runs ----------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class AccuracySweep:
    """Segment counts per case (at base_dt [s]) and time steps [s] (at dt_segments), twist modes
    of the helix, the helix reference's refinement factor over the finest helix count, and the
    timed runs per row (median wall time; one run when a run takes over 2 s)."""

    cantilever_segments: tuple = (12, 25, 50, 100, 200)
    frequency_segments: tuple = (12, 25, 50, 100, 200)
    helix_segments: tuple = (12, 25, 50)
    curl_segments: tuple = (25, 50, 100, 200)
    base_dt: float = 1e-3
    dts: tuple = (0.25e-3, 0.5e-3, 2e-3)
    dt_segments: int = 25
    twists: tuple = ("quasistatic", "kmoch")
    reference_factor: int = 4
    repeats: int = 3


FULL_SWEEP = AccuracySweep()
QUICK_SWEEP = AccuracySweep(cantilever_segments=(12, 25, 50), frequency_segments=(12, 25),
                            helix_segments=(12, 25), curl_segments=(25, 50), dts=(0.5e-3, 2e-3), dt_segments=12, repeats=1)


def _simulator(groom, material, **options):
    return Simulator(groom, material, **options)


def _timed(make, advance, repeats):
    """Warm up a throwaway simulator from make() (compiles its kernels), then time advance(sim) on
    fresh ones, `repeats` times (once if a run takes over 2 s). Returns (last sim, median wall
    seconds, what advance returned, runs timed)."""
    make().step(2)
    walls = []
    while len(walls) < repeats and (not walls or walls[-1] <= 2.0):
        sim = make()
        start = time.perf_counter()
        out = advance(sim)
        walls.append(time.perf_counter() - start)
    return sim, statistics.median(walls), out, len(walls)


def _settle(sim, seconds):
    """Run to `seconds`; returns the tip's motion [m] over the last 0.1 s (how settled it is)."""
    sim.run(seconds - 0.1, progress=False)
    before = sim.positions()[0, -1]
    sim.run(0.1, progress=False)
    return float(np.linalg.norm(sim.positions()[0, -1] - before))


def _row(case, n, dt, twist, timed, **extra):
    sim, wall, _, runs = timed
    return {"case": case, "segments": n, "dt": dt, "twist": twist, "precision": runtime.precision(),
            "wall_s": wall, "runs": runs, "steps": sim.steps_taken, "substeps": sim.substeps, "sim_time": sim.time, **extra}


def cantilever_row(n: int, dt: float, repeats: int = 1) -> dict:
    m = beam_material()
    ei, rho_a = m.bending_stiffness[0], m.linear_density
    drag = 2 * rho_a * 2 * math.pi * cantilever_first_frequency(BEAM_LENGTH, ei, rho_a)  # every mode damped at omega1

    def make():
        return _simulator(clamped_beam(n), m, dt=dt, drag=drag, twist="none")
    timed = _timed(make, lambda s: _settle(s, CANTILEVER_TIME), repeats)
    tip = timed[0].positions()[0, -1][[0, 2]]
    ref = cantilever_elastica_tip(BEAM_LENGTH, rho_a * 9.81, ei)
    return _row("cantilever", n, dt, "none", timed, settle=timed[2] / BEAM_LENGTH,
                error=float(np.linalg.norm(tip - ref) / BEAM_LENGTH))


def sample_tip_z(sim, seconds: float, every: float):
    """The last node's z of strand 0 [m] at t = 0 and then every ~`every` seconds (whole steps)
    until `seconds`: (times [s], z [m]) arrays."""
    chunk = max(1, round(every / sim.dt))
    times, tip = [sim.time], [sim.positions()[0, -1, 2]]
    while sim.time < seconds - 1e-12:
        sim.step(chunk)
        times.append(sim.time)
        tip.append(sim.positions()[0, -1, 2])
    return np.array(times), np.array(tip)


def zero_crossings(t, z):
    """Times [s] where the sampled z changes sign (linear interpolation)."""
    k = np.flatnonzero(np.sign(z[:-1]) != np.sign(z[1:]))
    return t[k] + (t[k + 1] - t[k]) * z[k] / (z[k] - z[k + 1])


def oscillation_frequency(t, z) -> float:
    """[Hz] from a line fit of the zero-crossing times (half a period apart); NaN with < 2."""
    crossings = zero_crossings(t, z)
    if len(crossings) < 2:
        return float("nan")
    return 0.5 / np.polyfit(np.arange(len(crossings)), crossings, 1)[0]


def amplitude_loss_per_period(t, z) -> float:
    """1 - A_{k+2} / A_k: the fraction of the oscillation's amplitude lost per period, from a
    line fit of ln|peak| over the half periods between zero crossings (each peak refined by a
    parabola through the largest sample and its neighbours); NaN with < 3 half periods."""
    crossings = zero_crossings(t, z)
    peaks = []
    for a, b in zip(crossings[:-1], crossings[1:]):
        inside = np.flatnonzero((t > a) & (t < b))
        if len(inside) == 0:
            continue
        k = inside[np.argmax(np.abs(z[inside]))]
        peak = abs(z[k])
        if 0 < k < len(z) - 1:
            y0, y1, y2 = np.abs(z[k - 1:k + 2])
            curvature = y0 - 2 * y1 + y2
            if curvature < 0:
                peak = y1 - 0.125 * (y2 - y0) ** 2 / curvature
        peaks.append(peak)
    if len(peaks) < 3:
        return float("nan")
    slope = np.polyfit(np.arange(len(peaks)), np.log(peaks), 1)[0]
    return float(1.0 - np.exp(2.0 * slope))


def _measure_frequency(sim, expected):
    """Tip z sampled every ~20 ms for FREQUENCY_PERIODS periods; the frequency from a line fit of
    its zero-crossing times (half a period apart) [Hz]."""
    return oscillation_frequency(*sample_tip_z(sim, FREQUENCY_PERIODS / expected, 0.02))


def frequency_row(n: int, dt: float, repeats: int = 1) -> dict:
    m = beam_material()
    ei, rho_a = m.bending_stiffness[0], m.linear_density
    expected = cantilever_first_frequency(BEAM_LENGTH, ei, rho_a)
    bent = clamped_beam(n, slope=lambda s: 0.01 * BEAM_LENGTH * first_mode_slope(s, BEAM_LENGTH)).positions

    def make():
        sim = _simulator(clamped_beam(n), m, dt=dt, gravity=(0, 0, 0), twist="none")
        sim.set_positions(bent)
        return sim
    timed = _timed(make, lambda s: _measure_frequency(s, expected), repeats)
    measured = timed[2]
    return _row("frequency", n, dt, "none", timed, measured_hz=measured, expected_hz=expected,
                error=abs(measured / expected - 1))


def helix_row(n: int, dt: float, twist: str, repeats: int = 1) -> dict:
    """The hanging helix at rest; its `tip` [m] is compared with the reference by the caller."""
    m = helix_material()
    drag = 2 * m.linear_density * HELIX_OMEGA

    def make():
        return _simulator(clamped_helix(n), m, dt=dt, drag=drag, twist=twist)
    timed = _timed(make, lambda s: _settle(s, HELIX_TIME), repeats)
    return _row("helix", n, dt, twist, timed, settle=timed[2] / HELIX_LENGTH,
                tip=timed[0].positions()[0, -1].tolist(), error=None)


def _settle_until_still(sim):
    """Run in 0.1 s chunks until the tip moves less than CURL_SETTLED [m] per chunk (or
    CURL_MAX_TIME). Returns the last chunk's tip motion [m]."""
    tip, motion = sim.positions()[0, -1], math.inf
    while motion > CURL_SETTLED and sim.time < CURL_MAX_TIME:
        sim.run(0.1, progress=False)
        previous, tip = tip, sim.positions()[0, -1]
        motion = float(np.linalg.norm(tip - previous))
    return motion


CURL_VARIANTS = {"": ("clamped", "rotation"), " der": ("clamped", "der"), " edge": ("edge", "der")}


def curl_row(n: int, dt: float, axis: str, repeats: int = 1, root: str = "clamped",
             strain: str = "rotation") -> dict:
    """The curled rod hanging with its axis `axis`, at rest, against the continuum; root and
    strain as in Simulator (the row is named "curl <axis>" + its CURL_VARIANTS suffix)."""
    m = curl_material()

    def make():
        return _simulator(curl_groom(n, axis), m, dt=dt, drag=2 * m.linear_density * CURL_OMEGA,
                          twist="quasistatic", root=root, strain=strain)
    timed = _timed(make, _settle_until_still, repeats)
    ref = curl_reference(axis)
    tip = timed[0].positions()[0, n]
    suffix = next(k for k, v in CURL_VARIANTS.items() if v == (root, strain))
    return _row(f"curl {axis}{suffix}", n, dt, "quasistatic", timed, settle=timed[2] / CURL_LENGTH, root=root,
                strain=strain,
                error=float(np.linalg.norm(tip - ref["tip"]) / ref["drop"]))


def helix_reference_spec(sweep: AccuracySweep) -> dict:
    """The fine solve (float64): reference_factor x the finest helix count, quasistatic twist."""
    n = sweep.reference_factor * max(sweep.helix_segments)
    return {"case": "helix", "n": n, "dt": min((sweep.base_dt,) + tuple(sweep.dts)), "twist": "quasistatic",
            "repeats": 1}


def helix_reference(sweep: AccuracySweep) -> dict:
    """Fine solve (float64 process): reference_factor x the finest helix count, quasistatic twist."""
    return accuracy_row(helix_reference_spec(sweep))


def accuracy_specs(sweep: AccuracySweep) -> list:
    """Every row of the sweep as a spec (JSON-able dict, see `accuracy_row`), in table order:
    the curled rods' segment counts, then per case the segment counts at base_dt and the time
    steps at dt_segments (helix: for each twist mode)."""
    specs = []
    for axis in CURL_AXES:  # segment counts only: the reference is static
        for root, strain in CURL_VARIANTS.values():
            specs += [{"case": "curl", "n": n, "dt": sweep.base_dt, "axis": axis, "root": root,
                       "strain": strain, "repeats": sweep.repeats} for n in sweep.curl_segments]
    cases = (("cantilever", sweep.cantilever_segments, ("none",)),
             ("frequency", sweep.frequency_segments, ("none",)), ("helix", sweep.helix_segments, sweep.twists))
    for case, segments, twists in cases:
        runs = [(n, sweep.base_dt) for n in segments] + [(sweep.dt_segments, dt) for dt in sweep.dts]
        specs += [{"case": case, "n": n, "dt": dt, "twist": twist, "repeats": sweep.repeats}
                  for twist in twists for n, dt in runs]
    return specs


def accuracy_row(spec: dict) -> dict:
    """The row of one spec, in this process's precision."""
    n, dt, k = spec["n"], spec["dt"], spec["repeats"]
    if spec["case"] == "curl":
        return curl_row(n, dt, spec["axis"], k, spec["root"], spec.get("strain", "rotation"))
    if spec["case"] == "helix":
        return helix_row(n, dt, spec["twist"], k)
    return cantilever_row(n, dt, k) if spec["case"] == "cantilever" else frequency_row(n, dt, k)


def accuracy_rows(sweep: AccuracySweep, log=None, specs=None) -> list:
    """Every row of the sweep (or of `specs`) in this process's precision, in order."""
    rows = []
    for spec in accuracy_specs(sweep) if specs is None else specs:
        rows.append(accuracy_row(spec))
        if log:
            r = rows[-1]
            error = "" if r["error"] is None else f"error {r['error']:.3g}, "
            log(f"{r['case']} {spec['n']} segments, dt {spec['dt'] * 1e3:g} ms, {r['twist']}, {r['precision']}: "
                f"{error}wall {r['wall_s']:.2f} s")
    return rows



def _worker(precision: str, sweep: AccuracySweep, arch: str, rows: bool, reference: bool, log=None) -> dict:
    """Rows and/or the helix reference in `precision`: here if possible, else in a subprocess."""
    if in_process(precision, arch):
        return {"rows": accuracy_rows(sweep, log) if rows else [],
                "reference": helix_reference(sweep) if reference else None}
    options = ["--sweep", json.dumps(asdict(sweep))] + ([] if rows else ["--no-rows"])
    return subprocess_worker("accuracy", precision, arch, options + (["--reference"] if reference else []), log=log)


def accuracy_task(task: dict) -> list:
    """On a cluster worker: the rows of task["specs"] in task["precision"], here if this
    process has (or can take) that precision, else in a subprocess."""
    if in_process(task["precision"], task["arch"]):
        return [accuracy_row(spec) for spec in task["specs"]]
    return subprocess_worker("accuracy", task["precision"], task["arch"],
                              ["--specs", json.dumps(task["specs"])])["rows"]


def _accuracy_on_cluster(client, sweep, precisions, arch, log=None):
    """(rows, helix reference): one task per row, spread over the cluster; rows in serial order."""
    tasks = [{"precision": p, "arch": arch, "specs": [spec]} for p in precisions for spec in accuracy_specs(sweep)]
    tasks.append({"precision": "float64", "arch": arch, "specs": [helix_reference_spec(sweep)]})
    rows = [None] * len(tasks)
    for k, part in map_unordered(client, accuracy_task, tasks, name="accuracy"):
        rows[k] = part[0]
        if log:
            log(f"{rows[k]['case']} {rows[k]['segments']} segments, dt {rows[k]['dt'] * 1e3:g} ms, "
                f"{rows[k]['twist']}, {rows[k]['precision']}: wall {rows[k]['wall_s']:.2f} s (cluster)")
    return rows[:-1], rows[-1]


def accuracy_report(quick: bool, precisions=("float32", "float64"), out_dir="out/reports",
                    sweep: AccuracySweep | None = None, arch: str = "cpu", log=None, client=None) -> dict:
    """Run the accuracy sweep in each precision (one process each; with a dask `client`, one
    task per row over the cluster, wall times then measured beside the other workers' load),
    compare with the references, write accuracy.json and accuracy.png to out_dir and return the
    result dict."""
    sweep = sweep or (QUICK_SWEEP if quick else FULL_SWEEP)
    precisions = list(dict.fromkeys(precisions))
    rows, reference = [], None
    if client is not None:
        rows, reference = _accuracy_on_cluster(client, sweep, precisions, arch, log)
    else:
        for p in precisions:
            part = _worker(p, sweep, arch, rows=True, reference=p == "float64", log=log)
            rows += part["rows"]
            reference = part["reference"] or reference
    if reference is None:
        reference = _worker("float64", sweep, arch, rows=False, reference=True, log=log)["reference"]
    for r in rows:
        if r["case"] == "helix":
            r["error"] = float(np.linalg.norm(np.subtract(r["tip"], reference["tip"])) / HELIX_LENGTH)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = {"report": "accuracy", "stamp": stamp(), "quick": bool(quick),
              "arch": arch, "precisions": precisions, "sweep": asdict(sweep), "rows": rows,
              "helix_reference": reference, "json": str(out / "accuracy.json"), "png": str(out / "accuracy.png"),
              "timing": f"wall_s: median of {sweep.repeats} timed runs of the stepping (1 if a run "
                        "takes over 2 s) after a warm-up run of the same configuration (compile excluded)"}
    Path(result["json"]).write_text(json.dumps(result, indent=1))
    from render import write_png  # the renderer loads only where a figure is drawn
    write_png(result["png"], accuracy_figure(result).image)
    return result


CASE_COLOURS = {("cantilever", "none"): 0, ("frequency", "none"): 2, ("helix", "quasistatic"): 1,
                ("helix", "kmoch"): 3, ("curl down", "quasistatic"): 5, ("curl horizontal", "quasistatic"): 6,
                ("curl down der", "quasistatic"): 8, ("curl horizontal der", "quasistatic"): 9,
                ("curl down edge", "quasistatic"): 7, ("curl horizontal edge", "quasistatic"): 4}


def accuracy_figure(result: dict):
    """Log error vs log wall time: a line per (case, twist, precision) through its segment counts
    (solid float64, dashed float32), and unjoined markers for the time-step sweep."""
    from render.plot import PALETTE, Series, loglog
    sweep, series = result["sweep"], []
    keys = sorted({(r["case"], r["twist"], r["precision"]) for r in result["rows"]})
    for case, twist, prec in keys:
        rows = [r for r in result["rows"] if (r["case"], r["twist"], r["precision"]) == (case, twist, prec)]
        colour = PALETTE[CASE_COLOURS.get((case, twist), 4)]
        f32 = prec == "float32"
        seg = sorted((r for r in rows if r["dt"] == sweep["base_dt"]), key=lambda r: r["segments"])
        dts = [r for r in rows if r["segments"] == sweep["dt_segments"] and r["dt"] != sweep["base_dt"]]
        series.append(Series(x=[r["wall_s"] for r in seg], y=[r["error"] for r in seg], colour=colour,
                             marker="s" if f32 else "o", dashed=f32))
        series.append(Series(x=[r["wall_s"] for r in dts], y=[r["error"] for r in dts], colour=colour,
                             marker="D" if f32 else "^", line=False))
    legend = [(f"{c} {t}" if c == "helix" else c, PALETTE[k], "o", True, False)
              for (c, t), k in CASE_COLOURS.items() if any(r["case"] == c and r["twist"] == t for r in result["rows"])]
    legend += [("float64 segments", (0, 0, 0), "o", True, False), ("float32 segments", (0, 0, 0), "s", True, True),
               (f"dt sweep f64 ({sweep['dt_segments']} seg)", (0, 0, 0), "^", False, False),
               (f"dt sweep f32 ({sweep['dt_segments']} seg)", (0, 0, 0), "D", False, False)]
    return loglog(series, title="taichi_hair accuracy: error vs wall time", x_label="wall time [s]",
                  y_label="error (tip / L, or relative frequency)", legend=legend)


def format_accuracy(result: dict) -> str:
    ref = result["helix_reference"]
    lines = [f"taichi_hair accuracy report ({result['arch']}; {result['timing']})",
             f"{'case':<20} {'segs':>4} {'dt ms':>5} {'twist':<11} {'precision':<9} {'error':>9} "
             f"{'wall s':>7} {'steps':>6} {'subst':>5} {'settle/L':>9}"]
    for r in result["rows"]:
        settle = f"{r['settle']:9.1e}" if r.get("settle") is not None else f"{'-':>9}"
        lines.append(f"{r['case']:<20} {r['segments']:4d} {r['dt'] * 1e3:5.2f} {r['twist']:<11} {r['precision']:<9} "
                     f"{r['error']:9.2e} {r['wall_s']:7.2f} {r['steps']:6d} {r['substeps']:5d} {settle}")
    lines += ["error: cantilever |tip - elastica| / L; frequency |f / f_beam - 1|; helix |tip - tip_ref| / L; "
              "curl |tip - tip_continuum| / |drop_continuum|",
              f"helix reference: {ref['segments']} segments, float64, quasistatic, dt {ref['dt'] * 1e3:g} ms "
              f"({ref['substeps']} substeps), {ref['wall_s']:.1f} s; settle/L: tip motion over the last 0.1 s",
              f"written: {result['json']}, {result['png']}"]
    return "\n".join(lines)
