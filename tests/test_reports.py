"""The accuracy and stability reports on tiny sweeps (measured physics, not printed text), and the
numpy log-log plotter they draw with."""

import json
import math

import numpy as np
import pytest

import taichi_hair as th
from render.plot import Series, draw_text, loglog
from render.video import read_png
from taichi_hair.app import reports, stability_report as stability_module, validation_page
from taichi_hair.rods.references import cantilever_elastica_tip, cantilever_first_frequency, first_mode_slope
from taichi_hair.app.accuracy_report import (CURL_AXES, CURL_VARIANTS, HELIX_LENGTH, AccuracySweep, accuracy_report,
                                             amplitude_loss_per_period, clamped_helix, oscillation_frequency)
from taichi_hair.app.stability_cases import BASE_CASE, STABILITY_AXES, StabilityCase, case_axes, stability_cases
from taichi_hair.app.stability_report import (CONSTRAINT_FAIL, STATUSES, format_stability, judge, run_stability_case,
                                              stability_report, stability_scene)
from taichi_hair.solver.stability import stable_time_step

TINY = AccuracySweep(cantilever_segments=(12, 25, 50), frequency_segments=(12,), helix_segments=(12,),
                             curl_segments=(25, 50, 100), dts=(2e-3,), dt_segments=12, reference_factor=2,
                             repeats=1)


@pytest.fixture(scope="module")
def accuracy(tmp_path_factory):
    out = tmp_path_factory.mktemp("reports")
    return accuracy_report(True, ["float64"], out, sweep=TINY)


# a few cases of the quick matrix, one of each kind of outcome and scene, run in this process's
# float64 for 0.1 s (the gale has its own test below)
STABILITY_SUBSET = ("human hair", "dt 20 ms", "curl 2 mm, 1 mm segments", "head", "pin mid", "hand 5 m/s",
                    "strict, dt 5 ms", "E 1e11, 1 mm, dt 20 ms (max_substeps)")


@pytest.fixture(scope="module")
def stability(tmp_path_factory):
    cases = [c for c in stability_cases(quick=True) if c.name in STABILITY_SUBSET]
    assert len(cases) == len(STABILITY_SUBSET)
    return stability_report(True, tmp_path_factory.mktemp("stability"), cases=cases, duration=0.1,
                                    precision="float64")


def test_cantilever_error_falls_with_refinement(accuracy):
    rows = {r["segments"]: r for r in accuracy["rows"] if r["case"] == "cantilever" and r["dt"] == TINY.base_dt}
    errors = [rows[n]["error"] for n in (12, 25, 50)]
    assert errors[0] > errors[1] > errors[2] > 0
    assert errors[0] / errors[2] > 8  # the clamp at the root node gives second order: about 11 here
    assert all(r["settle"] < 1e-4 for r in rows.values())  # at rest when measured


def test_frequency_row_matches_beam_theory(accuracy):
    row = next(r for r in accuracy["rows"] if r["case"] == "frequency" and r["dt"] == TINY.base_dt)
    assert row["error"] < 0.02 and row["measured_hz"] > 0


@pytest.mark.parametrize("loss", [0.0, 1e-3, 5e-2])
def test_frequency_and_damping_estimates_on_a_damped_cosine(loss):
    """The cantilever rows' estimators on z = A r^(t f) cos(2 pi f t), r = 1 - loss, sampled
    37 times a period as at dt 16 ms (numpy, no simulator)."""
    f = 1.7
    t = np.arange(0.0, 5.0 / f, 1.0 / (37 * f))
    z = 1e-3 * (1.0 - loss) ** (t * f) * np.cos(2 * np.pi * f * t)
    assert abs(oscillation_frequency(t, z) / f - 1) < 1e-4
    assert abs(amplitude_loss_per_period(t, z) - loss) < 2e-4


def test_implicit_figure_draws_both_integrators():
    """The implicit report's error-vs-wall-time figure: one colour per integrator, diverged rows
    left out (no simulator: rows as the report writes them)."""
    from render.plot import PALETTE
    from taichi_hair.app.implicit_report import implicit_figure
    rows = [{"integrator": i, "dt": dt, "wall_s": w, "tip_rms": e}
            for i, scale in (("explicit", 1.0), ("implicit", 0.2)) for dt, w, e in
            ((1e-3, 1.0 * scale, 1e-4), (4e-3, 0.5 * scale, 1e-3))]
    rows.append({"integrator": "implicit", "dt": 16e-3, "outcome": "diverged: ..."})
    image = implicit_figure({"scene": "scenes/x.py", "accuracy": {"reference_dt": 1e-4, "rows": rows}}).image
    for colour in PALETTE[:2]:
        assert (np.abs(image.astype(int) - colour).sum(axis=2) == 0).sum() > 50


