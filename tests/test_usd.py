"""USD in and out: round trips through our writer and through files built with pxr directly
(non-default metersPerUnit, Y up, a transformed parent, cubic bases), validation by USD's own
validators, pxr reading our files, the runner's --usd output surviving a kill and resume, and
bad input refused with HairFileError naming file and prim."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import kill_run_after
from helpers import run_cli as run

pytest.importorskip("pxr", reason="usd-core is not installed: pip install 'taichi_hair[usd]'")
from pxr import Gf, Usd, UsdGeom, UsdValidation, Vt  # noqa: E402

import taichi_hair as th  # noqa: E402
from taichi_hair.hair.usd import UsdCurvesWriter  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
F32 = 2e-7  # float32 rounding of coordinates below 1 m (relative 6e-8) with margin


def random_strands(rng, counts, scale=0.05):
    return [np.cumsum(rng.normal(size=(n, 3)) * scale / 4, axis=0) + rng.normal(size=3) * scale for n in counts]


@pytest.mark.parametrize("suffix", [".usdc", ".usda"])
def test_linear_round_trip_through_our_writer(tmp_path, suffix):
    rng = np.random.default_rng(0)
    counts = [3, 7, 12, 5]
    frames = [random_strands(rng, counts) for _ in range(3)]
    widths = rng.uniform(5e-5, 2e-4, sum(counts))
    colours = rng.uniform(0, 1, (4, 3))
    path = th.write_usd_curves(tmp_path / f"a{suffix}", frames, times=[0.5, 1.0, 1.5], fps=30,
                               widths=widths, colours=colours)
    for k, frame in enumerate(frames):
        back = th.read_usd_curves(path, time=(k + 1) * 15)
        assert list(back.groom.node_counts) == counts
        for s, x in enumerate(frame):
            assert np.abs(back.groom.strand(s) - x).max() < F32
        assert np.abs(np.concatenate(back.widths) - widths).max() < 1e-7 * widths.max()
        assert np.abs(back.colors - colours).max() < 1e-7
        assert back.prims == ["/Hair/Strands"] * 4 and list(back.curve_index) == [0, 1, 2, 3]


def transformed_stage(path, kind="linear", basis="bezier", wrap="nonperiodic", counts=(4, 7)):
    """A Y-up stage in centimetres: /World (translate, rotate, scale 2) / Groom (BasisCurves).
    Returns (control points [list of [n, 3]] in prim space, world matrix 4x4 row-vector, widths)."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    world.AddTranslateOp().Set(Gf.Vec3d(1.0, 2.0, -3.0))
    world.AddRotateXYZOp().Set(Gf.Vec3f(10.0, 40.0, -25.0))
    world.AddScaleOp().Set(Gf.Vec3f(2.0, 2.0, 2.0))
    curves = UsdGeom.BasisCurves.Define(stage, "/World/Groom")
    rng = np.random.default_rng(1)
    cvs = random_strands(rng, counts, scale=5.0)
    curves.CreateTypeAttr(kind)
    curves.CreateBasisAttr(basis)
    curves.CreateWrapAttr(wrap)
    curves.CreateCurveVertexCountsAttr(list(counts))
    curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.concatenate(cvs).astype(np.float32)))
    widths = rng.uniform(0.005, 0.02, sum(counts)).astype(np.float32)
    curves.CreateWidthsAttr(Vt.FloatArray.FromNumpy(widths))
    curves.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
    colours = rng.uniform(0, 1, (len(counts), 3)).astype(np.float32)
    curves.CreateDisplayColorPrimvar(UsdGeom.Tokens.uniform).Set(Vt.Vec3fArray.FromNumpy(colours))
    stage.GetRootLayer().Save()
    # the world matrix by hand: scale, then rotate x, y, z (XYZ order), then translate; row vectors
    ax, ay, az = np.radians([10.0, 40.0, -25.0])
    rx = np.array([[1, 0, 0], [0, np.cos(ax), np.sin(ax)], [0, -np.sin(ax), np.cos(ax)]])
    ry = np.array([[np.cos(ay), 0, -np.sin(ay)], [0, 1, 0], [np.sin(ay), 0, np.cos(ay)]])
    rz = np.array([[np.cos(az), np.sin(az), 0], [-np.sin(az), np.cos(az), 0], [0, 0, 1]])
    m = 2.0 * rx @ ry @ rz
    cvs = [c.astype(np.float32).astype(np.float64) for c in cvs]
    return cvs, m, np.array([1.0, 2.0, -3.0]), widths.astype(np.float64), colours


