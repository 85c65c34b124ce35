"""`taichi-hair report markdown`: docs/validation.md from the reports' JSON.

The prose is here, as templates; every number on the page comes from the JSON the reports wrote
(accuracy.json, stability.json, implicit.json in --reports, out/reports by default), each
section under the stamp its report wrote (commit, date, machine, versions) and its settings.
A report that has not been run gets a one-line pointer to its command instead of numbers.
"""

import json
import math
from pathlib import Path

from .stamp import STAMP_FIELDS, stamp

# report -> (its file, the keys the page reads, the command that writes it)
REPORTS = {
    "accuracy": ("accuracy.json", ("sweep", "precisions", "rows", "helix_reference", "quick", "timing"),
                 "taichi-hair report accuracy --quick"),
    "stability": ("stability.json", ("cases", "counts", "duration", "precisions", "quick", "thresholds"),
                  "taichi-hair report stability --quick"),
    "implicit": ("implicit.json", ("scene", "precision", "speed", "accuracy", "cantilever"),
                 "taichi-hair report implicit"),
}
OUTCOME_WIDTH = 140  # characters of a refusal's message shown in the stability table

HEADER = """# Validation: accuracy, stability, the implicit step, benchmarks and cosseratbench

How taichi_hair is checked against references independent of the code, and what was measured.
This page is written by `taichi-hair report markdown` from the JSON the reports wrote; every
number below comes from those files, under the stamp of the run that measured it. Do not edit
it by hand: its prose lives in `taichi_hair/app/validation_page.py`. To rebuild it:

```bash
.venv/bin/taichi-hair report accuracy --quick     # out/reports/accuracy.json (and accuracy.png)
.venv/bin/taichi-hair report stability --quick    # out/reports/stability.json
.venv/bin/taichi-hair report implicit             # out/reports/implicit.json (compiles the implicit step: minutes)
.venv/bin/taichi-hair report markdown             # this page, from out/reports/*.json
```

Page written {date} at commit {commit}.

| report | measured | commit | machine | settings |
| --- | --- | --- | --- | --- |
{runs}
"""

ACCURACY = """## Accuracy

`taichi-hair report accuracy` measures error against wall time for references independent of
the simulator (`taichi_hair/rods/references.py`): the static tip of a heavy clamped beam (L 1 m,
r 1 cm, E 1e7 Pa, rho 1000 kg/m^3) against the elastica (shooting), that beam's first vibration
frequency against the beam formula 1.875^2 / (2 pi L^2) sqrt(EI / rho A), a hanging curly
elliptic hair (L 20 cm, curl radius 1 cm, pitch 2 cm, ellipticity 1.5) against a fine solve of
the same strand (float64, quasistatic twist), and a curled rod (curl radius 5 cm, pitch 5 cm,
3 turns, r 1 cm, E 1e7 Pa) hanging with its helix axis down and horizontal against the continuum
Kirchhoff rod with intrinsic curvature and twist (`taichi_hair/rods/continuum.py`: numpy,
shooting on the root moment, RK4). Errors: cantilever and helix |tip - tip_ref| / L; frequency
|f / f_beam - 1|; curl |tip - tip_ref| / |drop|, drop the reference tip's displacement under
gravity. The `curl ...` rows use the rotation strain measure (the default), `... der` the DER
measure (`strain="der"`), `... edge` DER with the first edge held rigid (`root="edge"`); helix
rows name their twist update. Wall time: {timing}.

{stamp}

{tables}
"""

