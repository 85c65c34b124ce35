"""`taichi-hair report accuracy | stability`: error against run time, and stiff / extreme cases.

Accuracy (every number measured on this machine; wall time is the stepping time of one run after
a warm-up run of the same configuration, so compile time is excluded):
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
              continuum Kirchhoff rod with intrinsic curvature and twist (taichi_hair.continuum,
              numpy shooting, independent of the simulator); error = |tip - tip_ref| / |drop|,
              drop = the reference tip's displacement under gravity. Rows "curl ... edge" run the
              same strand with root="edge" (the first edge held rigid: the model before the clamp
              moved to the root node), side by side.
Each precision runs in its own process (Taichi fixes it at init), as `python -m taichi_hair.reports
accuracy --worker --precision float32`, and the rows are merged.

Stability: a matrix of stiff and extreme scenes (E, radius, segment length, dt, curl radius, head
shake, gale wind) run for a short simulated time; outcome stable / substepped (n) / refused:
<message> (a strict bound refusal or SimulationDiverged); any other exception or a NaN is FAIL.
"""

import argparse
import functools
import json
import math
import statistics
import subprocess
import sys
import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from render import write_png
from render.plot import PALETTE, Series, loglog

from . import runtime
from .forces import Wind
from .groom import Groom
from .materials import Material
from .motion import Shake
from .simulator import Simulator
from .stability import SimulationDiverged

REPORT_MARK = "-- taichi_hair report json --"
BEAM_LENGTH = 1.0
HELIX_LENGTH, HELIX_CURL, HELIX_PITCH = 0.2, 0.01, 0.02
HELIX_OMEGA = 10.0  # [rad/s] damping rate of the helix's drag 2 rho A omega (it settles in < 1 s)
CURL_RADIUS, CURL_PITCH, CURL_TURNS = 0.05, 0.05, 3
CURL_LENGTH = CURL_TURNS * math.hypot(2 * math.pi * CURL_RADIUS, CURL_PITCH)
CURL_AXES = {"down": (0.0, 0.0, -1.0), "horizontal": (1.0, 0.0, 0.0)}
CURL_OMEGA, CURL_SETTLED, CURL_MAX_TIME = 12.0, 1e-9, 6.0  # drag rate [rad/s]; tip motion [m] per 0.1 s
CANTILEVER_TIME, HELIX_TIME, FREQUENCY_PERIODS = 6.0, 2.0, 2.25
CONSTRAINT_FAIL = 1e-2  # a measured max |len^2/rest^2 - 1| above this (0.5 % strain) is garbage: FAIL


# ---- references (numpy only) -------------------------------------------------------------------
def _elastica_end_slope(kappa0, load, length, n):
    """theta'(L) of theta'' = -load (L - s) cos(theta), theta(0) = 0, theta'(0) = kappa0 (RK4);
    also returns the tip (x, z) by the trapezoid rule on the tangent."""
    h = length / n
    th, dth, x, z = 0.0, kappa0, 0.0, 0.0
    f = lambda s, t: -load * (length - s) * math.cos(t)  # noqa: E731
    for k in range(n):
        s = k * h
        k1t, k1d = dth, f(s, th)
        k2t, k2d = dth + h / 2 * k1d, f(s + h / 2, th + h / 2 * k1t)
        k3t, k3d = dth + h / 2 * k2d, f(s + h / 2, th + h / 2 * k2t)
        k4t, k4d = dth + h * k3d, f(s + h, th + h * k3t)
        new = th + h / 6 * (k1t + 2 * k2t + 2 * k3t + k4t)
        dth += h / 6 * (k1d + 2 * k2d + 2 * k3d + k4d)
        x += 0.5 * h * (math.cos(th) + math.cos(new))
        z -= 0.5 * h * (math.sin(th) + math.sin(new))
        th = new
    return dth, np.array([x, z])


