"""`taichi-hair report stability`: the stability matrix (taichi_hair.app.stability_cases) of scenes
sweeping every axis that can break a step, alone and combined (E, radius, ellipticity, segment
length, curl radius, dt, head shake frequency and amplitude, drag, wind with gusts and turbulence,
grab stiffness and speed, a hand, pins, hair-hair interaction, a sphere head, twist mode,
precision, strict / max_substeps), each run for 0.2 s (quick: 0.1 s). Outcome: stable /
substepped (n) / refused: <message> (a strict bound, max_substeps, or SimulationDiverged) / FAIL
(any other exception, a NaN, > 1 % strain, a node deeper in a collider than its margin, energy
rising without a source). float32 and float64 cases run in one process each (report_dispatch:
`python -m taichi_hair.app.reports stability --worker --precision float64`, cases on stdin), or
over a Dask cluster in chunks of one precision with --workers N / --scheduler ADDR.
"""

import json
import math
import time
import warnings
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from .. import runtime
from ..rods.groom import Groom
from ..rods.materials import Material
from ..solver.simulator import Simulator
from ..solver.stability import SimulationDiverged
from ..world.forces import Grab, HairInteraction, Hand, Wind
from ..world.motion import Shake
from ..world.scene import Head
from .cluster import map_unordered
from .report_dispatch import in_process, subprocess_worker
from .stability_cases import BASE_CASE, StabilityCase, case_axes, stability_cases
from .stamp import stamp

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
CONSTRAINT_FAIL = 2e-2  # a measured max |len^2/rest^2 - 1| above this (1 % strain) is FAIL
ENERGY_RISE_FAIL = 1e-2  # max (E(t) - E(0)) / energy in play, undamped undriven cases only
STABILITY_DURATION = {True: 0.1, False: 0.2}  # [s] simulated per case: quick, full
HEAD_RADIUS, HEAD_MARGIN = 0.1, 0.002  # [m] the sphere head of `head` cases
HAND_RADIUS, HAND_MARGIN = 0.03, 0.001  # [m] the hand of `hand_speed` cases
STATUSES = ("stable", "substepped", "refused", "FAIL")


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


def stability_scene(case: StabilityCase):
    """(groom, material, simulator options) of a case."""
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


def judge(case, facts, stats):
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
        groom, material, options = stability_scene(case)
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
        failure = failure or judge(case, facts, stats)
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
    if in_process(precision, arch):
        return stability_rows(cases, duration, log)
    return subprocess_worker("stability", precision, arch, ["--duration", repr(duration)],
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
              "thresholds": {"constraint_fail": CONSTRAINT_FAIL, "energy_rise_fail": ENERGY_RISE_FAIL},
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
