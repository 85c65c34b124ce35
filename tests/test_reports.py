"""The accuracy and stability reports on tiny sweeps (measured physics, not printed text), and the
numpy log-log plotter they draw with."""

import json
from dataclasses import replace

import numpy as np
import pytest

import taichi_hair as th
from references import cantilever_elastica_tip, cantilever_first_frequency, first_mode_slope
from render.plot import Series, draw_text, loglog
from render.video import read_png
from taichi_hair import reports
from taichi_hair.stability import stable_time_step

TINY = reports.AccuracySweep(cantilever_segments=(12, 25, 50), frequency_segments=(12,), helix_segments=(12,),
                             curl_segments=(25, 50, 100), dts=(2e-3,), dt_segments=12, reference_factor=2,
                             repeats=1)


@pytest.fixture(scope="module")
def accuracy(tmp_path_factory):
    out = tmp_path_factory.mktemp("reports")
    return reports.accuracy_report(True, ["float64"], out, sweep=TINY)


@pytest.fixture(scope="module")
def stability(tmp_path_factory):
    # the gale case is left to test_gale_wind_keeps_edges_inextensible below
    cases = [c for c in reports.stability_cases(quick=True) if not c.wind]
    return reports.stability_report(True, tmp_path_factory.mktemp("stability"), cases=cases, duration=0.1)


def test_references_agree_with_the_test_suites():
    m = reports.beam_material()
    ei, rho_a = m.bending_stiffness[0], m.linear_density
    ours = reports.elastica_tip(1.0, rho_a * 9.81, ei, n=500)
    assert np.abs(ours - cantilever_elastica_tip(1.0, rho_a * 9.81, ei, n=500)).max() < 1e-9
    assert reports.beam_frequency(1.0, ei, rho_a) == pytest.approx(cantilever_first_frequency(1.0, ei, rho_a), 1e-12)
    s = np.linspace(0, 1, 7)
    assert np.allclose(reports.first_mode_slope(s, 1.0), first_mode_slope(s, 1.0), rtol=1e-12)


def test_cantilever_error_falls_with_refinement(accuracy):
    rows = {r["segments"]: r for r in accuracy["rows"] if r["case"] == "cantilever" and r["dt"] == TINY.base_dt}
    errors = [rows[n]["error"] for n in (12, 25, 50)]
    assert errors[0] > errors[1] > errors[2] > 0
    assert errors[0] / errors[2] > 8  # the clamp at the root node gives second order: about 11 here
    assert all(r["settle"] < 1e-4 for r in rows.values())  # at rest when measured


def test_frequency_row_matches_beam_theory(accuracy):
    row = next(r for r in accuracy["rows"] if r["case"] == "frequency" and r["dt"] == TINY.base_dt)
    assert row["error"] < 0.02 and row["measured_hz"] > 0


def test_curly_case_has_both_twist_modes_with_finite_errors(accuracy):
    helix = [r for r in accuracy["rows"] if r["case"] == "helix"]
    assert {r["twist"] for r in helix} == {"quasistatic", "kmoch"}
    assert all(np.isfinite(r["error"]) and r["error"] > 0 for r in helix)
    reference = accuracy["helix_reference"]
    assert reference["segments"] == 24 and reference["precision"] == "float64"
    # quasistatic settles, with the helix stretched by its weight below its rest tip
    rest_tip = reports.clamped_helix(12).positions[0, -1]
    for r in [reference] + [r for r in helix if r["twist"] == "quasistatic"]:
        assert r["settle"] < 1e-6 and r["tip"][2] < rest_tip[2] - 0.02 * reports.HELIX_LENGTH


