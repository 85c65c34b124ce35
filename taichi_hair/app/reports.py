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
              continuum Kirchhoff rod with intrinsic curvature and twist (taichi_hair.rods.continuum,
              numpy shooting, independent of the simulator); error = |tip - tip_ref| / |drop|,
              drop = the reference tip's displacement under gravity. Side by side: "curl ..." with
              the rotation strain measure (strain="rotation", the default), "curl ... der" with the
              DER measure (strain="der", the measure before), "curl ... edge" with DER and
              root="edge" (the first edge held rigid: the model before the clamp moved to the root
              node).
Each precision runs in its own process (Taichi fixes it at init), as `python -m taichi_hair.app.reports
accuracy --worker --precision float32`, and the rows are merged.

Stability: a matrix of scenes sweeping every axis that can break a step, alone and combined (E,
radius, ellipticity, segment length, curl radius, dt, head shake frequency and amplitude, drag,
wind with gusts and turbulence, grab stiffness and speed, a hand, pins, hair-hair interaction, a
sphere head, twist mode, precision, strict / max_substeps), each run for 0.2 s (quick: 0.1 s);
outcome stable / substepped (n) / refused: <message> (a strict bound, max_substeps, or
SimulationDiverged) / FAIL (any other exception, a NaN, > 1 % strain, a node deeper in a collider
than its margin, energy rising without a source). float32 and float64 cases run in one process
each (`python -m taichi_hair.app.reports stability --worker --precision float64`, cases on stdin).