STABILITY = """## Stability

`taichi-hair report stability` runs stiff, fine, curly, shaken, windy, grabbed, pinned, crowded
and head-draped scenes (4 strands of 20 cm, 8 with hair-hair interaction), sweeping each axis
alone around human hair and in combinations: E, radius, ellipticity, segment length, curl
radius, dt, head shake frequency and amplitude, drag, wind with gusts and turbulence, grab
stiffness and speed, a hand, pins (mid, clip, head-attached tie, tip), hair-hair interaction, a
sphere head with the roots on it, the three twist modes and both precisions (float32 and
float64 cases run in one process each). The cases are a table in
`taichi_hair/app/stability_cases.py`. Each case ends stable, substepped (n), refused (a strict
bound, more than `max_substeps`, or `SimulationDiverged`, with its message) or FAIL: any other
exception, a NaN, a measured max |len^2/rest^2 - 1| above {constraint_fail:g} ({strain:.2g} % strain), a
node deeper inside the head or the hand than its margin, or, in an undamped and undriven case,
energy rising by more than {energy_rise_fail:g} of the energy in play (symplectic Euler's
bounded error is O(h); the projection, contacts and still pins only take energy out).

{stamp}

{counts}

{energy}

{table}
"""

IMPLICIT = """## The implicit step

`taichi-hair report implicit` sets the implicit step (linearised BDF2, one block-banded solve
per strand) beside the explicit one: the first bending mode of a real hair (human hair, round,
no gravity, no damping set) started in the clamped beam's first mode shape, its frequency
against the beam formula and the amplitude it loses per period (the step's numerical damping),
for both integrators over a range of steps; and on a scene, the simulation time per frame and
the tips' deviation from a tiny-step explicit reference.

{stamp}

{tables}
"""

SAGFREE = """## Sag-free start

`taichi-hair report sagfree [--quick]` prints the node drift under gravity of a mixed groom on
the default head with and without the sag-free start, and the solve's cost. It writes no JSON,
so its numbers are not on this page: run the command to measure them.
"""

BENCHMARK = """## Benchmark

```bash
.venv/bin/taichi-hair bench                      # quick table: 1, 100, 1000 guides x 32 nodes, explicit
.venv/bin/taichi-hair bench --full               # the whole table: up to 10000 guides, both integrators
.venv/bin/taichi-hair bench --precision both --json
.venv/bin/taichi-hair bench --arch cuda          # where a GPU exists
```

Human hair (E = 3 GPa, r = 40 um, 1 cm segments, dt = 1 ms, gravity, twist "quasistatic"): ms
per simulated frame (1/60 s) and strand-node-steps per second (medians after a warm-up, compile
time apart), a per-stage breakdown (forces, integration, projection, frames + twist), and with
`--full` the full head (1000 guides x 32 nodes on the default head, shaken: straight hair with
and without hair-hair interaction, and curly elliptic hair) for each integrator. Speed depends
on the machine and its load, so no figure is kept here: run the command. With `--json` stdout
holds the JSON document and nothing else (Taichi's banner and progress go to stderr).
"""

COSSERATBENCH = """## cosseratbench

taichi_hair takes part in [cosseratbench](https://pypi.org/project/cosseratbench/) (0.3) as four
solvers: `taichi_hair` (the explicit step, default fast projection), `taichi_hair_shake` (the
explicit step with `projection="shake"`), `taichi_hair_stretch` (the explicit step with
`extensible=True`: each rod stretches with EA = E A, as the benchmark's Cosserat rods do) and
`taichi_hair_implicit` (`integrator="implicit"`). They are registered in the entry point group
`cosseratbench.solvers`; the adapter is `taichi_hair/app/cosseratbench_plugin.py`, and the core
package never imports it.

```bash
.venv/bin/pip install -e '.[bench]'                # cosseratbench + the plugin
.venv/bin/pip install 'cosseratbench[pyelastica,mujoco]' 'mujoco<4'   # the comparison columns
.venv/bin/taichi-hair bench --cosseratbench        # every experiment: taichi_hair's solvers | pyelastica | mujoco
```

It prints one table per experiment (outcome, elements, wall time, each metric and observation)
and saves the results under `out/cosseratbench`. How the scenarios map onto taichi_hair and the
measured comparison with PyElastica and MuJoCo are in [cosseratbench.md](cosseratbench.md); this
page keeps no figures of it (the benchmark writes no report JSON): run the command.
"""

MISSING = """## {title}

Not measured for this page: run `{command}`, then `taichi-hair report markdown`.
"""