@functools.lru_cache(maxsize=8)
def elastica_tip(length: float, weight: float, ei: float, n: int = 4000) -> np.ndarray:
    """Tip (x, z) [m] of an inextensible cantilever clamped horizontally at the origin along +x,
    sagging under its weight w [N/m] (z up): EI theta'' = -w (L - s) cos theta, theta'(L) = 0,
    by shooting on theta'(0) with bisection (RK4 on n steps, trapezoid rule for the tip)."""
    load = weight / ei
    lo, hi = 0.0, load * length**2
    while _elastica_end_slope(hi, load, length, n)[0] < 0:
        hi *= 2.0
    while hi - lo > 1e-13 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _elastica_end_slope(mid, load, length, n)[0] < 0 else (lo, mid)
    return _elastica_end_slope(0.5 * (lo + hi), load, length, n)[1].copy()


def beam_frequency(length: float, ei: float, linear_density: float) -> float:
    """First natural frequency [Hz] of a clamped-free Euler-Bernoulli beam."""
    return 1.8751040687**2 / (2 * math.pi * length**2) * math.sqrt(ei / linear_density)


def first_mode_slope(s, length: float):
    """d/ds of the clamped-free beam's first mode, normalised to a unit tip deflection."""
    b = 1.8751040687 / length
    sig = (math.cosh(b * length) + math.cos(b * length)) / (math.sinh(b * length) + math.sin(b * length))
    tip = math.cosh(b * length) - math.cos(b * length) - sig * (math.sinh(b * length) - math.sin(b * length))
    return b * (np.sinh(b * s) + np.sin(b * s) - sig * (np.cosh(b * s) - np.cos(b * s))) / tip


# ---- the strands ------------------------------------------------------------------------------------
def clamped_beam(n_segments: int, slope=None):
    """Horizontal beam of length BEAM_LENGTH along +x clamped at its root node at the origin;
    slope(s) [rad] optionally bends it (exact edge lengths)."""
    ds = BEAM_LENGTH / n_segments
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
    """Continuum tip [m] under gravity and its drop [m] (displacement from the unloaded tip)."""
    from .continuum import hanging_helix
    m = curl_material()
    stiffness = (m.bending_stiffness[0], m.bending_stiffness[1], m.twist_stiffness)
    ref = hanging_helix(CURL_LENGTH, CURL_RADIUS, CURL_PITCH, CURL_AXES[axis], stiffness, m.linear_density)
    unloaded = hanging_helix(CURL_LENGTH, CURL_RADIUS, CURL_PITCH, CURL_AXES[axis], stiffness, 0.0)
    return {"tip": ref["tip"].tolist(), "drop": float(np.linalg.norm(ref["tip"] - unloaded["tip"]))}


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
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the substepping notice: reported as substeps
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
    drag = 2 * rho_a * 2 * math.pi * beam_frequency(BEAM_LENGTH, ei, rho_a)  # every mode damped at omega1

    def make():
        return _simulator(clamped_beam(n), m, dt=dt, drag=drag, twist="none")
    timed = _timed(make, lambda s: _settle(s, CANTILEVER_TIME), repeats)
    tip = timed[0].positions()[0, -1][[0, 2]]
    ref = elastica_tip(BEAM_LENGTH, rho_a * 9.81, ei)
    return _row("cantilever", n, dt, "none", timed, settle=timed[2] / BEAM_LENGTH,
                error=float(np.linalg.norm(tip - ref) / BEAM_LENGTH))


def _measure_frequency(sim, expected):
    """Tip z sampled every ~20 ms for FREQUENCY_PERIODS periods; the frequency from a line fit of
    its zero-crossing times (half a period apart) [Hz]."""
    chunk = max(1, round(0.02 / sim.dt))
    times, tip = [0.0], [sim.positions()[0, -1, 2]]
    while sim.time < FREQUENCY_PERIODS / expected:
        sim.step(chunk)
        times.append(sim.time)
        tip.append(sim.positions()[0, -1, 2])
    t, z = np.array(times), np.array(tip)
    k = np.flatnonzero(np.sign(z[:-1]) != np.sign(z[1:]))
    crossings = t[k] + (t[k + 1] - t[k]) * z[k] / (z[k] - z[k + 1])
    if len(crossings) < 2:
        return float("nan")
    return 0.5 / np.polyfit(np.arange(len(crossings)), crossings, 1)[0]


