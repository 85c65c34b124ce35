"""What a hostile user can do to a run and its inputs: failing disks, damaged checkpoints,
scripts that raise or exit, numbers at the edge of their range (a resumed run is
tests/test_resume.py, the command-line ranges tests/test_cli_fuzz.py)."""

import errno
import json
from pathlib import Path

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.app import implicit_report as implicit_module
from taichi_hair.app.outdir import LOCK_FILE, STATE_FILE, claim_out_dir
from taichi_hair.app.stability_report import stability_report
from taichi_hair.app.run_output import checkpoint
from taichi_hair.app.runner import MAX_IMAGE_PIXELS, SceneScriptError, Shot, load_scene_module
from taichi_hair.app.settings import sweep_points
from taichi_hair.app.cli import main as cli_main


# ---- image size ------------------------------------------------------------------------------
@pytest.mark.parametrize("size", [(100_000, 100_000), (16_384, 16_384), (8192, 8192, 2)])
def test_image_size_is_refused_past_the_limit(size):
    """Before: Shot(width=100000, height=100000) was taken and the run grew to 21 GB."""
    width, height, *ss = size
    with pytest.raises(ValueError, match="width|pixels"):
        Shot(width=width, height=height, supersample=ss[0] if ss else 1)
    assert 8192 * 8192 == MAX_IMAGE_PIXELS
    Shot(width=8192, height=8192)  # at the limit: accepted


# ---- sweep values ------------------------------------------------------------------------------
@pytest.mark.parametrize("values", [[1e-4, 1e-4], [1e-4, 0.0001], [1.0000001, 1.0000002]])
def test_sweep_refuses_values_that_share_a_folder(values):
    """Before: --set drag=1e-4,1e-4 ran twice into runs/drag=0.0001, the second's summary
    replacing the first's."""
    with pytest.raises(ValueError, match="drag lists the value"):
        sweep_points([("drag", values)])
    assert len(sweep_points([("drag", [1e-4, 2e-4])])) == 2


# ---- a report that simulates nothing ---------------------------------------------------------------
@pytest.mark.parametrize("duration", [-1.0, 0.0, float("nan"), float("inf")])
def test_stability_report_refuses_a_duration_that_simulates_nothing(duration, tmp_path):
    """Before: report stability --duration -1 (or nan) said every case was stable."""
    with pytest.raises(ValueError, match="duration"):
        stability_report(True, out_dir=tmp_path, cases=[], duration=duration)


# ---- output folders --------------------------------------------------------------------------
def _finished_run(out, frames):
    out.mkdir(parents=True, exist_ok=True)
    np.savez(out / STATE_FILE, extra_frames_done=frames, extra_fps=24, extra_frame_dt=1 / 24 / 42, time=frames / 24)


def test_resume_with_fewer_frames_than_finished_is_refused(tmp_path):
    """Before: run --frames 3 --resume on a finished 60-frame run overwrote its MP4 with 3 frames."""
    out = tmp_path / "done"
    _finished_run(out, 60)
    (out / "scene.mp4").write_bytes(b"sixty frames")
    with pytest.raises(ValueError, match="--frames 3 is fewer than the 60 frames"):
        claim_out_dir(out, "scene.py", frames=3, resume=True)
    assert (out / "scene.mp4").read_bytes() == b"sixty frames"
    _, lock = claim_out_dir(out, "scene.py", frames=60, resume=True)
    lock.close()


def test_a_second_run_on_one_output_folder_is_refused(tmp_path):
    """Before: two runs on one --out shared temporary names and one died mid-write."""
    out, lock = claim_out_dir(tmp_path / "o", "scene.py")
    assert (out / LOCK_FILE).exists()
    with pytest.raises(ValueError, match="another taichi-hair run is writing to this folder"):
        claim_out_dir(out, "scene.py")
    lock.close()
    _, again = claim_out_dir(out, "scene.py")  # free once the first run ends
    again.close()


# ---- the working directory -------------------------------------------------------------------------
def test_implicit_report_without_scene_rows_does_not_read_the_scene(tmp_path, monkeypatch):
    """Before: report implicit --cantilever-only from outside the repository failed on the
    default scene script (scenes/shake_curly.py), which it does not use."""
    monkeypatch.setattr(implicit_module, "cantilever_rows", lambda log: [{"row": "cantilever"}])
    monkeypatch.setattr(th.runtime, "init", lambda **kw: None)
    monkeypatch.chdir(tmp_path)
    result = implicit_module.implicit_report("scenes/shake_curly.py", scene_rows=False, out_dir=tmp_path / "r",
                                             log=lambda text: None)
    assert result["cantilever"] == [{"row": "cantilever"}]
    assert json.loads((tmp_path / "r" / "implicit.json").read_text())["speed"] == []


# ---- a full disk names its file --------------------------------------------------------------------
def test_a_full_disk_names_the_file(tmp_path):
    """Before: "[Errno 28] No space left on device", no file named."""
    class FullDisk:
        time = 0.0

        def save_state(self, path, extra=None):
            raise OSError(errno.ENOSPC, "No space left on device")
    with pytest.raises(OSError) as err:
        checkpoint(tmp_path, FullDisk(), Shot(), 1)
    assert err.value.filename == str(tmp_path / STATE_FILE) and err.value.errno == errno.ENOSPC