def load_reports(folder) -> dict:
    """{name: the report's JSON} for every report file in `folder`; ValueError (one line naming
    the folder or file) when the folder is missing, holds no report, or a file is not a stamped
    report of its kind."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"--reports {folder}: no such folder (the reports write their JSON there: "
                         f"run `taichi-hair report accuracy --quick` first)")
    found = {}
    for name, (file, keys, command) in REPORTS.items():
        path = folder / file
        if not path.exists():
            continue
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise ValueError(f"--reports: {path} is not readable JSON ({' '.join(str(err).split())})") from None
        if not isinstance(data, dict) or data.get("report") != name:
            raise ValueError(f"--reports: {path} is not the {name} report's JSON (no \"report\": \"{name}\")")
        missing = [k for k in keys if k not in data] + \
            [f"stamp.{k}" for k in STAMP_FIELDS if not isinstance(data.get("stamp"), dict) or k not in data["stamp"]]
        if missing:
            raise ValueError(f"--reports: {path} lacks {', '.join(missing)}: rerun `{command}`")
        found[name] = data
    if not found:
        raise ValueError(f"--reports {folder}: no report JSON in it ({', '.join(f for f, _, _ in REPORTS.values())}); "
                         f"run `taichi-hair report accuracy --quick` and `taichi-hair report stability --quick`")
    return found


def number(value, digits: int = 3) -> str:
    """A measurement as the page prints it: 3 significant digits, "-" for None or NaN."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}g}"


def machine(s: dict) -> str:
    return f"{s['cpu']}, {s['cores']} cores, {s['os']}, Python {s['python']}, Taichi {s['taichi']}"


def settings(name: str, r: dict) -> str:
    """A report's settings in words, from its JSON."""
    if name == "accuracy":
        w = r["sweep"]
        return (f"{'--quick' if r['quick'] else 'full'}: {', '.join(r['precisions'])}; segments: cantilever "
                f"{list(w['cantilever_segments'])}, frequency {list(w['frequency_segments'])}, helix "
                f"{list(w['helix_segments'])}, curl {list(w['curl_segments'])} at dt {1e3 * w['base_dt']:g} ms; "
                f"dt {', '.join(f'{1e3 * d:g}' for d in w['dts'])} ms at {w['dt_segments']} segments; "
                f"helix reference {w['reference_factor']}x; {w['repeats']} timed run(s) per row")
    if name == "stability":
        overrides = ", ".join(f"{k} {v}" for k, v in (r.get("overrides") or {}).items())
        return (f"{'--quick' if r['quick'] else 'full'}: {len(r['cases'])} cases, {r['duration']:g} s simulated "
                f"each, {', '.join(r['precisions'])}" + (f"; every case with {overrides}" if overrides else ""))
    return (f"{r['scene'] if r.get('scene_rows', True) else 'cantilever only'}, {r['precision']}"
            + (f"; {r['frames']} frames timed, every {r['every']}-th guide for {r['seconds']:g} s, steps "
               f"{r['steps_ms']} ms against dt {1e3 * r['reference_dt']:g} ms" if r.get("scene_rows", True)
               and "steps_ms" in r else ""))


def stamp_line(name: str, r: dict) -> str:
    s = r["stamp"]
    return (f"Measured by `{REPORTS[name][2].split(' --')[0]}` ({settings(name, r)}) on {s['date']}, commit "
            f"{s['commit']}; {machine(s)}.")