def test_curly_case_has_both_twist_modes_with_finite_errors(accuracy):
    helix = [r for r in accuracy["rows"] if r["case"] == "helix"]
    assert {r["twist"] for r in helix} == {"quasistatic", "kmoch"}
    assert all(np.isfinite(r["error"]) and r["error"] > 0 for r in helix)
    reference = accuracy["helix_reference"]
    assert reference["segments"] == 24 and reference["precision"] == "float64"
    # quasistatic settles, with the helix stretched by its weight below its rest tip
    rest_tip = clamped_helix(12).positions[0, -1]
    for r in [reference] + [r for r in helix if r["twist"] == "quasistatic"]:
        assert r["settle"] < 1e-6 and r["tip"][2] < rest_tip[2] - 0.02 * HELIX_LENGTH


def test_curled_rod_converges_to_the_continuum_at_second_order(accuracy):
    """The curl rows against the continuum Kirchhoff rod (taichi_hair.rods.continuum): halving the
    segment length divides the tip error by about 4, with the helix axis down and horizontal; with
    the rotation strain measure (the default) the tip is within 2.5 % of the drop at 50 segments,
    and the DER measure (strain="der") and the rigid first edge (root="edge", with DER) are worse
    at every resolution."""
    for axis in CURL_AXES:
        variants = {}
        for suffix in CURL_VARIANTS:
            rows = {r["segments"]: r for r in accuracy["rows"] if r["case"] == f"curl {axis}{suffix}"}
            assert all(r["settle"] < 1e-8 for r in rows.values())  # at rest when measured
            variants[suffix] = [rows[n]["error"] for n in (25, 50, 100)]
            errors = variants[suffix]
            print(f"\ncurl {axis}{suffix}: tip error / drop {[f'{e:.4f}' for e in errors]}, "
                  f"ratios {errors[0] / errors[1]:.2f}, {errors[1] / errors[2]:.2f}")
        rotation, der, edge = variants[""], variants[" der"], variants[" edge"]
        assert rotation[0] / rotation[1] > 3.5 and rotation[1] / rotation[2] > 3.5
        assert der[0] / der[1] > 3.3 and der[1] / der[2] > 3.5
        assert rotation[1] < 0.025
        assert all(e > d > r for e, d, r in zip(edge, der, rotation))


def test_accuracy_writes_json_and_a_non_blank_png(accuracy):
    saved = json.loads(open(accuracy["json"]).read())
    assert len(saved["rows"]) == len(accuracy["rows"]) == 3 + 1 + 1 + 1 + 2 * 2 + 2 * 3 * 3  # + curl rows
    image = read_png(accuracy["png"])
    assert image is not None and image.shape == (600, 960, 3)
    assert image.astype(float).var() > 0
    assert all(r["wall_s"] > 0 and r["steps"] > 0 and r["substeps"] >= 1 for r in accuracy["rows"])


def test_stability_matrix_covers_every_axis():
    """>= 100 cases (quick: a third, >= 34) sweeping each axis (material, geometry, step, motion,
    air, touch, pins, interaction, head, twist, precision, limits) over its whole range,
    alone and combined, in both precisions and every twist mode."""
    full, quick = stability_cases(quick=False), stability_cases(quick=True)
    assert len(full) >= 100 and 34 <= len(quick) <= len(full) // 2
    assert len({c.name for c in full}) == len(full) and set(quick) <= set(full)
    for cases in (full, quick):
        covered = {axis for c in cases for axis in case_axes(c)}
        assert covered == set(STABILITY_AXES), set(STABILITY_AXES) - covered
        assert {c.precision for c in cases} == {"float32", "float64"}
        assert {c.twist for c in cases} == {"none", "kmoch", "quasistatic"}
    # each axis alone (or with the one it needs: a curl its segment, wind its drag, a tie its shake)
    # and >= 15 cases combining three axes or more
    needs = {"curl": {"segment"}, "wind": {"drag"}, "pin": {"shake", "curl", "segment"}, "limits": {"dt"}}
    for axis in STABILITY_AXES:
        assert any(set(case_axes(c)) <= {axis} | needs.get(axis, set()) and axis in case_axes(c)
                   for c in full), axis
    assert sum(len(case_axes(c)) >= 3 for c in full) >= 15
    # each axis from one end of its range to the other
    def span(field, cases=full):
        values = [getattr(c, field) for c in cases]
        return min(values), max(values)
    assert span("youngs_modulus") == (1e7, 1e11) and span("radius") == (10e-6, 200e-6)
    assert span("ellipticity") == (1.0, 4.0) and span("segment") == (0.001, 0.03) and span("dt") == (5e-5, 2e-2)
    assert span("shake_hz") == (0.0, 10.0) and max(c.shake_deg for c in full if c.shake_hz) == 90.0
    assert span("wind") == (0.0, 60.0) and {c.curl_radius for c in full} >= {0.0, 0.002}
    assert {c.gust for c in full if c.wind} >= {0.0, 1.0} and {c.turbulence for c in full if c.wind} >= {0.0, 0.3}
    assert span("grab_stiffness", [c for c in full if c.grab_stiffness]) == (0.01, 100.0)
    assert span("grab_speed", [c for c in full if c.grab_stiffness]) == (0.0, 10.0)
    assert {c.pin for c in full} >= {"", "mid", "clip", "tie"} and any(c.head for c in full)
    assert any(c.interaction for c in full) and any(c.hand_speed for c in full)