Both spread over a Dask cluster with --workers N / --scheduler ADDR (taichi_hair.app.cluster): one
task per accuracy row, stability cases in chunks of one precision; a worker whose Taichi runs the
other precision runs the task through the same --worker subprocess. The rows are the serial ones.
"""

import argparse
import contextlib
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


from .. import runtime
from ..world.forces import Wind
from ..rods.groom import Groom
from ..rods.materials import Material
from ..world.motion import Shake
from ..world.scene import PROJECTIONS
from ..solver.simulator import Simulator
from ..solver.stability import SimulationDiverged
from ..validation import cli_real, one_line_parser_class
from .stamp import stamp

REPORT_MARK = "-- taichi_hair report json --"
BEAM_LENGTH = 1.0
HELIX_LENGTH, HELIX_CURL, HELIX_PITCH = 0.2, 0.01, 0.02
HELIX_OMEGA = 10.0  # [rad/s] damping rate of the helix's drag 2 rho A omega (it settles in < 1 s)
CURL_RADIUS, CURL_PITCH, CURL_TURNS = 0.05, 0.05, 3
CURL_LENGTH = CURL_TURNS * math.hypot(2 * math.pi * CURL_RADIUS, CURL_PITCH)
CURL_AXES = {"down": (0.0, 0.0, -1.0), "horizontal": (1.0, 0.0, 0.0)}
CURL_OMEGA, CURL_SETTLED, CURL_MAX_TIME = 12.0, 1e-9, 6.0  # drag rate [rad/s]; tip motion [m] per 0.1 s
CANTILEVER_TIME, HELIX_TIME, FREQUENCY_PERIODS = 6.0, 2.0, 2.25
CONSTRAINT_FAIL = 2e-2  # stability: a measured max |len^2/rest^2 - 1| above this (1 % strain) is FAIL


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
    """Continuum tip [m] under gravity and its drop [m] (displacement from the unloaded tip)."""
    from ..rods.continuum import hanging_helix
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


def _in_process(precision: str, arch: str) -> bool:
    """Run `precision` here if Taichi is not initialised yet (then initialise it) or already is so."""
    if not runtime.taichi_is_initialized():
        runtime.init(arch=arch, precision=precision)
        return True
    return runtime.precision() == precision and runtime.arch() == arch


def _subprocess_worker(kind: str, precision: str, arch: str, options: list, stdin=None, log=None):
    """`python -m taichi_hair.app.reports KIND --worker ...` in `precision`; its JSON answer.
    Progress lines pass through to our stderr when logging, else are kept for the error message."""
    cmd = [sys.executable, "-m", "taichi_hair.app.reports", kind, "--worker", "--arch", arch,
           "--precision", precision, *options]
    done = subprocess.run(cmd, input=stdin, stdout=subprocess.PIPE, stderr=None if log else subprocess.PIPE,
                          text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{kind} worker ({precision}) failed (exit {done.returncode}):\n"
                           f"{(done.stderr or '')[-4000:]}")
    return json.loads(done.stdout[done.stdout.index(REPORT_MARK) + len(REPORT_MARK):])


def _worker(precision: str, sweep: AccuracySweep, arch: str, rows: bool, reference: bool, log=None) -> dict:
    """Rows and/or the helix reference in `precision`: here if possible, else in a subprocess."""
    if _in_process(precision, arch):
        return {"rows": accuracy_rows(sweep, log) if rows else [],
                "reference": helix_reference(sweep) if reference else None}
    options = ["--sweep", json.dumps(asdict(sweep))] + ([] if rows else ["--no-rows"])
    return _subprocess_worker("accuracy", precision, arch, options + (["--reference"] if reference else []), log=log)


def accuracy_task(task: dict) -> list:
    """On a cluster worker: the rows of task["specs"] in task["precision"], here if this
    process has (or can take) that precision, else in a subprocess."""
    if _in_process(task["precision"], task["arch"]):
        return [accuracy_row(spec) for spec in task["specs"]]
    return _subprocess_worker("accuracy", task["precision"], task["arch"],
                              ["--specs", json.dumps(task["specs"])])["rows"]


def _accuracy_on_cluster(client, sweep, precisions, arch, log=None):
    """(rows, helix reference): one task per row, spread over the cluster; rows in serial order."""
    from .cluster import map_unordered
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


# ---- stability matrix -----------------------------------------------------------------------------
# FAIL thresholds. Strain: |len^2/rest^2 - 1| = 2 strain + strain^2, so CONSTRAINT_FAIL = 2e-2
# is 1 % strain (the simulator gives up on a step whose projection leaves more than 0.5 %,
# step.FAILED_ABOVE, so a row past it means the positions disagree with what the projection
# reported). Penetration: contacts push nodes out to a collider's margin, so a node deeper inside
# the surface than the margin went through it. Energy: symplectic Euler has no secular energy
# error: it exactly conserves a modified energy H~ = H + (h/2) v . grad V + O(h^2), so from rest
# H can rise at most by (h/2) |P|, P = F . v the power of the conservative forces. For the swing
# under gravity that holds the energy in play here, (h/2) m g v / (m v^2 / 2) = h g / v: <= 6e-3
# for substeps up to 1.65 ms at the 2.5 m/s the strands reach (every undamped case but the coarse
# 20 ms one, where the projection's loss, also O(h), dominates: -0.38); the stiff elastic modes
# (h omega <= 1 under the bound) add at most half their own, small, share. The projection,
# contacts and still pins only take energy out. So a rise above 1e-2 of the energy in play is
# energy created; measured in float64: <= 1.3e-5 on every undamped, undriven case (Kmoch's rule
# before its total-derivative force: 0.66).
ENERGY_RISE_FAIL = 1e-2  # max (E(t) - E(0)) / energy in play, undamped undriven cases only
STABILITY_DURATION = {True: 0.1, False: 0.2}  # [s] simulated per case: quick, full
HEAD_RADIUS, HEAD_MARGIN = 0.1, 0.002  # [m] the sphere head of `head` cases
HAND_RADIUS, HAND_MARGIN = 0.03, 0.001  # [m] the hand of `hand_speed` cases
STATUSES = ("stable", "substepped", "refused", "FAIL")


@dataclass(frozen=True, kw_only=True)
class StabilityCase:
    """One scene: n_strands strands of `length` [m] growing horizontally outward from roots on a
    circle of radius `spread` [m] (they swing down under gravity), or with head=True from roots
    on a sphere head (radius HEAD_RADIUS, margin HEAD_MARGIN, centred on the shake's pivot) 30
    degrees from its crown, leaving the surface at 12 degrees toward the equator (curly: along its
    normal), so they fall onto it and drape over it.

    Material: E [Pa] (G = E / 3), radius [m], ellipticity (a/b >= 1); segment length [m]; curl
    radius [m] (0: straight; else pitch 2 curl_radius); dt [s]; twist mode.
    Head motion: a shake about +z, shake_deg at shake_hz [Hz] (0: still).
    Air: drag [N s/m per m]; wind [m/s] along +y with gusts of relative size `gust` and
    turbulence rms `turbulence` * wind (eddies 5 cm); wind needs drag > 0.
    Touch: grab_stiffness [N/m] > 0 adds a Grab (radius 3 cm) starting at the middle node of
    strand 0 and moving up at grab_speed [m/s]; hand_speed [m/s] > 0 sweeps a Hand (radius 3 cm)
    along +y through the hair of strand 0 (starting 10 cm before it).
    pin: "" none, "mid" (world pin on every strand's middle node), "clip" (clamp=True there),
    "tie" (head-attached pins there: they ride on the shake), "tip" (world pin on the tip).
    interaction: hair-hair interaction on a grid of `cell` [m] with `repulsion` [m^2/s^2] and
    `interaction_friction` [1/s].
    Limits: strict refuses dt past the bound; max_substeps caps automatic substeps.
    precision: the process the report runs the case in (run_stability_case runs it in this
    process's). quick: part of the --quick matrix. projection_iterations: the simulator's cap
    (lowered only to break a case on purpose)."""

    name: str
    youngs_modulus: float = 3e9
    radius: float = 40e-6
    ellipticity: float = 1.0
    segment: float = 0.01
    curl_radius: float = 0.0
    dt: float = 1e-3
    twist: str = "quasistatic"
    shake_hz: float = 0.0
    shake_deg: float = 30.0
    drag: float = 0.0
    wind: float = 0.0
    gust: float = 0.5
    turbulence: float = 0.1
    grab_stiffness: float = 0.0
    grab_speed: float = 0.0
    hand_speed: float = 0.0
    pin: str = ""
    interaction: bool = False
    cell: float = 0.02
    repulsion: float = 1.0
    interaction_friction: float = 5.0
    head: bool = False
    precision: str = "float32"
    strict: bool = False
    max_substeps: int = 1000
    length: float = 0.2
    n_strands: int = 4
    spread: float = 0.1
    projection_iterations: int = 100
    quick: bool = False
    integrator: str = "explicit"
    projection: str = "fast"


BASE_CASE = StabilityCase(name="human hair")
# the matrix's axes and the StabilityCase fields that make each (a case covers an axis when one
# of its fields differs from BASE_CASE)
STABILITY_AXES = {
    "E": ("youngs_modulus",), "radius": ("radius",), "ellipticity": ("ellipticity",), "segment": ("segment",),
    "curl": ("curl_radius",), "dt": ("dt",), "shake": ("shake_hz", "shake_deg"),
    "wind": ("wind", "gust", "turbulence"), "drag": ("drag",), "grab": ("grab_stiffness", "grab_speed"),
    "hand": ("hand_speed",), "pin": ("pin",),
    "interaction": ("interaction", "cell", "repulsion", "interaction_friction"),
    "head": ("head",), "twist": ("twist",), "precision": ("precision",), "limits": ("strict", "max_substeps"),
}  # the integrator and projection are not axes: `report stability --integrator implicit` (or
#   `--projection shake`) runs the whole matrix with it


def case_axes(case: StabilityCase) -> list:
    """The axes on which `case` differs from BASE_CASE (human hair, 1 cm segments, dt 1 ms)."""
    return [axis for axis, fields in STABILITY_AXES.items()
            if any(getattr(case, f) != getattr(BASE_CASE, f) for f in fields)]


def stability_cases(quick: bool) -> list:
    """The matrix: every axis alone around human hair (E 3 GPa, r 40 um, round, straight, 1 cm
    segments, dt 1 ms, still, undamped, quasistatic twist, float32), from one end of its range
    to the other, then combinations, float64 twins of the hardest cases, and refusals.
    quick: the cases marked quick (a third, covering every axis)."""
    cases = []

    def add(name, quick=False, **changes):
        cases.append(replace(BASE_CASE, name=name, quick=quick, **changes))

    gale = dict(wind=30.0, drag=5e-4)
    add("human hair", True)
    add("human hair, twist none", True, twist="none")
    add("human hair, kmoch", True, twist="kmoch")
    for e, q in ((1e7, True), (1e8, False), (1e9, False), (1e10, False), (1e11, True)):
        add(f"E {e:.0e} Pa", q, youngs_modulus=e)
    for r, q in ((10e-6, True), (20e-6, False), (60e-6, False), (100e-6, False), (200e-6, False)):
        add(f"radius {r * 1e6:g} um", q, radius=r)
    for e, q in ((1.5, False), (2.0, False), (3.0, True), (4.0, False)):
        add(f"ellipticity {e:g}", q, ellipticity=e)
    for d, q in ((0.001, True), (0.002, False), (0.005, False), (0.02, False), (0.03, False)):
        add(f"segment {d * 1e3:g} mm", q, segment=d)
    # the polyline must resolve the curl: segments of at most half the curl radius
    for c, d, q in ((0.002, 0.001, True), (0.005, 0.0025, False), (0.01, 0.005, False), (0.02, 0.01, False)):
        add(f"curl {c * 1e3:g} mm, {d * 1e3:g} mm segments", q, curl_radius=c, segment=d)
    for dt, q in ((5e-5, True), (1e-4, False), (5e-4, False), (2e-3, False), (5e-3, False), (1e-2, False),
                  (2e-2, True)):
        add(f"dt {dt * 1e3:g} ms", q, dt=dt)
    for f, q in ((1.0, False), (3.0, False), (5.0, True), (10.0, False)):
        add(f"shake {f:g} Hz 30 deg", q, shake_hz=f)
    for a, q in ((10.0, False), (60.0, False), (90.0, True)):
        add(f"shake 3 Hz {a:g} deg", q, shake_hz=3.0, shake_deg=a)
    add("drag 5e-4", drag=5e-4)
    add("drag 1e-2", True, drag=1e-2)
    for w, q in ((5.0, False), (15.0, False), (30.0, False), (60.0, True)):
        add(f"wind {w:g} m/s", q, wind=w, drag=5e-4)
    add("wind 30 m/s steady", wind=30.0, drag=5e-4, gust=0.0, turbulence=0.0)
    add("wind 30 m/s, gusts 100 %", wind=30.0, drag=5e-4, gust=1.0)
    add("wind 30 m/s, turbulence 30 %", True, wind=30.0, drag=5e-4, turbulence=0.3)
    for k, q in ((0.01, False), (0.1, False), (1.0, False), (10.0, False), (100.0, True)):
        add(f"grab {k:g} N/m, 0.5 m/s", q, grab_stiffness=k, grab_speed=0.5)
    for v, q in ((0.0, False), (2.0, False), (10.0, True)):
        add(f"grab 0.1 N/m, {v:g} m/s", q, grab_stiffness=0.1, grab_speed=v)
    add("hand 1 m/s", hand_speed=1.0)
    add("hand 5 m/s", True, hand_speed=5.0)
    add("pin mid", True, pin="mid")
    add("clip mid", pin="clip")
    add("tie mid, shake 3 Hz", True, pin="tie", shake_hz=3.0)
    add("pin tip, curl 1 cm", pin="tip", curl_radius=0.01, segment=0.005)
    add("interaction", True, interaction=True, n_strands=8, spread=0.02)
    add("interaction, repulsion 100", interaction=True, n_strands=8, spread=0.02, repulsion=100.0)
    add("interaction, friction 1000/s", interaction=True, n_strands=8, spread=0.02, interaction_friction=1000.0)
    add("interaction, 5 mm cells", interaction=True, n_strands=8, spread=0.02, cell=0.005)
    add("head", True, head=True)
    add("head, curl 5 mm", head=True, curl_radius=0.005, segment=0.0025)
    add("head, shake 5 Hz", True, head=True, shake_hz=5.0)
    add("head, gale 30 m/s", head=True, **gale)
    for e, q in ((1.5, False), (4.0, True)):  # twist modes on curly elliptic hair
        for twist in ("none", "kmoch", "quasistatic"):
            add(f"curl 5 mm, ellipticity {e:g}, {twist}", q and twist == "kmoch", curl_radius=0.005,
                segment=0.0025, ellipticity=e, twist=twist)
    # combinations
    extreme = dict(segment=0.002, dt=5e-3, curl_radius=0.005, shake_hz=5.0, ellipticity=1.5, **gale)
    for twist in ("quasistatic", "kmoch"):
        add(f"extreme stiff, {twist}", twist == "quasistatic", youngs_modulus=1e10, radius=100e-6, twist=twist,
            **extreme)
        add(f"extreme soft, {twist}", False, youngs_modulus=1e8, radius=20e-6, twist=twist, **extreme)
    add("E 1e11, r 200 um, 2 mm, dt 5 ms", youngs_modulus=1e11, radius=200e-6, segment=0.002, dt=5e-3)
    add("E 1e7, r 10 um, gale 60 m/s", False, youngs_modulus=1e7, radius=10e-6, wind=60.0, drag=5e-4, gust=1.0,
        turbulence=0.3)
    add("coarse: E 1e7, 30 mm, dt 20 ms", youngs_modulus=1e7, segment=0.03, dt=2e-2)
    add("dt 20 ms, shake 10 Hz 90 deg", True, dt=2e-2, shake_hz=10.0, shake_deg=90.0)
    add("curl 2 mm, e 4, kmoch, shake 10 Hz", True, curl_radius=0.002, segment=0.001, ellipticity=4.0,
        twist="kmoch", shake_hz=10.0)
    add("curl 2 mm, e 4, none, dt 10 ms", curl_radius=0.002, segment=0.001, ellipticity=4.0, twist="none", dt=1e-2)
    add("grab 10 N/m, 2 m/s, pin mid", grab_stiffness=10.0, grab_speed=2.0, pin="mid")
    add("grab 100 N/m, 10 m/s, E 1e11", youngs_modulus=1e11, grab_stiffness=100.0, grab_speed=10.0)
    add("hand 5 m/s, head, shake 3 Hz", head=True, shake_hz=3.0, hand_speed=5.0)
    add("head, tie, shake 10 Hz 60 deg", True, head=True, pin="tie", shake_hz=10.0, shake_deg=60.0)
    add("head, curl 5 mm, e 1.5, kmoch, interaction, shake 5 Hz, gale", True, head=True, curl_radius=0.005,
        segment=0.0025, ellipticity=1.5, twist="kmoch", interaction=True, n_strands=8, shake_hz=5.0, **gale)
    add("interaction, repulsion 100, gale 60 m/s", interaction=True, n_strands=8, spread=0.02, repulsion=100.0,
        wind=60.0, drag=5e-4)
    add("segment 1 mm, E 1e10, dt 2 ms", youngs_modulus=1e10, segment=0.001, dt=2e-3)
    add("radius 200 um, ellipticity 4, segment 30 mm", radius=200e-6, ellipticity=4.0, segment=0.03)
    add("E 1e11, drag 1e-2, dt 10 ms", youngs_modulus=1e11, drag=1e-2, dt=1e-2)
    # float64 twins: base, the ends of each range, and the hardest combinations
    f64 = [c for c in cases if c.name in (
        "human hair", "human hair, kmoch", "E 1e+11 Pa", "E 1e+07 Pa", "radius 10 um", "radius 200 um",
        "segment 1 mm", "curl 2 mm, 1 mm segments", "dt 20 ms", "shake 3 Hz 90 deg", "wind 60 m/s",
        "grab 100 N/m, 0.5 m/s", "hand 5 m/s", "pin mid", "tie mid, shake 3 Hz", "interaction", "head",
        "curl 5 mm, ellipticity 4, kmoch", "extreme stiff, quasistatic", "extreme stiff, kmoch",
        "E 1e7, r 10 um, gale 60 m/s", "curl 2 mm, e 4, kmoch, shake 10 Hz",
        "head, curl 5 mm, e 1.5, kmoch, interaction, shake 5 Hz, gale", "segment 1 mm, E 1e10, dt 2 ms")]
    keep64 = {"human hair", "segment 1 mm", "dt 20 ms", "pin mid", "head", "curl 5 mm, ellipticity 4, kmoch",
              "extreme stiff, kmoch", "E 1e7, r 10 um, gale 60 m/s", "interaction"}
    cases += [replace(c, name=f"{c.name}, float64", precision="float64", quick=c.name in keep64) for c in f64]
    # refusals: a strict bound, and more substeps than max_substeps
    add("strict, dt 5 ms", True, dt=5e-3, strict=True)
    add("strict, E 1e10, 2 mm", youngs_modulus=1e10, segment=0.002, strict=True)
    add("strict, grab 100 N/m", grab_stiffness=100.0, grab_speed=0.5, strict=True)
    add("E 1e11, 1 mm, dt 20 ms (max_substeps)", True, youngs_modulus=1e11, segment=0.001, dt=2e-2)
    add("drag 1, dt 20 ms (max_substeps 100)", drag=1.0, dt=2e-2, max_substeps=100)
    return [c for c in cases if c.quick] if quick else cases


def _strand_layout(case: StabilityCase):
    """Roots [S, 3] and growth directions [S, 3]."""
    angle = 2 * np.pi * np.arange(case.n_strands) / case.n_strands
    ring = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=1)
    if case.head:  # 30 degrees from the crown, leaving 12 degrees off the surface toward the equator
        # (curls along the normal: a helix leaves its root sideways, into the head at a shallow angle)
        polar, tilt = math.radians(30.0), math.radians(90.0 if case.curl_radius else 12.0)
        up = np.array([0.0, 0.0, 1.0])
        normal = ring * math.sin(polar) + up * math.cos(polar)
        downhill = ring * math.cos(polar) - up * math.sin(polar)
        return HEAD_RADIUS * normal, downhill * math.cos(tilt) + normal * math.sin(tilt)
    return case.spread * ring, ring


def _grab_path(start, speed):
    start = np.asarray(start, dtype=np.float64)
    return lambda t: start + np.array([0.0, 0.0, speed * t])


def _hand_path(start, speed):
    start = np.asarray(start, dtype=np.float64)
    return lambda t: start + np.array([0.0, speed * t, 0.0])


def _stability_scene(case: StabilityCase):
    """(groom, material, simulator options) of a case."""
    from ..world.forces import Grab, Hand
    from ..world.forces import HairInteraction
    from ..world.scene import Head
    roots, directions = _strand_layout(case)
    shape = dict(roots=roots, directions=directions, length=case.length,
                 n_nodes=int(round(case.length / case.segment)) + 1)
    groom = (Groom.curly(**shape, curl_radius=case.curl_radius, curl_pitch=2 * case.curl_radius)
             if case.curl_radius > 0 else Groom.straight(**shape))
    material = Material(youngs_modulus=case.youngs_modulus, shear_modulus=case.youngs_modulus / 3,
                        radius=case.radius, ellipticity=case.ellipticity)
    options = dict(dt=case.dt, drag=case.drag, twist=case.twist, strict=case.strict,
                   max_substeps=case.max_substeps, projection_iterations=case.projection_iterations,
                   integrator=case.integrator, projection=case.projection)
    if case.shake_hz:
        options["root_motion"] = Shake(amplitude_deg=case.shake_deg, frequency_hz=case.shake_hz)
    if case.wind:
        options["wind"] = Wind(velocity=(0.0, case.wind, 0.0), gust_amplitude=case.gust, gust_frequency=1.0,
                               turbulence=case.turbulence * case.wind, turbulence_scale=0.05)
    touch = []
    if case.grab_stiffness:
        middle = groom.positions[0, groom.node_counts[0] // 2]
        touch.append(Grab(path=_grab_path(middle, case.grab_speed), radius=0.03, stiffness=case.grab_stiffness))
    if case.hand_speed:
        touch.append(Hand(path=_hand_path(_hand_start(groom), case.hand_speed), radius=HAND_RADIUS,
                          margin=HAND_MARGIN))
    options["touch"] = tuple(touch)
    if case.head:
        options["colliders"] = Head.sphere(radius=HEAD_RADIUS, margin=HEAD_MARGIN).colliders
    if case.interaction:
        options["hair_interaction"] = HairInteraction(cell_size=case.cell, repulsion=case.repulsion,
                                                      friction=case.interaction_friction)
    return groom, material, options


def _hand_start(groom):
    """The hand starts 10 cm before strand 0 (along -y), level with its middle node, 3 cm below."""
    middle = groom.positions[0, groom.node_counts[0] // 2]
    return middle + np.array([0.0, -0.1, -0.03])


def _obstacles(case: StabilityCase, groom):
    """What nodes must stay out of, from the case (not from the simulator's options, so a scene
    that loses its colliders still has them measured): [(kind, margin, signed distance of world
    points [M, 3] at sim time t given the head pose)]."""
    out = []
    if case.head:
        from ..world.scene import Head
        field = Head.sphere(radius=HEAD_RADIUS, margin=HEAD_MARGIN).distance_field()

        def head_distance(points, t, pose):
            rotation, translation = pose
            return field.sample((np.asarray(points) - translation) @ np.asarray(rotation))  # R^T (x - t)
        out.append(("head", HEAD_MARGIN, head_distance))
    if case.hand_speed:
        path = _hand_path(_hand_start(groom), case.hand_speed)
        out.append(("hand", HAND_MARGIN,
                    lambda points, t, pose: np.linalg.norm(np.asarray(points) - path(t), axis=1) - HAND_RADIUS))
    return out


def _add_pins(sim, case: StabilityCase, groom):
    if not case.pin:
        return
    strands = np.arange(groom.n_strands)
    if case.pin == "tip":
        sim.add_pin(strands, groom.node_counts - 1)
        return
    middle = groom.node_counts // 2
    if case.pin == "mid":
        sim.add_pin(strands, middle)
    elif case.pin == "clip":
        for s in strands:
            sim.add_pin(int(s), int(middle[s]), clamp=True)
    elif case.pin == "tie":
        sim.add_pin(strands, middle, attach="head")
    else:
        raise ValueError(f"pin must be '', 'mid', 'clip', 'tie' or 'tip', got {case.pin!r}")


def is_conservative(case: StabilityCase) -> bool:
    """Undamped and undriven: no drag, wind, head motion, touch or hair interaction (still pins
    and a still head do no work), so total energy may not rise."""
    return (case.drag == 0 and not case.wind and not case.shake_hz and not case.grab_stiffness
            and not case.hand_speed and not case.interaction)


def constraint_residual(x, groom) -> float:
    """max |len^2 / rest^2 - 1| over every real edge of positions x [S, N, 3] [m]."""
    valid = np.arange(groom.max_nodes - 1)[None, :] < (groom.node_counts[:, None] - 1)
    now = np.sum(np.diff(x, axis=1) ** 2, axis=2)
    rest = np.sum(np.diff(groom.positions, axis=1) ** 2, axis=2)
    return float(np.abs(now[valid] / rest[valid] - 1.0).max())


def _observe(sim, groom, duration, obstacles=()):
    """Step to `duration` [s] in ~10 ms chunks; after each chunk measure the edge residual, the
    energies, the fastest node and each obstacle's deepest node. Returns (facts, failure text or
    None); a non-finite state ends the run at once."""
    chunk = max(1, round(0.01 / sim.dt))
    real = np.arange(groom.max_nodes)[None, :] < groom.node_counts[:, None]
    free = real.copy()
    free[:, 0] = False  # the root nodes ride on the head: contacts do not move them
    e0, exchanged, rise, residual, speed = sim.total_energy(), 0.0, 0.0, 0.0, 0.0
    energy = e0
    depth = {kind: -math.inf for kind, _, _ in obstacles}  # max (-distance) / margin seen
    while sim.time < duration - 1e-9:
        sim.step(chunk)
        x, v = sim.positions(), sim.velocities()
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
            return {}, f"FAIL: non-finite positions or velocities at t = {sim.time:.4g} s"
        residual = max(residual, constraint_residual(x, groom))
        speed = max(speed, float(np.linalg.norm(v, axis=2).max()))
        energy = sim.total_energy()
        if not math.isfinite(energy):
            return {}, f"FAIL: non-finite energy at t = {sim.time:.4g} s"
        exchanged = max(exchanged, sim.kinetic_energy() + sim.elastic_energy())
        rise = max(rise, energy - e0)
        for kind, margin, distance in obstacles:
            depth[kind] = max(depth[kind], float(-distance(x[free], sim.time, sim.head_transform).min()) / margin)
    scale = exchanged if exchanged > 0 else 1.0
    return {"measured_residual": residual, "max_speed": speed, "energy_drift": (energy - e0) / scale,
            "energy_max_rise": rise / scale, "energy_in_play": exchanged,
            "penetration": max(depth.values()) if depth else None, "penetration_by": depth}, None


def _judge(case, facts, stats):
    """The FAIL text of a finished run's facts, or None."""
    if facts["measured_residual"] > CONSTRAINT_FAIL:
        return (f"FAIL: edges stretched, max |len^2/rest^2 - 1| = {facts['measured_residual']:.3g} > "
                f"{CONSTRAINT_FAIL:g} (1 % strain; {stats['projection_stalls']} projection stalls)")
    for kind, depth in facts["penetration_by"].items():
        if depth > 1.0:
            return f"FAIL: a node {depth:.3g} margins inside the {kind} (more than its margin)"
    if is_conservative(case) and facts["energy_max_rise"] > ENERGY_RISE_FAIL:
        return (f"FAIL: energy rose without a source by {facts['energy_max_rise']:.3g} of the energy in play "
                f"(> {ENERGY_RISE_FAIL:g})")
    return None


def _stability_simulator(groom, material, options):
    """Simulator(...) with its warnings recorded: any warning is kept in the row (substeps are
    the row's substep count)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sim = Simulator(groom, material, **options)
    notes = [str(w.message) for w in caught]
    return sim, notes


# The simulator's documented refusals by ValueError (Simulator's docstring): dt past the bound
# with strict=True, and more automatic substeps than max_substeps.
DOCUMENTED_REFUSALS = ("exceeds this scene's explicit stability bound", "more than max_substeps",
                       "runs with integrator='explicit'")  # a combination the implicit step has not


def run_stability_case(case: StabilityCase, duration: float) -> dict:
    """Run one case for `duration` simulated seconds in this process's precision. Refused: the
    documented refusals, a ValueError for dt past the bound with strict=True or for more
    substeps than max_substeps (DOCUMENTED_REFUSALS), and SimulationDiverged (the state rolled
    back, with its likely cause). FAIL: anything else raised (every case's inputs are valid, so
    another ValueError is a defect too), a NaN, more than 1 % strain, a node deeper in a collider
    than its margin, or energy rising past ENERGY_RISE_FAIL of the energy in play in an
    undamped, undriven case."""
    row = {**asdict(case), "duration": duration, "conservative": is_conservative(case), "axes": case_axes(case),
           "precision": runtime.precision(), "warnings": []}
    start = time.perf_counter()
    try:
        groom, material, options = _stability_scene(case)
        try:
            sim, row["warnings"] = _stability_simulator(groom, material, options)
        except ValueError as err:
            if not any(text in str(err) for text in DOCUMENTED_REFUSALS):
                raise
            return {**row, "outcome": f"refused: {err}", "status": "refused", "wall_s": time.perf_counter() - start}
        _add_pins(sim, case, groom)
        row.update(stable_dt=sim.stable_dt, substeps=sim.substeps)
        facts, failure = _observe(sim, groom, duration, _obstacles(case, groom))
        row.update(facts)
        stats = sim.stats()
        row.update({k: stats[k] for k in ("projection_residual_max", "projection_tol", "projection_cap_hits",
                                          "projection_stalls", "steps")})
        failure = failure or _judge(case, facts, stats)
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


def stability_rows(cases, duration: float, log=None) -> list:
    """Run `cases` in this process, in order."""
    rows = []
    for case in cases:
        rows.append(run_stability_case(case, duration))
        if log:
            r = rows[-1]
            log(f"{case.name} ({r['precision']}): {r['outcome'][:100]} ({r['wall_s']:.1f} s)")
    return rows


def _stability_worker(precision: str, cases, duration: float, arch: str, log=None) -> list:
    """Rows of `cases` in `precision`: here if this process has (or can take) that precision,
    else in a subprocess (`python -m taichi_hair.app.reports stability --worker`, cases on stdin)."""
    if _in_process(precision, arch):
        return stability_rows(cases, duration, log)
    return _subprocess_worker("stability", precision, arch, ["--duration", repr(duration)],
                              stdin=json.dumps([asdict(c) for c in cases]), log=log)


def stability_task(task: dict) -> list:
    """On a cluster worker: rows of task["cases"] (dicts) in task["precision"] (here, or in a
    subprocess when this worker's Taichi runs the other precision)."""
    cases = [StabilityCase(**c) for c in task["cases"]]
    return _stability_worker(task["precision"], cases, task["duration"], task["arch"])


def _stability_on_cluster(client, cases, duration, arch, log=None) -> list:
    """Rows of `cases` in their order, computed over the cluster: chunks of one precision (a
    worker's Taichi keeps the first precision it meets; a chunk of the other one runs in a
    subprocess there), about four per worker, so the load evens out."""
    from .cluster import map_unordered
    workers = max(1, len(client.scheduler_info()["workers"]))
    size = max(1, math.ceil(len(cases) / (4 * workers)))
    chunks = []
    for p in dict.fromkeys(c.precision for c in cases):
        index = [k for k, c in enumerate(cases) if c.precision == p]
        chunks += [index[j: j + size] for j in range(0, len(index), size)]
    tasks = [{"precision": cases[chunk[0]].precision, "arch": arch, "duration": duration,
              "cases": [asdict(cases[k]) for k in chunk]} for chunk in chunks]
    rows = [None] * len(cases)
    for j, part in map_unordered(client, stability_task, tasks, name="stability"):
        for k, row in zip(chunks[j], part):
            rows[k] = row
            if log:
                log(f"{row['name']} ({row['precision']}): {row['outcome'][:100]} ({row['wall_s']:.1f} s, cluster)")
    return rows


def stability_counts(rows) -> dict:
    """Cases and how many ended in each status, overall and per precision."""
    def count(rs):
        return {"cases": len(rs), **{s: sum(r["status"] == s for r in rs) for s in STATUSES}}
    return {"all": count(rows), **{p: count([r for r in rows if r["precision"] == p])
                                   for p in sorted({r["precision"] for r in rows})}}


def stability_report(quick: bool, out_dir="out/reports", cases=None, duration: float | None = None,
                     log=None, precision: str = "both", arch: str = "cpu", client=None,
                     integrator: str | None = None, projection: str | None = None) -> dict:
    """Run the matrix (or `cases`) for `duration` simulated seconds each (STABILITY_DURATION);
    precision "both": each case in its own precision, one process per precision (Taichi fixes it
    at init: this one if it can, else a worker subprocess); "float32" / "float64": every case in
    that one. integrator, projection: run every case with this one (None: each case's own). With a dask
    `client`, the cases are spread over its cluster instead. Writes
    stability.json to out_dir and returns the result."""
    duration = STABILITY_DURATION[bool(quick)] if duration is None else duration
    if not (isinstance(duration, (int, float)) and 0 < duration <= 100):
        raise ValueError(f"duration (--duration) must be in (0, 100] s, got {duration!r}")
    cases = list(cases if cases is not None else stability_cases(quick))
    if precision != "both":
        cases = [replace(c, precision=precision) for c in cases]
    overrides = {k: v for k, v in (("integrator", integrator), ("projection", projection)) if v is not None}
    if overrides:
        cases = [replace(c, **overrides) for c in cases]
    wanted = list(dict.fromkeys(c.precision for c in cases))
    here = runtime.precision() if runtime.taichi_is_initialized() else None
    wanted.sort(key=lambda p: p != here)  # this process's precision first, no subprocess for it
    if client is not None:
        rows = _stability_on_cluster(client, cases, duration, arch, log)
    else:
        rows = [None] * len(cases)
        for p in wanted:
            index = [k for k, c in enumerate(cases) if c.precision == p]
            for k, row in zip(index, _stability_worker(p, [cases[k] for k in index], duration, arch, log)):
                rows[k] = row
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = {"report": "stability", "stamp": stamp(), "arch": arch, "precisions": wanted, "duration": duration,
              "quick": bool(quick), "overrides": overrides, "cases": rows,
              "counts": stability_counts(rows), "failures": sum(r["status"] == "FAIL" for r in rows),
              "wall_s": sum(r["wall_s"] for r in rows), "json": str(out / "stability.json")}
    Path(result["json"]).write_text(json.dumps(result, indent=1))
    return result


def _fmt(value, spec):
    return "-".rjust(int(spec.split(".")[0])) if value is None else format(value, spec)


def _extras(r) -> str:
    """The scene's extras in words: grab, hand, pins, interaction, head, limits."""
    parts = []
    if r["grab_stiffness"]:
        parts.append(f"grab {r['grab_stiffness']:g}N/m@{r['grab_speed']:g}")
    if r["hand_speed"]:
        parts.append(f"hand@{r['hand_speed']:g}")
    if r["pin"]:
        parts.append(r["pin"])
    if r["interaction"]:
        parts.append("hh")
    if r["head"]:
        parts.append("head")
    if r["drag"] and not r["wind"]:
        parts.append(f"drag {r['drag']:g}")
    if r["strict"]:
        parts.append("strict")
    if r["max_substeps"] != BASE_CASE.max_substeps:
        parts.append(f"max {r['max_substeps']}")
    return ",".join(parts) or "-"


def format_stability(result: dict) -> str:
    head = (f"{'case':<40} {'prec':>4} {'twist':<5} {'E Pa':>7} {'r um':>4} {'e':>3} {'ds mm':>5} {'curl':>4} "
            f"{'dt ms':>5} {'shake':>6} {'wind':>4} {'extras':<18} {'bound ms':>8} {'meas res':>8} {'depth':>6} "
            f"{'E rise':>8} {'v max':>6} {'wall s':>6}  outcome")
    lines = [f"taichi_hair stability matrix ({result['arch']}, {result['duration']:g} s simulated per case)", head]
    for r in result["cases"]:
        shake = f"{r['shake_hz']:g}/{r['shake_deg']:g}" if r["shake_hz"] else "-"
        wind = f"{r['wind']:g}" if r["wind"] else "-"
        lines.append(
            f"{r['name'][:40]:<40} {r['precision'][-2:]:>4} {r['twist'][:5]:<5} {r['youngs_modulus']:7.0e} "
            f"{r['radius'] * 1e6:4.0f} {r['ellipticity']:3.1f} {r['segment'] * 1e3:5.1f} "
            f"{r['curl_radius'] * 1e3 if r['curl_radius'] else '-':>4} {r['dt'] * 1e3:5.2f} {shake:>6} {wind:>4} "
            f"{_extras(r)[:18]:<18} {_fmt(r.get('stable_dt') and r['stable_dt'] * 1e3, '8.4f')} "
            f"{_fmt(r.get('measured_residual'), '8.1e')} {_fmt(r.get('penetration'), '6.2f')} "
            f"{_fmt(r.get('energy_max_rise') if r['conservative'] else None, '8.1e')} "
            f"{_fmt(r.get('max_speed'), '6.2f')} "
            f"{r['wall_s']:6.1f}  {r['outcome']}")
    c = result["counts"]
    per = "; ".join(f"{p}: {n['cases']} cases, {n['stable']} stable, {n['substepped']} substepped, "
                    f"{n['refused']} refused, {n['FAIL']} FAIL" for p, n in c.items() if p != "all")
    lines += ["prec: 32 / 64 (float32 / float64, one process each); e: ellipticity; curl: radius [mm]; shake: "
              "Hz/deg; wind [m/s] along +y (gusts and turbulence: see the case name); extras: grab k@speed, hand@speed, "
              "pin / clip / tie / tip, hh (hair-hair interaction), head (sphere collider, roots on it), drag, "
              "strict, max (max_substeps)",
              "bound: the simulator's explicit stability bound; meas res: max |len^2/rest^2 - 1| measured from "
              f"positions every ~10 ms (FAIL above {CONSTRAINT_FAIL:g}: 1 % strain); depth: deepest node inside a "
              "collider or hand, in margins (FAIL above 1); E rise: max (E(t) - E_0) over the largest kinetic + "
              f"elastic energy reached, undamped undriven cases only (FAIL above {ENERGY_RISE_FAIL:g}); v max "
              "[m/s]: fastest node seen; wall s includes compiling kernels the first time a configuration is met",
              f"cases: {c['all']['cases']}; stable {c['all']['stable']}, substepped {c['all']['substepped']}, "
              f"refused {c['all']['refused']}, FAIL {c['all']['FAIL']} ({per}); wall {result['wall_s']:.0f} s",
              f"failures: {result['failures']}; written: {result['json']}"]
    return "\n".join(lines)


# ---- command line ---------------------------------------------------------------------------------
def _log(text):
    print(text, file=sys.stderr, flush=True)


def _cluster_client(args):
    """A dask client for --workers / --scheduler (taichi_hair.app.cluster), else a context of None."""
    from . import cluster
    return cluster.client_from_args(args) if cluster.wanted(args) else contextlib.nullcontext()


def _accuracy_main(args) -> int:
    if args.worker:
        runtime.init(arch=args.arch, precision=args.precision)
        if args.specs:
            print(REPORT_MARK + json.dumps({"rows": accuracy_rows(None, _log, json.loads(args.specs))}))
            return 0
        sweep = AccuracySweep(**{k: tuple(v) if isinstance(v, list) else v for k, v in json.loads(args.sweep).items()})
        part = {"rows": accuracy_rows(sweep, _log) if not args.no_rows else [],
                "reference": helix_reference(sweep) if args.reference else None}
        print(REPORT_MARK + json.dumps(part))
        return 0
    precisions = ["float32", "float64"] if args.precision == "both" else [args.precision]
    with _cluster_client(args) as client:
        result = accuracy_report(args.quick, precisions, args.out, arch=args.arch, log=_log, client=client)
    print(json.dumps(result, indent=1) if args.json else format_accuracy(result))
    return 0


def _stability_main(args) -> int:
    if args.worker:
        runtime.init(arch=args.arch, precision=args.precision)
        cases = [StabilityCase(**c) for c in json.loads(sys.stdin.read())]
        print(REPORT_MARK + json.dumps(stability_rows(cases, args.duration, _log)))
        return 0
    with _cluster_client(args) as client:
        result = stability_report(args.quick, args.out, log=_log, precision=args.precision, arch=args.arch,
                                  duration=args.duration, client=client, integrator=args.integrator,
                                  projection=args.projection)
    print(json.dumps(result, indent=1) if args.json else format_stability(result))
    return 1 if result["failures"] else 0


def _add_commands(sub):
    from . import cluster
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
    acc.add_argument("--specs", help=argparse.SUPPRESS)
    cluster.add_arguments(acc)
    acc.set_defaults(func=_accuracy_main)
    stab = sub.add_parser("stability", help="the stability matrix: stable / substepped / refused / FAIL per case "
                                            "(exit 1 on any FAIL)")
    stab.add_argument("--quick", action="store_true", help="a third of the cases (every axis), 0.1 s simulated each")
    stab.add_argument("--precision", default="both", choices=["both", "float32", "float64"],
                      help="both: each case in its own precision (one process each); else every case in this one")
    stab.add_argument("--out", default="out/reports", help="folder for stability.json")
    stab.add_argument("--arch", default="cpu")
    stab.add_argument("--json", action="store_true", help="print JSON instead of the table")
    stab.add_argument("--duration", type=cli_real("--duration", 0.0, 100.0, unit="s"),
                      help="simulated seconds per case (default 0.2, quick 0.1)")
    stab.add_argument("--integrator", default=None, choices=["explicit", "implicit"],
                      help="run every case with this integrator (default: each case's own, explicit)")
    stab.add_argument("--projection", default=None, choices=PROJECTIONS,
                      help="run every case with this projection of the explicit step (default: each case's own, fast)")
    stab.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    cluster.add_arguments(stab)
    stab.set_defaults(func=_stability_main)
    from ..hair.sagfree import add_report_parser
    add_report_parser(sub)
    from .implicit_report import add_parser as add_implicit_parser
    add_implicit_parser(sub)


def add_parsers(sub) -> None:
    """Add `report accuracy`, `report stability` and `report sagfree` to an argparse subparsers object."""
    report = sub.add_parser("report", help="accuracy (error vs run time) and stability reports")
    _add_commands(report.add_subparsers(dest="report", required=True))


def main(argv=None) -> int:
    parser = one_line_parser_class()(prog="python -m taichi_hair.app.reports", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_commands(parser.add_subparsers(dest="report", required=True))
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ValueError as err:
        print(f"taichi-hair report: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    from taichi_hair.app import reports as _by_name  # cluster tasks must be pickled by name, not from __main__
    sys.exit(_by_name.main())