def test_curled_rod_converges_to_the_continuum_at_second_order(accuracy):
    """The curl rows against the continuum Kirchhoff rod (taichi_hair.continuum): halving the
    segment length divides the tip error by about 4, with the helix axis down and horizontal."""
    for axis in reports.CURL_AXES:
        rows = {r["segments"]: r for r in accuracy["rows"] if r["case"] == f"curl {axis}"}
        errors = [rows[n]["error"] for n in (25, 50, 100)]
        print(f"\ncurl {axis}: tip error / drop {[f'{e:.4f}' for e in errors]}, "
              f"ratios {errors[0] / errors[1]:.2f}, {errors[1] / errors[2]:.2f}")
        assert all(r["settle"] < 1e-8 for r in rows.values())  # at rest when measured
        assert errors[0] / errors[1] > 3.3 and errors[1] / errors[2] > 3.5
        assert errors[2] < 0.025
        # the rigid first edge ("edge", the model before) is worse at every resolution
        edge = {r["segments"]: r["error"] for r in accuracy["rows"] if r["case"] == f"curl {axis} edge"}
        print(f"curl {axis} edge: {[f'{edge[n]:.4f}' for n in (25, 50, 100)]}")
        assert all(edge[n] > rows[n]["error"] for n in (25, 50, 100))


def test_accuracy_writes_json_and_a_non_blank_png(accuracy):
    saved = json.loads(open(accuracy["json"]).read())
    assert len(saved["rows"]) == len(accuracy["rows"]) == 3 + 1 + 1 + 1 + 2 * 2 + 2 * 2 * 3  # + curl rows
    image = read_png(accuracy["png"])
    assert image is not None and image.shape == (600, 960, 3)
    assert image.astype(float).var() > 0
    assert all(r["wall_s"] > 0 and r["steps"] > 0 and r["substeps"] >= 1 for r in accuracy["rows"])


def test_stability_matrix_outcomes(stability):
    rows = stability["cases"]
    assert stability["failures"] == 0, [r["outcome"] for r in rows if r["status"] == "FAIL"]
    status = {r["status"] for r in rows}
    assert {"stable", "substepped", "refused"} <= status
    for r in rows:
        if r["status"] == "substepped":
            assert r["substeps"] > 1 and r["dt"] / r["substeps"] <= r["stable_dt"]
        if r["status"] != "refused":
            assert r["measured_residual"] < reports.CONSTRAINT_FAIL
    # undamped, undriven, quasistatic twist: the projection may only remove energy
    quasi = [r for r in rows if r["conservative"] and r["twist"] == "quasistatic" and r["status"] != "refused"]
    assert quasi and all(r["energy_max_rise"] < 1e-6 for r in quasi)


def test_strict_refusal_names_the_bound(stability):
    row = next(r for r in stability["cases"] if r["strict"] and r["status"] == "refused")
    case = next(c for c in reports.stability_cases(quick=True) if c.name == row["name"])
    groom, material, _ = reports._stability_scene(case)
    bound = stable_time_step(groom, [material] * groom.n_strands, case.drag)
    assert row["outcome"].startswith("refused: ") and "stability bound" in row["outcome"]
    assert f"{bound:.3g} s" in row["outcome"] and bound < case.dt


def test_gale_wind_keeps_edges_inextensible():
    # a 30 m/s gale at dt 1 ms: the wind bound (an air particle crosses at most part of a
    # segment per substep) substeps it; the row's own check measures the edge strain
    case = next(c for c in reports.stability_cases(quick=True) if c.wind)
    row = reports.run_stability_case(case, 0.1)
    assert row["status"] in ("stable", "substepped"), row["outcome"]


def test_undocumented_exceptions_are_failures(monkeypatch, tmp_path):
    def broken(case):
        raise RuntimeError("boom")
    monkeypatch.setattr(reports, "_stability_scene", broken)
    monkeypatch.setattr(reports, "stability_cases", lambda quick: [reports.StabilityCase(name="broken")])
    row = reports.run_stability_case(reports.StabilityCase(name="broken"), 0.01)
    assert row["status"] == "FAIL" and "RuntimeError: boom" in row["outcome"]
    assert reports.main(["stability", "--quick", "--precision", "float64", "--out", str(tmp_path)]) == 1


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