def frequency_row(n: int, dt: float, repeats: int = 1) -> dict:
    m = beam_material()
    ei, rho_a = m.bending_stiffness[0], m.linear_density
    expected = beam_frequency(BEAM_LENGTH, ei, rho_a)
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
        motion, tip = float(np.linalg.norm(sim.positions()[0, -1] - tip)), sim.positions()[0, -1]
    return motion


def curl_row(n: int, dt: float, axis: str, repeats: int = 1, root: str = "clamped") -> dict:
    """The curled rod hanging with its axis `axis`, at rest, against the continuum; root as in
    Simulator ("edge" rows are named "curl <axis> edge")."""
    m = curl_material()

    def make():
        return _simulator(curl_groom(n, axis), m, dt=dt, drag=2 * m.linear_density * CURL_OMEGA,
                          twist="quasistatic", root=root)
    timed = _timed(make, _settle_until_still, repeats)
    ref = curl_reference(axis)
    tip = timed[0].positions()[0, n]
    case = f"curl {axis}" + (" edge" if root == "edge" else "")
    return _row(case, n, dt, "quasistatic", timed, settle=timed[2] / CURL_LENGTH, root=root,
                error=float(np.linalg.norm(tip - ref["tip"]) / ref["drop"]))


def helix_reference(sweep: AccuracySweep) -> dict:
    """Fine solve (float64 process): reference_factor x the finest helix count, quasistatic twist."""
    n = sweep.reference_factor * max(sweep.helix_segments)
    return helix_row(n, min((sweep.base_dt,) + tuple(sweep.dts)), "quasistatic")


def accuracy_rows(sweep: AccuracySweep, log=None) -> list:
    """Every row of the sweep in this process's precision: segment counts at base_dt, then the
    time steps at dt_segments (helix: for each twist mode)."""
    rows = []
    cases = (("cantilever", sweep.cantilever_segments, ("none",)),
             ("frequency", sweep.frequency_segments, ("none",)), ("helix", sweep.helix_segments, sweep.twists))
    for axis in CURL_AXES:  # segment counts only: the reference is static
        for root in ("clamped", "edge"):
            for n in sweep.curl_segments:
                rows.append(curl_row(n, sweep.base_dt, axis, sweep.repeats, root))
                if log:
                    log(f"{rows[-1]['case']} {n} segments: error {rows[-1]['error']:.3g}, "
                        f"wall {rows[-1]['wall_s']:.2f} s")
    for case, segments, twists in cases:
        runs = [(n, sweep.base_dt) for n in segments] + [(sweep.dt_segments, dt) for dt in sweep.dts]
        for twist in twists:
            for n, dt in runs:
                k = sweep.repeats
                rows.append(helix_row(n, dt, twist, k) if case == "helix" else
                            cantilever_row(n, dt, k) if case == "cantilever" else frequency_row(n, dt, k))
                if log:
                    r = rows[-1]
                    log(f"{case} {n} segments, dt {dt * 1e3:g} ms, {twist}, {r['precision']}: "
                        f"wall {r['wall_s']:.2f} s")
    return rows


def _in_process(precision: str, arch: str) -> bool:
    """Run `precision` here if Taichi is not initialised yet (then initialise it) or already is so."""
    if not runtime.taichi_is_initialized():
        runtime.init(arch=arch, precision=precision)
        return True
    return runtime.precision() == precision and runtime.arch() == arch


def _worker(precision: str, sweep: AccuracySweep, arch: str, rows: bool, reference: bool, log=None) -> dict:
    """Rows and/or the helix reference in `precision`: here if possible, else in a subprocess."""
    if _in_process(precision, arch):
        return {"rows": accuracy_rows(sweep, log) if rows else [],
                "reference": helix_reference(sweep) if reference else None}
    cmd = [sys.executable, "-m", "taichi_hair.reports", "accuracy", "--worker", "--arch", arch,
           "--precision", precision, "--sweep", json.dumps(asdict(sweep))]
    cmd += [] if rows else ["--no-rows"]
    cmd += ["--reference"] if reference else []
    # progress lines pass through to our stderr when logging, else are kept for the error message
    done = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=None if log else subprocess.PIPE, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"accuracy worker ({precision}) failed (exit {done.returncode}):\n{(done.stderr or '')[-4000:]}")
    return json.loads(done.stdout[done.stdout.index(REPORT_MARK) + len(REPORT_MARK):])