def table(head: list, rows: list) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def accuracy_tables(r: dict) -> str:
    """Per precision: error by segment count at the base step (wall time in brackets) with the
    ratio per refinement, and error by time step; then the helix reference."""
    w, out = r["sweep"], []
    for precision in r["precisions"]:
        rows = [x for x in r["rows"] if x["precision"] == precision]
        keys = list(dict.fromkeys((x["case"], x["twist"]) for x in rows))
        label = {k: k[0] + (f", {k[1]}" if k[0] == "helix" else "") for k in keys}
        segments = sorted({x["segments"] for x in rows if x["dt"] == w["base_dt"]})
        body = []
        for key in keys:
            by_n = {x["segments"]: x for x in rows if (x["case"], x["twist"]) == key and x["dt"] == w["base_dt"]}
            errors = [by_n[n]["error"] for n in segments if n in by_n]
            ratios = ", ".join(number(a / b, 2) for a, b in zip(errors, errors[1:]) if b)
            body.append([label[key]] + [f"{number(by_n[n]['error'])} ({by_n[n]['wall_s']:.2f} s)" if n in by_n
                                        else "" for n in segments] + [ratios or "-"])
        out += [f"{precision}, dt {1e3 * w['base_dt']:g} ms: error (wall time) by segment count, and the error's "
                "ratio from one column to the next (second order divides it by about 4 per halving)", "",
                table(["case"] + [f"{n} seg" for n in segments] + ["ratios"], body), ""]
        steps = sorted({x["dt"] for x in rows if x["segments"] == w["dt_segments"]})
        body = []
        for key in keys:
            by_dt = {x["dt"]: x for x in rows if (x["case"], x["twist"]) == key and x["segments"] == w["dt_segments"]}
            if len(by_dt) > 1:
                body.append([label[key]] + [number(by_dt[d]["error"]) if d in by_dt else "" for d in steps])
        if body:
            out += [f"{precision}, {w['dt_segments']} segments: error by time step", "",
                    table(["case"] + [f"dt {1e3 * d:g} ms" for d in steps], body), ""]
    if len(r["precisions"]) > 1:
        f32 = {(x["case"], x["twist"], x["segments"], x["dt"]): x["error"] for x in r["rows"]
               if x["precision"] == "float32"}
        gaps = [(abs(f32[k] / x["error"] - 1), k) for x in r["rows"] if x["precision"] == "float64"
                for k in [(x["case"], x["twist"], x["segments"], x["dt"])] if k in f32 and x["error"]]
        if gaps:
            gap, (case, twist, n, dt) = max(gaps)
            out.append(f"float32 against float64: the errors differ by at most {number(100 * gap, 2)} % "
                       f"({case}, {twist}, {n} segments, dt {1e3 * dt:g} ms).")
            out.append("")
    ref = r["helix_reference"]
    out.append(f"The helix reference: {ref['segments']} segments, {ref['precision']}, {ref['twist']}, dt "
               f"{1e3 * ref['dt']:g} ms ({ref['substeps']} substeps), {ref['wall_s']:.1f} s.")
    return "\n".join(out)


def stability_sections(r: dict) -> dict:
    counts = r["counts"]
    head = ["precision", "cases", "stable", "substepped", "refused", "FAIL"]
    rows = [[p, n["cases"], n["stable"], n["substepped"], n["refused"], n["FAIL"]] for p, n in counts.items()]
    wall = sum(c["wall_s"] for c in r["cases"])
    count_text = table(head, rows) + f"\n\nWall time {wall:.0f} s in all (compiling kernels included)."
    energy = []
    for p in r["precisions"]:
        rises = [(c["energy_max_rise"], c["name"]) for c in r["cases"] if c["precision"] == p and c["conservative"]
                 and c["status"] != "refused" and c.get("energy_max_rise") is not None]
        if rises:
            rise, name = max(rises)
            energy.append(f"{p}: the largest energy rise of the {len(rises)} undamped, undriven cases is "
                          f"{number(rise, 2)} of the energy in play ({name})." if rise > 0 else
                          f"{p}: none of the {len(rises)} undamped, undriven cases gained energy.")
    body = []
    for c in r["cases"]:
        outcome = " ".join(c["outcome"].split()).replace("|", "/")
        if len(outcome) > OUTCOME_WIDTH:
            outcome = outcome[:OUTCOME_WIDTH - 3] + "..."
        body.append([c["name"], c["precision"], outcome,
                     number(c["stable_dt"] * 1e3) if c.get("stable_dt") else "-",
                     number(c.get("measured_residual"), 2), number(c.get("max_speed"), 2), f"{c['wall_s']:.1f}"])
    cases = table(["case", "precision", "outcome", "bound ms", "max \\|len^2/rest^2 - 1\\|", "v max m/s", "wall s"],
                  body)
    return {"counts": count_text, "energy": " ".join(energy), "table": cases}