def test_stability_outcomes(stability):
    rows = stability["cases"]
    assert sorted(r["name"] for r in rows) == sorted(STABILITY_SUBSET)
    assert all(r["status"] in STATUSES and r["precision"] == "float64" for r in rows)
    assert stability["failures"] == 0, [r["outcome"] for r in rows if r["status"] == "FAIL"]
    assert {"stable", "substepped", "refused"} <= {r["status"] for r in rows}
    counts = stability["counts"]["all"]
    assert counts["cases"] == len(rows) == sum(counts[s] for s in STATUSES)
    for r in rows:
        if r["status"] == "substepped":
            assert r["substeps"] > 1 and r["dt"] / r["substeps"] <= r["stable_dt"]
            assert r["outcome"] == f"substepped ({r['substeps']})"
        if r["status"] == "refused":
            assert r["outcome"].startswith("refused: ") and len(r["outcome"]) > 40
        else:
            assert r["measured_residual"] < CONSTRAINT_FAIL and r["max_speed"] > 0.5
    # undamped, undriven: the projection, contacts and still pins may only remove energy
    conservative = [r for r in rows if r["conservative"] and r["status"] != "refused"]
    assert {r["name"] for r in conservative} >= {"human hair", "curl 2 mm, 1 mm segments", "head", "pin mid"}
    assert all(r["energy_max_rise"] < 1e-4 for r in conservative), [(r["name"], r["energy_max_rise"])
                                                                     for r in conservative]
    # the hair reached the head and the hand (nodes at their margins) without going through
    head = next(r for r in rows if r["name"] == "head")
    hand = next(r for r in rows if r["name"] == "hand 5 m/s")
    assert -1.05 < head["penetration_by"]["head"] <= 1.0 and -1.05 < hand["penetration_by"]["hand"] <= 1.0
    text = format_stability(stability)
    assert f"cases: {len(rows)}; stable {counts['stable']}, substepped {counts['substepped']}, refused " \
           f"{counts['refused']}, FAIL 0" in text


def test_stability_refusals_name_the_bound(stability):
    row = next(r for r in stability["cases"] if r["name"] == "strict, dt 5 ms")
    case = next(c for c in stability_cases(quick=True) if c.name == row["name"])
    groom, material, _ = stability_scene(case)
    bound = stable_time_step(groom, [material] * groom.n_strands, case.drag)
    assert row["status"] == "refused" and "stability bound" in row["outcome"]
    assert f"{bound:.3g} s" in row["outcome"] and bound < case.dt
    row = next(r for r in stability["cases"] if "max_substeps" in r["name"])
    assert row["status"] == "refused" and "more than max_substeps = 1000" in row["outcome"]
    assert "bending stiffness" in row["outcome"]


def test_gale_wind_keeps_edges_inextensible():
    # a 60 m/s gale with gusts and turbulence at dt 1 ms: the wind bound (the fastest air moves a
    # node at most one segment per substep) substeps it; the row's own check measures the strain
    case = next(c for c in stability_cases(quick=True) if c.name == "wind 60 m/s")
    row = run_stability_case(case, 0.1)
    fastest = case.wind * (1.0 + case.gust) + 3.0 * case.turbulence * case.wind  # m/s
    assert row["status"] == "substepped", row["outcome"]
    assert row["substeps"] == math.ceil(case.dt * fastest / case.segment - 1e-9), row["outcome"]
    assert row["measured_residual"] < 1e-5 and row["max_speed"] > 5