def accuracy_report(quick: bool, precisions=("float32", "float64"), out_dir="out/reports",
                    sweep: AccuracySweep | None = None, arch: str = "cpu", log=None) -> dict:
    """Run the accuracy sweep in each precision (one process each), compare with the references,
    write accuracy.json and accuracy.png to out_dir and return the result dict."""
    sweep = sweep or (QUICK_SWEEP if quick else FULL_SWEEP)
    precisions = list(dict.fromkeys(precisions))
    rows, reference = [], None
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
    result = {"arch": arch, "precisions": precisions, "sweep": asdict(sweep), "rows": rows,
              "helix_reference": reference, "json": str(out / "accuracy.json"), "png": str(out / "accuracy.png"),
              "timing": f"wall_s: median of {sweep.repeats} timed runs of the stepping (1 if a run "
                        "takes over 2 s) after a warm-up run of the same configuration (compile excluded)"}
    Path(result["json"]).write_text(json.dumps(result, indent=1))
    write_png(result["png"], accuracy_figure(result).image)
    return result


CASE_COLOURS = {("cantilever", "none"): 0, ("frequency", "none"): 2, ("helix", "quasistatic"): 1,
                ("helix", "kmoch"): 3, ("curl down", "quasistatic"): 5, ("curl horizontal", "quasistatic"): 6,
                ("curl down edge", "quasistatic"): 7, ("curl horizontal edge", "quasistatic"): 4}


def accuracy_figure(result: dict):
    """Log error vs log wall time: a line per (case, twist, precision) through its segment counts
    (solid float64, dashed float32), and unjoined markers for the time-step sweep."""
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


# ---- stability matrix -----------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class StabilityCase:
    """One scene: n_strands strands of `length` [m] growing horizontally from roots on a 10 cm
    circle (they swing down under gravity). Material E [Pa] (G = E / 3), radius [m], segment
    length [m], dt [s]; curl_radius [m] (0: straight; curly: pitch 2 curl_radius, ellipticity 1.5);
    head shake 30 deg at shake_hz [Hz] (0: still); gale: mean wind speed [m/s] (gusts 50 %,
    turbulence 10 %; needs drag [N s/m per m] > 0); twist mode; strict: refuse dt past the bound."""

    name: str
    youngs_modulus: float = 3e9
    radius: float = 40e-6
    segment: float = 0.01
    dt: float = 1e-3
    curl_radius: float = 0.0
    shake_hz: float = 0.0
    wind: float = 0.0
    drag: float = 0.0
    twist: str = "kmoch"
    strict: bool = False
    length: float = 0.2
    n_strands: int = 4


def stability_cases(quick: bool) -> list:
    """The matrix: one factor at a time around human hair (E 3 GPa, r 40 um, 1 cm segments, dt
    1 ms), then combined extremes and strict refusals. quick: a subset covering every outcome."""
    base = StabilityCase(name="human hair")
    gale = dict(wind=30.0, drag=5e-4)
    extreme = dict(segment=0.002, dt=5e-3, curl_radius=0.005, shake_hz=5.0, **gale)
    cases = [base, replace(base, name="human hair quasistatic", twist="quasistatic")]
    cases += [replace(base, name=f"E {e:.0e} Pa", youngs_modulus=e) for e in (1e8, 1e9, 1e10)]
    cases += [replace(base, name=f"radius {r * 1e6:.0f} um", radius=r) for r in (20e-6, 60e-6, 100e-6)]
    cases += [replace(base, name=f"segment {d * 1e3:g} mm", segment=d) for d in (0.002, 0.005, 0.02)]
    cases += [replace(base, name=f"dt {dt * 1e3:g} ms", dt=dt) for dt in (1e-4, 5e-4, 2e-3, 5e-3)]
    cases += [replace(base, name=f"curl {c * 1e3:g} mm", curl_radius=c) for c in (0.02, 0.01, 0.005)]
    cases += [replace(base, name="curl 5 mm quasistatic", curl_radius=0.005, twist="quasistatic")]
    cases += [replace(base, name=f"shake {f:g} Hz", shake_hz=f) for f in (1.0, 3.0, 5.0)]
    cases += [replace(base, name="gale 30 m/s", **gale), replace(base, name="gale + shake 5 Hz", shake_hz=5.0, **gale)]
    cases += [replace(base, name="extreme stiff", youngs_modulus=1e10, radius=100e-6, **extreme),
              replace(base, name="extreme stiff quasistatic", youngs_modulus=1e10, radius=100e-6,
                      twist="quasistatic", **extreme),
              replace(base, name="extreme soft", youngs_modulus=1e8, radius=20e-6, **extreme),
              replace(base, name="extreme soft quasistatic", youngs_modulus=1e8, radius=20e-6,
                      twist="quasistatic", **extreme),
              replace(base, name="strict, dt 0.1 ms", dt=1e-4, strict=True),
              replace(base, name="strict, E 1e10, 2 mm", youngs_modulus=1e10, segment=0.002, strict=True),
              replace(base, name="strict, dt 5 ms", dt=5e-3, strict=True)]
    if quick:
        keep = {"human hair", "human hair quasistatic", "E 1e+10 Pa", "segment 2 mm", "dt 5 ms", "curl 5 mm",
                "curl 5 mm quasistatic", "shake 5 Hz", "gale 30 m/s", "extreme stiff quasistatic",
                "strict, E 1e10, 2 mm"}
        cases = [c for c in cases if c.name in keep]
    return cases