def to_metres_z_up(p, m, t):
    y_up = p @ m + t
    return 0.01 * np.stack([y_up[:, 0], -y_up[:, 2], y_up[:, 1]], axis=1)


def test_pxr_built_linear_y_up_centimetres_transformed(tmp_path):
    cvs, m, t, widths, colours = transformed_stage(tmp_path / "lin.usda")
    back = th.read_usd_curves(tmp_path / "lin.usda")
    assert list(back.groom.node_counts) == [4, 7]
    for s, c in enumerate(cvs):
        assert np.abs(back.groom.strand(s) - to_metres_z_up(c, m, t)).max() < 1e-12
    assert np.abs(np.concatenate(back.widths) - widths * 0.01 * 2.0).max() < 1e-12  # cm, scale 2
    assert np.abs(back.colors - colours).max() == 0
    assert back.prims == ["/World/Groom"] * 2


def bezier_reference(cv, u):
    """de Casteljau on segment floor(u) of a piecewise cubic bezier."""
    k = min(int(u), (len(cv) - 1) // 3 - 1)
    p, t = list(cv[3 * k: 3 * k + 4]), u - k
    while len(p) > 1:
        p = [(1 - t) * a + t * b for a, b in zip(p[:-1], p[1:])]
    return p[0]


@pytest.mark.parametrize("basis, wrap, counts", [("bezier", "nonperiodic", (4, 10)),
                                                 ("bspline", "nonperiodic", (5, 8)),
                                                 ("catmullRom", "nonperiodic", (4, 9)),
                                                 ("catmullRom", "pinned", (3, 6)),
                                                 ("bspline", "pinned", (3, 6))])
def test_pxr_built_cubic_curves(tmp_path, basis, wrap, counts):
    cvs, m, t, widths, _ = transformed_stage(tmp_path / "cubic.usdc", "cubic", basis, wrap, counts)
    back = th.read_usd_curves(tmp_path / "cubic.usdc", n_nodes=None)
    for s, cv in enumerate(cvs):
        x = back.groom.strand(s)
        segments = {"bezier": (len(cv) - 1) // 3, "bspline": len(cv) - 3, "catmullRom": len(cv) - 3}[basis]
        if wrap == "pinned":
            segments += 2
            cv = np.concatenate([2 * cv[:1] - cv[1:2], cv, 2 * cv[-1:] - cv[-2:-1]])
        assert len(x) == 3 * segments + 1  # default: 3 nodes per segment + 1
        for k in range(segments + 1):  # segment ends: closed forms of each basis
            if basis == "bezier":
                expect = cv[3 * k]
            elif basis == "catmullRom":
                expect = cv[k + 1]
            else:
                expect = (cv[k] + 4 * cv[k + 1] + cv[k + 2]) / 6
            assert np.abs(x[3 * k] - to_metres_z_up(expect[None], m, t)[0]).max() < 1e-12
        if basis == "bezier":  # every node against de Casteljau
            ref = np.array([bezier_reference(cv, u) for u in np.linspace(0, segments, len(x))])
            assert np.abs(x - to_metres_z_up(ref, m, t)).max() < 1e-12
        if wrap == "pinned":  # pinned curves pass through both end points
            assert np.abs(x[[0, -1]] - to_metres_z_up(cv[[1, -2]], m, t)).max() < 1e-12
    assert len(th.read_usd_curves(tmp_path / "cubic.usdc", n_nodes=17).groom.strand(0)) == 17


def validation_errors(path):
    context = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    return [e.GetMessage() for e in context.Validate(Usd.Stage.Open(str(path)))
            if e.GetType() == UsdValidation.ValidationErrorType.Error]


def test_written_file_validates_and_pxr_reads_it(tmp_path):
    rng = np.random.default_rng(2)
    head = th.default_head()
    writer = UsdCurvesWriter(tmp_path / "anim.usdc", 24, head_mesh=(head.vertices, head.faces))
    guides = random_strands(rng, [6] * 5)
    dense = np.stack(random_strands(rng, [9] * 40))
    for k in range(4):
        angle = 0.1 * k
        rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
        writer.write_frame(k + 1, {"Guides": [g + 0.01 * k for g in guides], "Dense": dense - 0.01 * k},
                           head_pose=(rot, np.array([0.0, 0.0, 0.01 * k])))
    assert validation_errors(tmp_path / "anim.usdc") == []
    bare = Usd.Stage.CreateNew(str(tmp_path / "bare.usda"))  # the check is not vacuous
    UsdGeom.BasisCurves.Define(bare, "/C")
    bare.Save()
    assert len(validation_errors(tmp_path / "bare.usda")) >= 2

    stage = Usd.Stage.Open(str(tmp_path / "anim.usdc"))
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == 24 and (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1, 4)
    curves = {p.GetName(): UsdGeom.BasisCurves(p) for p in stage.Traverse() if p.IsA(UsdGeom.BasisCurves)}
    assert sorted(curves) == ["Dense", "Guides"]
    assert len(curves["Guides"].GetCurveVertexCountsAttr().Get()) == 5
    assert len(curves["Dense"].GetCurveVertexCountsAttr().Get()) == 40
    for name, n in (("Guides", 30), ("Dense", 360)):
        points = curves[name].GetPointsAttr()
        assert points.GetTimeSamples() == [1.0, 2.0, 3.0, 4.0]
        assert all(len(points.Get(c)) == n for c in (1, 4))
    assert np.abs(np.asarray(curves["Dense"].GetPointsAttr().Get(4)).reshape(40, 9, 3) - (dense - 0.03)).max() < F32
    xform = UsdGeom.Xformable(stage.GetPrimAtPath("/Head"))
    assert xform.GetTimeSamples() == [1.0, 2.0, 3.0, 4.0]
    m = np.asarray(xform.ComputeLocalToWorldTransform(4))
    assert np.allclose(m[3, :3], [0, 0, 0.03]) and np.isclose(m[0, 1], np.sin(0.3))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Head/Mesh"))
    assert len(mesh.GetPointsAttr().Get()) == len(head.vertices)


def test_writer_resume_drops_unconfirmed_frames_and_appends(tmp_path):
    rng = np.random.default_rng(3)
    frames = [random_strands(rng, [5, 6]) for _ in range(6)]
    whole = UsdCurvesWriter(tmp_path / "whole.usda", 24)
    for k, f in enumerate(frames):
        whole.write_frame(k + 1, {"Guides": f})
    broken = UsdCurvesWriter(tmp_path / "broken.usda", 24)
    for k, f in enumerate(frames[:4]):  # frame 4 written, but only 3 checkpointed
        broken.write_frame(k + 1, {"Guides": f})
    resumed = UsdCurvesWriter(tmp_path / "broken.usda", 24, resume=3)
    assert Usd.Stage.Open(resumed.stage.GetRootLayer()).GetPrimAtPath("/Hair/Guides").GetAttribute(
        "points").GetTimeSamples() == [1.0, 2.0, 3.0]
    for k in range(3, 6):
        resumed.write_frame(k + 1, {"Guides": frames[k]})
    assert (tmp_path / "broken.usda").read_text() == (tmp_path / "whole.usda").read_text()
    with pytest.raises(ValueError, match="checkpoint says 9 frames"):
        UsdCurvesWriter(tmp_path / "whole.usda", 24, resume=9)
    with pytest.raises(ValueError, match="missing"):
        UsdCurvesWriter(tmp_path / "nothing.usdc", 24, resume=2)


def time_samples(path):
    stage = Usd.Stage.Open(str(path))
    attr = stage.GetPrimAtPath("/Hair/Guides").GetAttribute("points")
    return {c: np.asarray(attr.Get(c)) for c in attr.GetTimeSamples()}


def test_cli_usd_run_killed_and_resumed_matches_an_uninterrupted_run(tmp_path):
    """The cantilever scene (1 strand, about 20 ms a frame here) stands in for shake_curly (300
    curly guides: seconds per frame); the USD path through the runner is the same."""
    scene = str(ROOT / "scenes" / "cantilever.py")
    args = ["--frames", "60", "--width", "48", "--height", "36", "--usd"]
    whole = tmp_path / "whole"
    result = run([scene, "--out", str(whole), *args], cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "cantilever.usdc" in result.stdout
    assert validation_errors(whole / "cantilever.usdc") == []
    full = time_samples(whole / "cantilever.usdc")
    assert list(full) == [float(k) for k in range(1, 61)]
    assert all(v.shape == (31, 3) for v in full.values())

    broken = tmp_path / "broken"
    done = kill_run_after([scene, "--out", str(broken), *args], broken, tmp_path, 10, timeout=300)
    assert 10 <= done < 60, "the run was not killed mid-way"
    partial = time_samples(broken / "cantilever.usdc")  # a valid file at every moment
    assert len(partial) in (done, done + 1)

    resumed = run([scene, "--out", str(broken), *args, "--resume"], cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resumed from {done}" in resumed.stdout
    again = time_samples(broken / "cantilever.usdc")
    assert list(again) == list(full)
    assert max(np.abs(again[c] - full[c]).max() for c in full) < 1e-6
    # the same file, byte for byte (0.0 m apart, identical bytes when measured)
    assert (broken / "cantilever.usdc").read_bytes() == (whole / "cantilever.usdc").read_bytes()
    assert validation_errors(broken / "cantilever.usdc") == []


def test_cli_shake_curly_12_frames_writes_a_valid_animated_file(tmp_path):
    result = run([str(ROOT / "scenes" / "shake_curly.py"), "--out", str(tmp_path / "out"), "--frames", "12",
                  "--width", "48", "--height", "36", "--dense", "200", "--usd"], cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    path = tmp_path / "out" / "shake_curly.usdc"
    assert validation_errors(path) == []
    stage = Usd.Stage.Open(str(path))
    guides = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Hair/Guides"))
    assert len(guides.GetCurveVertexCountsAttr().Get()) == 300
    assert guides.GetPointsAttr().GetTimeSamples() == [float(k) for k in range(1, 13)]
    first, last = (np.asarray(guides.GetPointsAttr().Get(c)) for c in (1, 12))
    assert first.shape == (300 * 40, 3) and np.abs(last - first).max() > 0.01  # the shake moved the hair
    head = UsdGeom.Xformable(stage.GetPrimAtPath("/Head"))
    assert len(head.GetTimeSamples()) == 12
    assert not np.allclose(head.ComputeLocalToWorldTransform(1), head.ComputeLocalToWorldTransform(12))


def bad_stage(path, points, counts, prim="/Groom"):
    stage = Usd.Stage.CreateNew(str(path))
    if points is not None:
        curves = UsdGeom.BasisCurves.Define(stage, prim)
        curves.CreateTypeAttr("linear")
        curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(points, dtype=np.float32)))
        curves.CreateCurveVertexCountsAttr(counts)
    else:
        UsdGeom.Mesh.Define(stage, "/NotHair")
    stage.Save()
    return path


def test_bad_input_names_file_and_prim(tmp_path):
    good = np.linspace([0, 0, 0], [0, 0, 0.1], 4)
    cases = [
        (bad_stage(tmp_path / "empty.usda", None, None), None, "no BasisCurves prim"),
        (bad_stage(tmp_path / "short.usda", np.concatenate([good, good[:2]]), [4, 2], "/A/B"), "/A/B",
         "curve 1 has 2 points"),
        (bad_stage(tmp_path / "nan.usda", np.where(np.arange(4)[:, None] == 2, np.nan, good), [4], "/N"), "/N",
         "non-finite"),
        (bad_stage(tmp_path / "counts.usda", good, [5], "/C"), "/C", "add up to 5"),
    ]
    for path, prim, problem in cases:
        with pytest.raises(th.HairFileError) as err:
            th.read_usd_curves(path)
        message = str(err.value)
        assert str(path) in message and problem in message and (prim is None or f"prim {prim}" in message)
    with pytest.raises(th.HairFileError, match=r"missing\.usdc: no such file"):
        th.read_usd_curves(tmp_path / "missing.usdc")
    with pytest.raises(th.HairFileError, match=r"prim /NotHair is a Mesh, not BasisCurves"):
        th.read_usd_curves(tmp_path / "empty.usda", prim="/NotHair")
    (tmp_path / "junk.usdc").write_bytes(b"not usd at all")
    with pytest.raises(th.HairFileError, match="junk.usdc: not a readable USD file"):
        th.read_usd_curves(tmp_path / "junk.usdc")


def test_pxr_is_optional(monkeypatch, tmp_path):
    code = "import sys, taichi_hair; print('pxr' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "False"  # the core never imports pxr
    code = ("import sys; sys.modules['pxr'] = None; from taichi_hair.app.cli import main; "
            f"sys.exit(main(['run', {str(ROOT / 'scenes' / 'cantilever.py')!r}, '--out', 'x', '--usd']))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert out.returncode == 2 and "taichi-hair: error: --usd: USD support needs" in out.stderr
    assert "pip install 'taichi_hair[usd]'" in out.stderr
    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(ImportError, match=r"pip install 'taichi_hair\[usd\]'"):
        th.read_usd_curves("anything.usdc")