def test_stability_broken_cases_fail(monkeypatch, tmp_path):
    """Each FAIL rule catches a deliberately broken case: an undocumented exception, a head
    whose collider the simulator never got (the measure comes from the case), a hidden energy
    source in a case judged undamped and undriven, and (on the rule itself) strain past 1 %."""
    scene = stability_scene

    def without_colliders(case):
        groom, material, options = scene(case)
        return groom, material, {**options, "colliders": ()}
    monkeypatch.setattr(stability_module, "stability_scene", without_colliders)
    row = run_stability_case(StabilityCase(name="head", head=True, youngs_modulus=1e8), 0.1)
    assert row["status"] == "FAIL" and "inside the head" in row["outcome"], row["outcome"]

    def hidden_grab(case):
        groom, material, options = scene(case)
        lift = th.Grab(path=lambda t: groom.positions[0, 10] + [0.0, 0.0, 0.5 * t], stiffness=0.1)
        return groom, material, {**options, "touch": (lift,)}
    monkeypatch.setattr(stability_module, "stability_scene", hidden_grab)
    row = run_stability_case(StabilityCase(name="lifted"), 0.1)
    assert row["conservative"] and row["status"] == "FAIL" and "energy rose" in row["outcome"], row["outcome"]

    facts = {"measured_residual": 0.021, "penetration_by": {}, "energy_max_rise": 0.0}
    assert "1 % strain" in judge(BASE_CASE, facts, {"projection_stalls": 0})
    assert judge(BASE_CASE, {**facts, "measured_residual": 0.019}, {"projection_stalls": 0}) is None

    def broken(case):
        raise RuntimeError("boom")
    monkeypatch.setattr(stability_module, "stability_scene", broken)
    monkeypatch.setattr(stability_module, "stability_cases", lambda quick: [StabilityCase(name="broken")])
    row = run_stability_case(StabilityCase(name="broken"), 0.01)
    assert row["status"] == "FAIL" and "RuntimeError: boom" in row["outcome"]
    assert reports.main(["stability", "--quick", "--precision", "float64", "--out", str(tmp_path)]) == 1


def test_stability_runs_each_precision_in_its_own_process(tmp_path):
    """precision "both": float64 cases here, float32 ones in a worker subprocess, rows in order."""
    cases = [StabilityCase(name="f32", precision="float32"),
             StabilityCase(name="f64", precision="float64"),
             StabilityCase(name="f32 strict", precision="float32", dt=5e-3, strict=True)]
    result = stability_report(False, tmp_path, cases=cases, duration=0.02)
    assert [r["name"] for r in result["cases"]] == ["f32", "f64", "f32 strict"]
    assert [r["precision"] for r in result["cases"]] == ["float32", "float64", "float32"]
    assert [r["status"] for r in result["cases"]] == ["stable", "stable", "refused"]
    assert result["counts"]["float32"] == {"cases": 2, "stable": 1, "substepped": 0, "refused": 1, "FAIL": 0}
    assert json.loads(open(result["json"]).read())["counts"] == result["counts"]


def test_horizontal_line_lands_on_its_pixel_row():
    red = (255, 0, 0)
    fig = loglog([Series(x=(1.0, 100.0), y=(1e-2, 1e-2), colour=red, marker="")], width=400, height=300,
                 x_range=(1.0, 100.0), y_range=(1e-4, 1.0))
    ax, image = fig.axes, fig.image
    row = ax.top + (0.0 - (-2.0)) / (0.0 - (-4.0)) * (ax.bottom - ax.top)  # log10 1e-2 in [-4, 0]
    r = int(round(row))
    is_red = np.all(image == red, axis=2)
    assert is_red[r, ax.left + 2:ax.right - 1].all()
    assert not is_red[r - 3].any() and not is_red[r + 3].any()
    assert is_red.sum() == pytest.approx(3 * (ax.right - ax.left - 1), rel=0.05)  # 3 px thick, clipped