def _stability_scene(case: StabilityCase):
    """(groom, material, simulator options) of a case."""
    angle = 2 * np.pi * np.arange(case.n_strands) / case.n_strands
    directions = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=1)
    shape = dict(roots=0.1 * directions, directions=directions, length=case.length,
                 n_nodes=int(round(case.length / case.segment)) + 1)
    groom = (Groom.curly(**shape, curl_radius=case.curl_radius, curl_pitch=2 * case.curl_radius)
             if case.curl_radius > 0 else Groom.straight(**shape))
    material = Material(youngs_modulus=case.youngs_modulus, shear_modulus=case.youngs_modulus / 3,
                        radius=case.radius, ellipticity=1.5 if case.curl_radius > 0 else 1.0)
    options = dict(dt=case.dt, drag=case.drag, twist=case.twist, strict=case.strict)
    if case.shake_hz:
        options["root_motion"] = Shake(amplitude_deg=30.0, frequency_hz=case.shake_hz)
    if case.wind:
        options["wind"] = Wind(velocity=(0.0, case.wind, 0.0), gust_amplitude=0.5, gust_frequency=1.0,
                               turbulence=0.1 * case.wind, turbulence_scale=0.05)
    return groom, material, options


def constraint_residual(x, groom) -> float:
    """max |len^2 / rest^2 - 1| over every real edge of positions x [S, N, 3] [m]."""
    valid = np.arange(groom.max_nodes - 1)[None, :] < (groom.node_counts[:, None] - 1)
    now = np.sum(np.diff(x, axis=1) ** 2, axis=2)
    rest = np.sum(np.diff(groom.positions, axis=1) ** 2, axis=2)
    return float(np.abs(now[valid] / rest[valid] - 1.0).max())


def _observe(sim, groom, duration):
    """Step to `duration` [s] in ~10 ms chunks; measured residual, energies and speed per chunk.
    Returns (facts dict, failure text or None)."""
    chunk = max(1, round(0.01 / sim.dt))
    e0, exchanged, rise, residual, speed = sim.total_energy(), 0.0, 0.0, 0.0, 0.0
    energy = e0
    while sim.time < duration - 1e-9:
        sim.step(chunk)
        x, v = sim.positions(), sim.velocities()
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
            return {}, f"FAIL: non-finite positions or velocities at t = {sim.time:.4g} s"
        residual = max(residual, constraint_residual(x, groom))
        speed = max(speed, float(np.linalg.norm(v, axis=2).max()))
        energy = sim.total_energy()
        exchanged = max(exchanged, sim.kinetic_energy() + sim.elastic_energy())
        rise = max(rise, energy - e0)
    scale = exchanged if exchanged > 0 else 1.0
    return {"measured_residual": residual, "max_speed": speed, "energy_drift": (energy - e0) / scale,
            "energy_max_rise": rise / scale}, None