# ---- a scene script that exits --------------------------------------------------------------------
@pytest.mark.parametrize("where", ["module", "build"])
def test_a_scene_script_calling_sys_exit_is_a_one_line_error(where, tmp_path, capsys):
    """Before: a script calling sys.exit(3) ended `run` with rc 3 and no message."""
    script = tmp_path / "exits.py"
    body = "import sys\nPRECISION = 'float64'  # the test process's\n" + ("sys.exit(3)\ndef build():\n    pass\n" if where == "module"
                             else "def build():\n    sys.exit(3)\n")
    script.write_text(body)
    if where == "module":
        with pytest.raises(SceneScriptError, match=r"sys.exit\(3\)"):
            load_scene_module(script)
    assert cli_main(["run", str(script), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "sys.exit(3)" in lines[0] and str(script) in lines[0]


# ---- set_positions refuses a stretched strand -------------------------------------------------------
def test_set_positions_refuses_a_strand_stretched_tenfold():
    """Before: accepted; the next step raised SimulationDiverged."""
    sim = th.Simulator(th.Groom.straight(length=0.1, n_nodes=8), th.Material())
    x = sim.positions()
    stretched = x.copy()
    stretched[0] = x[0, 0] + 10.0 * (x[0] - x[0, 0])
    with pytest.raises(ValueError, match=r"strand 0 is 10 x its rest length"):
        sim.set_positions(stretched)
    sim.set_positions(x[:, :] + np.array([0.0, 0.0, 1e-3]) * (np.arange(8) > 0)[None, :, None])  # a shift: taken


# ---- the groom check is one pass over every strand ---------------------------------------------------
def test_groom_check_names_the_first_bad_strand_among_many():
    """The vectorised check (a loop over strands cost 35 us each) still names the first bad
    strand and its fault, as the loop did."""
    x = np.zeros((1000, 4, 3))
    x[:, :, 2] = -0.01 * np.arange(4)
    x[:, :, 0] = np.arange(1000)[:, None] * 1e-3
    counts = np.full(1000, 4)
    th.Groom(x.copy(), counts)
    bad = x.copy()
    bad[700, 2] = bad[700, 1]  # zero-length segment
    bad[900, 3, 1] = np.nan
    with pytest.raises(ValueError, match=r"strand 700: segment 1 has length 0"):
        th.Groom(bad, counts)
    folded = x.copy()
    folded[42, 3] = folded[42, 1]  # folds straight back
    folded[42, 3, 0] += 1e-4
    with pytest.raises(ValueError, match=r"strand 42: turning angle at node 2"):
        th.Groom(folded, counts)
    short = counts.copy()
    short[5] = 2
    with pytest.raises(ValueError, match=r"strand 5: node count must be in \[3, 4\]"):
        th.Groom(x, short)


# ---- USD ----------------------------------------------------------------------------------------
pxr = pytest.importorskip("pxr", reason="usd-core is not installed: pip install 'taichi_hair[usd]'")


def _stage(path, *, up="Z", widths=None, points=None, scale=None):
    from pxr import Gf, Usd, UsdGeom, Vt
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetMetadata("upAxis", up)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    parent = UsdGeom.Xform.Define(stage, "/World")
    if scale is not None:
        parent.AddScaleOp().Set(Gf.Vec3f(*scale))
    curves = UsdGeom.BasisCurves.Define(stage, "/World/Hair")
    curves.CreateTypeAttr("linear")
    pts = np.array([[0, 0, 0], [0, 0, -0.01], [0, 0, -0.02]] * 2, dtype=np.float64)
    pts[3:, 0] = 0.01
    if points is not None:
        pts = points
    curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    curves.CreateCurveVertexCountsAttr([3, 3])
    if widths is not None:
        curves.CreateWidthsAttr(Vt.FloatArray(list(widths)))
        curves.SetWidthsInterpolation("vertex" if len(widths) == 6 else "constant")
    stage.GetRootLayer().Save()
    return path


@pytest.mark.parametrize("case, match", [
    (dict(widths=[1e-4, 1e-4, float("nan"), 1e-4, 1e-4, 1e-4]), "width nan of curve 0"),
    (dict(widths=[-1.0]), "width -1.0 of curve 0"),
    (dict(widths=[0.0]), "widths must be finite and > 0"),
    (dict(up="X"), "upAxis must be Y or Z, got 'X'"),
    (dict(points=np.array([[0, 0, 0], [0, 0, -1e30], [0, 0, -2e30]] * 2)), "coordinates must lie within"),
    (dict(scale=(1e30, 1e30, 1e30)), "coordinates must lie within"),
])
def test_usd_values_out_of_range_are_refused(case, match, tmp_path):
    """Before: NaN and negative widths, coordinates of 1e30 m and upAxis "X" (read as Z) were taken."""
    path = _stage(tmp_path / "bad.usda", **case)
    with pytest.raises(th.HairFileError, match=match):
        th.read_usd_curves(path)


def test_usd_good_stage_still_reads(tmp_path):
    curves = th.read_usd_curves(_stage(tmp_path / "good.usda", widths=[1e-4], scale=(2, 2, 2)))
    assert curves.groom.n_strands == 2 and np.allclose(np.concatenate(curves.widths), 2e-4)


def test_usd_target_that_is_a_folder_is_refused_and_leaves_no_temporary(tmp_path):
    """Before: run --usd with a folder at <out>/<scene>.usdc failed naming the temporary file and
    left it behind."""
    from taichi_hair.hair.usd import UsdCurvesWriter
    out = tmp_path / "run"
    target = out / "scene.usdc"
    target.mkdir(parents=True)
    with pytest.raises(ValueError, match="--usd: .*scene.usdc is a folder"):
        claim_out_dir(out, "scene.py", usd="usdc")
    writer = UsdCurvesWriter(target, 24)
    writer.define("Guides", [3], widths=1e-4)
    with pytest.raises(th.HairFileError, match="a folder of that name is in the way"):
        writer.write_frame(1, {"Guides": [np.array([[0, 0, 0], [0, 0, -0.01], [0, 0, -0.02]])]})
    assert not [p.name for p in out.iterdir() if ".tmp" in p.name]
    assert not Path(target).is_file()