def test_markers_text_and_range_checks():
    blue = (0, 0, 255)
    fig = loglog([Series(x=(10.0,), y=(1e-3,), colour=blue, marker="s", line=False, label="one point")],
                 width=500, height=300, x_range=(1.0, 100.0), y_range=(1e-6, 1.0))
    col, row = fig.axes.to_pixel(10.0, 1e-3)
    assert np.all(fig.image[int(round(float(row))), int(round(float(col)))] == blue)
    assert (fig.axes.left + fig.axes.right) / 2 == pytest.approx(float(col), abs=0.5)
    canvas = np.full((20, 60, 3), 255, np.uint8)
    draw_text(canvas, 1, 1, "1E-3", scale=2)
    assert (canvas == 0).all(axis=2).sum() > 20
    with pytest.raises(ValueError, match="same length"):
        Series(x=(1.0, 2.0), y=(1.0,))
    with pytest.raises(ValueError, match="increasing"):
        loglog([], x_range=(10.0, 1.0))


def test_references_meet_small_load_beam_theory():
    """The shared references (taichi_hair.rods.references) against closed forms: under a tiny
    load the elastica's tip drops w L^4 / (8 EI) (linear beam theory) and stays at x = L to
    second order; the first mode's slope integrates to its unit tip deflection and vanishes at
    the clamp."""
    length, ei, weight = 0.7, 2.0, 1e-5
    tip = cantilever_elastica_tip(length, weight, ei, n=800)
    linear = weight * length**4 / (8 * ei)
    assert tip[1] == pytest.approx(-linear, rel=1e-4) and tip[0] == pytest.approx(length, abs=1e-9)
    s = np.linspace(0.0, length, 20001)
    slope = first_mode_slope(s, length)
    assert slope[0] == pytest.approx(0.0, abs=1e-12)
    assert np.sum(0.5 * (slope[1:] + slope[:-1]) * np.diff(s)) == pytest.approx(1.0, rel=1e-6)
    # f = (beta L)^2 / (2 pi L^2) sqrt(EI / rho A): scaling as 1 / L^2 and sqrt(EI)
    f = cantilever_first_frequency(length, ei, 0.3)
    assert cantilever_first_frequency(2 * length, 4 * ei, 0.3) == pytest.approx(f / 2, rel=1e-12)


def synthetic_reports(folder):
    """Small accuracy and stability JSON as the reports write them (two segment counts, two
    cases), with a stamp: the page must show exactly these numbers."""
    stamp = {"commit": "abc1234", "date": "2026-01-02 03:04 UTC", "cpu": "Test CPU 9000", "cores": 3,
             "os": "TestOS-1", "python": "3.99.0", "taichi": "9.8.7"}
    sweep = {"cantilever_segments": [10, 20], "frequency_segments": [10], "helix_segments": [10],
             "curl_segments": [20], "base_dt": 0.001, "dts": [0.002], "dt_segments": 10,
             "twists": ["quasistatic"], "reference_factor": 4, "repeats": 1}
    row = {"twist": "none", "precision": "float64", "runs": 1, "steps": 10, "substeps": 1, "sim_time": 1.0}
    rows = [{**row, "case": "cantilever", "segments": 10, "dt": 0.001, "error": 0.0123456, "wall_s": 1.5},
            {**row, "case": "cantilever", "segments": 20, "dt": 0.001, "error": 0.00308, "wall_s": 2.75},
            {**row, "case": "cantilever", "segments": 10, "dt": 0.002, "error": 0.0124, "wall_s": 0.8}]
    accuracy = {"report": "accuracy", "stamp": stamp, "quick": True, "arch": "cpu", "precisions": ["float64"],
                "sweep": sweep, "rows": rows, "timing": "one timed run",
                "helix_reference": {"segments": 40, "precision": "float64", "twist": "quasistatic", "dt": 0.0005,
                                    "substeps": 2, "wall_s": 7.25}}
    case = {"precision": "float32", "conservative": True, "wall_s": 4.0, "measured_residual": 3.5e-7,
            "max_speed": 1.25, "stable_dt": 0.0004}
    cases = [{**case, "name": "soft case", "status": "stable", "outcome": "stable", "energy_max_rise": 4.5e-6},
             {**case, "name": "strict case", "status": "refused",
              "outcome": "refused: dt | past the bound " + "x" * 300,
              "energy_max_rise": None}]
    stability = {"report": "stability", "stamp": {**stamp, "commit": "def5678"}, "arch": "cpu",
                 "precisions": ["float32"], "duration": 0.05, "quick": True, "overrides": {}, "cases": cases,
                 "counts": {"all": {"cases": 2, "stable": 1, "substepped": 0, "refused": 1, "FAIL": 0},
                            "float32": {"cases": 2, "stable": 1, "substepped": 0, "refused": 1, "FAIL": 0}},
                 "thresholds": {"constraint_fail": 0.0345, "energy_rise_fail": 0.0678}, "failures": 0}
    folder.mkdir(exist_ok=True)
    (folder / "accuracy.json").write_text(json.dumps(accuracy))
    (folder / "stability.json").write_text(json.dumps(stability))