def run_stability_case(case: StabilityCase, duration: float) -> dict:
    """Run one case for `duration` simulated seconds. Refusals: ValueError from the constructor (a
    strict bound, or an input it rejects) and SimulationDiverged; anything else, or a NaN, is FAIL."""
    row = {**asdict(case), "duration": duration,
           "conservative": case.drag == 0 and not case.shake_hz and not case.wind}
    start = time.perf_counter()
    try:
        groom, material, options = _stability_scene(case)
        try:
            sim = _simulator(groom, material, **options)
        except ValueError as err:
            return {**row, "outcome": f"refused: {err}", "status": "refused", "wall_s": time.perf_counter() - start}
        row.update(stable_dt=sim.stable_dt, substeps=sim.substeps)
        facts, failure = _observe(sim, groom, duration)
        row.update(facts)
        stats = sim.stats()
        row.update({k: stats[k] for k in ("projection_residual_max", "projection_tol", "projection_cap_hits",
                                          "projection_stalls", "steps")})
        if not failure and facts["measured_residual"] > CONSTRAINT_FAIL:
            failure = (f"FAIL: edges stretched, max |len^2/rest^2 - 1| = {facts['measured_residual']:.3g} "
                       f"> {CONSTRAINT_FAIL:g} ({stats['projection_stalls']} projection stalls)")
        if failure:
            row.update(outcome=failure, status="FAIL")
        else:
            row.update(outcome="stable" if sim.substeps == 1 else f"substepped ({sim.substeps})",
                       status="stable" if sim.substeps == 1 else "substepped")
    except SimulationDiverged as err:
        row.update(outcome=f"refused: {err}", status="refused")
    except Exception as err:  # noqa: BLE001 - the report's rule: anything undocumented is a FAIL
        row.update(outcome=f"FAIL: {type(err).__name__}: {err}", status="FAIL")
    row["wall_s"] = time.perf_counter() - start
    return row


def stability_report(quick: bool, out_dir="out/reports", cases=None, duration: float | None = None,
                     log=None) -> dict:
    """Run the matrix (or `cases`) in this process's precision for `duration` simulated seconds
    (0.5 s, quick 0.2 s); write stability.json to out_dir and return the result."""
    duration = duration or (0.2 if quick else 0.5)
    rows = []
    for case in cases if cases is not None else stability_cases(quick):
        rows.append(run_stability_case(case, duration))
        if log:
            log(f"{case.name}: {rows[-1]['outcome'][:100]} ({rows[-1]['wall_s']:.1f} s)")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = {"arch": runtime.arch(), "precision": runtime.precision(), "duration": duration, "cases": rows,
              "failures": sum(r["status"] == "FAIL" for r in rows), "json": str(out / "stability.json")}
    Path(result["json"]).write_text(json.dumps(result, indent=1))
    return result


def _fmt(value, spec):
    return "-".rjust(int(spec.split(".")[0])) if value is None else format(value, spec)


def format_stability(result: dict) -> str:
    head = (f"{'case':<26} {'E Pa':>7} {'r um':>4} {'ds mm':>5} {'dt ms':>5} {'curl':>4} {'shake':>5} "
            f"{'wind':>4} {'bound ms':>8} {'proj res':>8} {'meas res':>8} {'E drift':>8} {'E rise':>8} "
            f"{'v max':>6} {'wall s':>6}  outcome")
    lines = [f"taichi_hair stability matrix ({result['arch']}, {result['precision']}, "
             f"{result['duration']:g} s simulated per case, 4 strands)", head]
    for r in result["cases"]:
        cons = r.get("conservative")
        lines.append(
            f"{r['name']:<26} {r['youngs_modulus']:7.0e} {r['radius'] * 1e6:4.0f} {r['segment'] * 1e3:5.1f} "
            f"{r['dt'] * 1e3:5.2f} {r['curl_radius'] * 1e3:4.0f} {r['shake_hz']:5.0f} {r['wind']:4.0f} "
            f"{_fmt(r.get('stable_dt') and r['stable_dt'] * 1e3, '8.3f')} {_fmt(r.get('projection_residual_max'), '8.1e')} "
            f"{_fmt(r.get('measured_residual'), '8.1e')} {_fmt(r.get('energy_drift') if cons else None, '8.1e')} "
            f"{_fmt(r.get('energy_max_rise') if cons else None, '8.1e')} {_fmt(r.get('max_speed'), '6.2f')} "
            f"{r['wall_s']:6.1f}  {r['outcome']}")
    lines += ["bound: the simulator's explicit stability bound; proj res: max projection residual from "
              "sim.stats(); meas res: max |len^2/rest^2 - 1| measured from positions every ~10 ms (FAIL above "
              f"{CONSTRAINT_FAIL:g}); wall s includes compiling kernels the first time a configuration is met",
              "E drift / E rise: (E_end - E_0) and max (E(t) - E_0) relative to the largest kinetic + elastic "
              "energy reached, for undamped, undriven cases only ('-' where drag, wind or head motion "
              "exchange energy); v max [m/s]: fastest node seen",
              f"failures: {result['failures']}; written: {result['json']}"]
    return "\n".join(lines)