def implicit_tables(r: dict) -> str:
    out = []
    if r["cantilever"]:
        first = r["cantilever"][0]
        out += [f"Real-hair cantilever, first mode {number(first['expected_hz'], 4)} Hz by the beam formula:", "",
                table(["integrator", "dt ms", "substeps", "frequency Hz", "f / f_beam - 1", "amplitude lost / period",
                       "wall s"],
                      [[x["integrator"], f"{1e3 * x['dt']:g}", x["substeps"], number(x["frequency_hz"], 5),
                        f"{x['frequency_error']:+.2e}", number(x["loss_per_period"]), f"{x['wall_s']:.2f}"]
                       for x in r["cantilever"]]), ""]
    if r["speed"]:
        out += [f"{r['scene']}: simulation ms per frame (median over frames after the first)", "",
                table(["integrator", "guides", "dt ms", "substeps", "ms / frame", "head depth mm", "max strain"],
                      [[x["integrator"], x["guides"], f"{1e3 * x['dt']:g}", x["substeps"], f"{x['ms_per_frame']:.0f}",
                        f"{x['head_depth_mm']:.3f}", number(x["max_strain"], 2)] for x in r["speed"]]), ""]
    acc = r["accuracy"]
    if acc:
        out += [f"Every {r['every']}-th guide for {r['seconds']:g} s: tip deviation / L from the explicit step at dt "
                f"{1e3 * acc['reference_dt']:g} ms", "",
                table(["integrator", "dt ms", "substeps", "wall s", "tip RMS", "tip max", "max strain"],
                      [[x["integrator"], f"{1e3 * x['dt']:g}", x["substeps"]] +
                       ([x["outcome"][:OUTCOME_WIDTH], "", "", ""] if "outcome" in x else
                        [f"{x['wall_s']:.2f}", number(x["tip_rms"]), number(x["tip_max"]), number(x["max_strain"], 2)])
                       for x in acc["rows"]]), ""]
    return "\n".join(out).rstrip()


def render_page(reports: dict, page_stamp: dict) -> str:
    """The page's markdown from the loaded reports (load_reports) and the stamp of this writing."""
    runs = "\n".join(f"| {name} | {r['stamp']['date']} | {r['stamp']['commit']} | {machine(r['stamp'])} | "
                     f"{settings(name, r)} |" for name, r in reports.items())
    parts = [HEADER.format(date=page_stamp["date"], commit=page_stamp["commit"], runs=runs)]
    if "accuracy" in reports:
        r = reports["accuracy"]
        parts.append(ACCURACY.format(timing=r["timing"], stamp=stamp_line("accuracy", r),
                                     tables=accuracy_tables(r)))
    else:
        parts.append(MISSING.format(title="Accuracy", command=REPORTS["accuracy"][2]))
    if "stability" in reports:
        r = reports["stability"]
        strain = 100 * (math.sqrt(1 + r["thresholds"]["constraint_fail"]) - 1)  # |len^2/rest^2 - 1| = 2 e + e^2
        parts.append(STABILITY.format(stamp=stamp_line("stability", r), strain=strain, **r["thresholds"],
                                      **stability_sections(r)))
    else:
        parts.append(MISSING.format(title="Stability", command=REPORTS["stability"][2]))
    if "implicit" in reports:
        parts.append(IMPLICIT.format(stamp=stamp_line("implicit", reports["implicit"]),
                                     tables=implicit_tables(reports["implicit"])))
    else:
        parts.append(MISSING.format(title="The implicit step", command=REPORTS["implicit"][2]))
    parts += [SAGFREE, BENCHMARK, COSSERATBENCH]
    return "\n".join(p.rstrip() + "\n" for p in parts)


def write_page(folder="out/reports", out="docs/validation.md") -> Path:
    """Read the reports in `folder` (checked first: load_reports) and write the page to `out`."""
    reports = load_reports(folder)
    out = Path(out)
    if not out.parent.is_dir():
        raise ValueError(f"--out {out}: its folder {out.parent} does not exist")
    out.write_text(render_page(reports, stamp()))
    return out