def test_markdown_page_from_synthetic_reports(tmp_path, capsys):
    """`report markdown` writes the page from the JSON alone: the stamps (commit, date, machine,
    versions), the settings and every number come from the synthetic files."""
    synthetic_reports(tmp_path / "r")
    page = tmp_path / "validation.md"
    assert reports.main(["markdown", "--reports", str(tmp_path / "r"), "--out", str(page)]) == 0
    text = page.read_text()
    for stamp in ("abc1234", "def5678", "2026-01-02 03:04 UTC", "Test CPU 9000, 3 cores, TestOS-1, Python 3.99.0, "
                  "Taichi 9.8.7"):
        assert stamp in text
    assert "| cantilever | 0.0123 (1.50 s) | 0.00308 (2.75 s) | 4 |" in text  # ratio 0.0123456 / 0.00308
    assert "| cantilever | 0.0123 | 0.0124 |" in text and "dt 2 ms" in text  # the time-step table
    assert "40 segments, float64, quasistatic, dt 0.5 ms (2 substeps), 7.2 s" in text
    assert "| float32 | 2 | 1 | 0 | 1 | 0 |" in text and "0.0345 (1.7 % strain)" in text and "0.0678" in text
    assert "4.5e-06 of the energy in play (soft case)" in text
    assert "refused: dt / past the bound xxx" in text and "x" * 200 not in text  # trimmed, no table break
    assert "Not measured for this page: run `taichi-hair report implicit`" in text
    assert "--quick: 2 cases, 0.05 s simulated each, float32" in text
    # nothing on the page is a number the JSON does not hold: the old page's figures are gone
    assert "114x" not in text and "2.1 %" not in text


@pytest.mark.parametrize("make, message", [
    (lambda d: None, "no such folder"),
    (lambda d: d.mkdir(), "no report JSON in it"),
    (lambda d: (d.mkdir(), (d / "accuracy.json").write_text("{not json")), "accuracy.json is not readable JSON"),
    (lambda d: (d.mkdir(), (d / "stability.json").write_text(json.dumps({"report": "stability", "cases": []}))),
     "stability.json lacks counts, duration"),
])
def test_markdown_refuses_a_missing_or_bad_report_folder(tmp_path, capsys, make, message):
    folder = tmp_path / "r"
    make(folder)
    page = tmp_path / "validation.md"
    assert reports.main(["markdown", "--reports", str(folder), "--out", str(page)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "--reports" in err and len(err.splitlines()) == 1
    assert not page.exists()


def test_markdown_page_shows_the_implicit_report(tmp_path):
    """A cantilever-only implicit.json (as `report implicit --cantilever-only` writes it) gets its
    section: its stamp, settings and the frequency and damping rows from the file."""
    synthetic_reports(tmp_path)
    stamp = {**json.loads((tmp_path / "accuracy.json").read_text())["stamp"], "commit": "fed9876"}
    rows = [{"integrator": i, "dt": 0.004, "substeps": s, "wall_s": 1.5, "frequency_hz": 1.6789, "expected_hz": 1.7,
             "frequency_error": e, "loss_per_period": loss}
            for i, s, e, loss in (("explicit", 3, -0.0123, 2.5e-5), ("implicit", 1, -0.0456, 0.0321))]
    implicit = {"report": "implicit", "stamp": stamp, "scene": "scenes/shake_curly.py", "precision": "float32",
                "speed": [], "accuracy": None, "every": 10, "seconds": 0.5, "frames": 12, "reference_dt": 1e-4,
                "steps_ms": [1, 2], "scene_rows": False, "cantilever": rows}
    (tmp_path / "implicit.json").write_text(json.dumps(implicit))
    text = validation_page.render_page(validation_page.load_reports(tmp_path), stamp)
    section = text[text.index("## The implicit step"):text.index("## Sag-free start")]
    assert "fed9876" in section and "(cantilever only, float32)" in section
    assert "| implicit | 4 | 1 | 1.6789 | -4.56e-02 | 0.0321 | 1.50 |" in section
    assert "| explicit | 4 | 3 | 1.6789 | -1.23e-02 | 2.5e-05 | 1.50 |" in section
    assert "first mode 1.7 Hz" in section