# ---- command line ---------------------------------------------------------------------------------
def _log(text):
    print(text, file=sys.stderr, flush=True)


def _accuracy_main(args) -> int:
    if args.worker:
        runtime.init(arch=args.arch, precision=args.precision)
        sweep = AccuracySweep(**{k: tuple(v) if isinstance(v, list) else v for k, v in json.loads(args.sweep).items()})
        part = {"rows": accuracy_rows(sweep, _log) if not args.no_rows else [],
                "reference": helix_reference(sweep) if args.reference else None}
        print(REPORT_MARK + json.dumps(part))
        return 0
    precisions = ["float32", "float64"] if args.precision == "both" else [args.precision]
    result = accuracy_report(args.quick, precisions, args.out, arch=args.arch, log=_log)
    print(json.dumps(result, indent=1) if args.json else format_accuracy(result))
    return 0


def _stability_main(args) -> int:
    if not _in_process(args.precision, args.arch):
        raise ValueError(f"Taichi is already initialised with another precision than {args.precision}")
    result = stability_report(args.quick, args.out, log=_log)
    print(json.dumps(result, indent=1) if args.json else format_stability(result))
    return 1 if result["failures"] else 0


def _add_commands(sub):
    acc = sub.add_parser("accuracy", help="error against run time (table, JSON and a log-log PNG)")
    acc.add_argument("--quick", action="store_true", help="smaller sweep (about a minute)")
    acc.add_argument("--precision", default="both", choices=["float32", "float64", "both"])
    acc.add_argument("--out", default="out/reports", help="folder for accuracy.json and accuracy.png")
    acc.add_argument("--arch", default="cpu")
    acc.add_argument("--json", action="store_true", help="print JSON instead of the table")
    acc.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    acc.add_argument("--sweep", help=argparse.SUPPRESS)
    acc.add_argument("--no-rows", action="store_true", help=argparse.SUPPRESS)
    acc.add_argument("--reference", action="store_true", help=argparse.SUPPRESS)
    acc.set_defaults(func=_accuracy_main)
    stab = sub.add_parser("stability", help="stiff and extreme cases: stable / substepped / refused (exit 1 on FAIL)")
    stab.add_argument("--quick", action="store_true", help="a subset, 0.2 s simulated each")
    stab.add_argument("--precision", default="float32", choices=["float32", "float64"])
    stab.add_argument("--out", default="out/reports", help="folder for stability.json")
    stab.add_argument("--arch", default="cpu")
    stab.add_argument("--json", action="store_true", help="print JSON instead of the table")
    stab.set_defaults(func=_stability_main)
    from .sagfree import add_report_parser
    add_report_parser(sub)


def add_parsers(sub) -> None:
    """Add `report accuracy`, `report stability` and `report sagfree` to an argparse subparsers object."""
    report = sub.add_parser("report", help="accuracy (error vs run time) and stability reports")
    _add_commands(report.add_subparsers(dest="report", required=True))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m taichi_hair.reports", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_commands(parser.add_subparsers(dest="report", required=True))
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ValueError as err:
        print(f"taichi-hair report: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
