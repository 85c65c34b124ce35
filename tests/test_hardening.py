"""Regression tests for the defects of issue 15 (hardening): each failed on the code before its fix."""

import json
import shutil
import struct
import subprocess
import sys
import textwrap
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.hair.hairfile import HairFileError
from taichi_hair.app.runner import Shot
from taichi_hair.solver.step.plan import STALL_BELOW


# ---- 1. a root exactly on a head's surface keeps that head as a collider ----------------------

@pytest.mark.parametrize("head", [th.Head.sphere(radius=0.1), th.Head.ellipsoid(radii=(0.1, 0.1, 0.1))],
                         ids=["sphere", "ellipsoid"])
@pytest.mark.parametrize("root", ["clamped", "pinned"])
def test_root_on_the_surface_keeps_the_head_collider(head, root):
    groom = th.Groom.straight(roots=[[0, 0, 0.1]], directions=[[1, 0, 0]], length=0.3, n_nodes=31)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no collider is skipped, so nothing to warn about
        sim = th.Simulator.from_scene(th.Scene(groom=groom, head=head), dt=1e-3, root=root)
    sim.run(0.5, progress=False)
    free = sim.positions()[0, 2 if root == "clamped" else 1:]
    depth = np.linalg.norm(free, axis=1) - 0.1
    # before the fix: 11 (clamped) / 13 (pinned) nodes inside, 1.5 / 3.5 cm deep after 1 s
    assert np.count_nonzero(depth < 0) == 0, f"{np.count_nonzero(depth < 0)} nodes inside, deepest {depth.min():.3g} m"
    # and out to the margin, less what the length-only iterations that finish a projection in
    # contact may move a node: STALL_BELOW x its edge (1e-5 m here; measured 4e-8 / 2.1e-7 m)
    assert depth.min() > 0.002 - STALL_BELOW * 0.01
    assert sim.skipped_colliders == []


def test_root_deep_inside_a_collider_skips_it_with_a_warning():
    """A groom rooted 5 mm inside a neck capsule (margin 2 mm) does not collide with the capsule,
    and says so; a root 1 mm inside (within the margin) keeps it."""
    groom = th.Groom.straight(roots=[[0, 0, 0.045], [0.02, 0, 0.045]], directions=[[1, 0, 0], [1, 0, 0]],
                              length=0.1, n_nodes=11)
    neck = th.Capsule(p0=(0, 0, 0), p1=(0, 0, -0.2), radius=0.05, margin=0.002)
    with pytest.warns(RuntimeWarning, match=r"inside Capsule \(colliders\[0\]\) by more than its margin"):
        sim = th.Simulator(groom, th.Material(), colliders=(neck,), gravity=(0, 0, 0))
    assert sim.skipped_colliders == [(0, 0)]


# ---- 2. a tiny .hair header cannot force a huge allocation ---------------------------------

def _tiny_hair(path, n_strands, n_points=1, flags=2, default_segments=0, **defaults):
    """A 128-byte header (fields packed one by one) and the points it promises, nothing more."""
    thickness = defaults.get("thickness", 1.0)
    header = (b"HAIR" + struct.pack("<IIII", n_strands, n_points, flags, default_segments)
              + struct.pack("<ff3f", thickness, 0.0, 1.0, 1.0, 1.0) + b"\0" * 88)
    body = b"".join(struct.pack("<3f", *p) for p in defaults.get("points", [(0, 0, 0)] * n_points))
    path.write_bytes(header + body)
    return path


@pytest.mark.parametrize("n_strands, flags, segments", [
    (2**24, 2, 0),            # no segments array: the strand count alone sized an array
    (2**31, 2, 0),            # (2^28: 4.2 s and 1.7 GB before this fix; 2^31: MemoryError)
    (2**32 - 1, 2, 2**32 - 1),
    (2**32 - 1, 3, 0),        # a segments array the file cannot hold
])
def test_absurd_header_counts_fail_fast_without_allocating(tmp_path, n_strands, flags, segments):
    path = _tiny_hair(tmp_path / "tiny.hair", n_strands, flags=flags, default_segments=segments)
    tracemalloc.start()
    start = time.perf_counter()
    with pytest.raises(HairFileError) as info:
        th.read_hair(path)
    seconds = time.perf_counter() - start
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert str(path) in str(info.value)
    assert peak < 1e6, f"read_hair allocated {peak / 1e6:.0f} MB for a {path.stat().st_size}-byte file"
    assert seconds < 0.5


@pytest.mark.parametrize("reader", [th.read_hair, th.read_obj_polylines])
def test_readers_refuse_devices(reader):
    with pytest.raises(HairFileError, match="/dev/zero: not a regular file"):
        reader("/dev/zero")


# ---- 8. hair files: non-finite defaults, absurd coordinates, write errors -------------------

def test_hair_file_with_nan_default_thickness_is_rejected(tmp_path):
    path = _tiny_hair(tmp_path / "nan.hair", 1, n_points=2, default_segments=1, thickness=float("nan"))
    with pytest.raises(HairFileError, match="default thickness, transparency and colour must be finite"):
        th.read_hair(path)
    hair = th.HairFile.from_strands([np.zeros((2, 3))], default_thickness=float("nan"))
    with pytest.raises(HairFileError, match="must be finite"):
        th.write_hair(tmp_path / "out.hair", hair)


def test_absurd_coordinates_are_rejected(tmp_path):
    obj = tmp_path / "far.obj"
    obj.write_text("v 0 0 0\nv 1e300 0 0\nl 1 2\n")
    with pytest.raises(HairFileError, match=r"line 2: vertex coordinates must lie within \+-1e\+06"):
        th.read_obj_polylines(obj)
    path = _tiny_hair(tmp_path / "far.hair", 1, n_points=2, default_segments=1,
                      points=[(0, 0, 0), (3e38, 0, 0)])
    with pytest.raises(HairFileError, match="point 1 has coordinates"):
        th.read_hair(path)


@pytest.mark.parametrize("write", [th.write_hair, th.write_obj_polylines])
def test_writers_wrap_os_errors_naming_the_path(tmp_path, write):
    path = tmp_path / "no such directory" / "out.file"
    with pytest.raises(HairFileError, match="no such directory/out.file: cannot write the file"):
        write(path, [np.zeros((2, 3)), np.ones((3, 3))])


# ---- 3. --json prints JSON only; 8. compiling touch tools warns of no division by zero -------

def _run(args, timeout=300, **kwargs):
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, **kwargs)


def test_bench_json_stdout_is_one_json_document():
    done = _run([sys.executable, "-m", "taichi_hair", "bench", "--json", "--strands", "1", "--repeats", "1",
                 "--stage-steps", "1", "--head-guides", "0", "--dense", "0"],
                timeout=900)  # both integrators compile from a cold cache: over 300 s on CI's 2 cores
    assert done.returncode == 0, done.stderr[-2000:]
    results = json.loads(done.stdout)  # before: "[Taichi] version ..." first, not JSON
    assert results[0]["precision"] == "float32"
    assert "[Taichi]" in done.stderr


def test_library_keeps_stdout_for_the_caller():
    script = ("import taichi_hair as th; th.init(); import taichi.lang.shell as shell; "
              "print('data', shell.pybuf_enabled)")
    done = _run([sys.executable, "-c", script])
    assert done.returncode == 0, done.stderr[-2000:]
    # the banner went to stderr without Taichi mistaking a replaced stdout for a notebook's
    assert done.stdout == "data False\n" and "[Taichi] version" in done.stderr


def test_touch_tools_compile_without_division_warnings():
    script = textwrap.dedent("""
        import taichi_hair as th
        th.init(arch="cpu", precision="float64", offline_cache=False)  # compile for real
        groom = th.Groom.straight(roots=[[0, 0, 0]], directions=[[0, 0, -1]], length=0.1, n_nodes=11)
        tools = (th.Grab(path=lambda t: (0.0, 0.02, -0.05)), th.Hand(path=lambda t: (0.0, -0.05, -0.05)))
        sim = th.Simulator(groom, th.Material(), dt=2e-4, touch=tools)
        sim.step(2)
        print(sim.time)
        """)
    done = _run([sys.executable, "-c", script])
    assert done.returncode == 0, done.stderr[-2000:]
    assert float(done.stdout.split()[-1]) == pytest.approx(4e-4)
    # before: 12 "Potential division by 0" warnings (the hands reused the ellipsoid branch with zero radii)
    assert done.stderr.count("division by 0") == 0, done.stderr[-3000:]


# ---- 4. automatic substepping has a ceiling ------------------------------------------------

def _hair(n_nodes=21):
    return th.Groom.straight(roots=[[0, 0, 0]], directions=[[1, 0, 0]], length=0.2, n_nodes=n_nodes)


def test_substeps_past_max_substeps_are_refused_naming_the_cause():
    start = time.perf_counter()
    # before: 153,033,600 substeps per step after one warning (an apparent hang)
    with pytest.raises(ValueError, match=r"153033600 substeps .* more than max_substeps = 1000; the "
                                         r"stability bound is set by drag = 1e\+06 N s/m per metre"):
        th.Simulator(_hair(), th.Material(), drag=1e6)
    assert time.perf_counter() - start < 5.0
    grab = th.Grab(path=lambda t: (0.1, 0.0, 0.0), stiffness=1e6)
    with pytest.raises(ValueError, match=r"set by touch\[0\]\.stiffness = 1e\+06 N/m"):
        th.Simulator(_hair(), th.Material(), touch=(grab,))
    with pytest.raises(ValueError, match=r"4386 substeps .* set by the material's bending stiffness"):
        th.Simulator(_hair(101), th.Material(youngs_modulus=1e13, radius=2e-4))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the substepping notice
        sim = th.Simulator(_hair(), th.Material(), drag=100.0, max_substeps=20000)
    assert 1000 < sim.substeps <= 20000 and sim.dt / sim.substeps <= sim.stable_dt


@pytest.mark.parametrize("value", [0, -3, 2.5, True, "10"])
def test_max_substeps_must_be_a_positive_integer(value):
    with pytest.raises(ValueError, match=f"max_substeps must be an integer >= 1, got {value!r}"):
        th.Simulator(_hair(), th.Material(), max_substeps=value)


# ---- 5. one atomic checkpoint; 6. frames land on exact times -------------------------------

ROOT = Path(__file__).resolve().parents[1]
CANTILEVER = str(ROOT / "scenes" / "cantilever.py")  # 24 fps, dt 1 ms


def _taichi_hair(*args, cwd):
    return _run([sys.executable, "-m", "taichi_hair", *args], cwd=cwd)


def _render(out, frames, *extra):
    return _taichi_hair("run", CANTILEVER, "--out", str(out), "--frames", str(frames), "--width", "32",
                        "--height", "24", "--no-progress", *extra, cwd=out.parent)


@pytest.fixture(scope="module")
def three_frames(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "out"
    done = _render(out, 3)
    assert done.returncode == 0, done.stderr[-2000:]
    return out


def _copy(src, tmp_path):
    dst = tmp_path / "out"
    shutil.copytree(src, dst)
    return dst


def test_resume_trusts_the_state_file_not_a_stale_progress_file(three_frames, tmp_path):
    """A kill between the state file and progress.json left progress.json one frame behind: the
    resume continues from the state file's own frame count, redoing nothing, and the frames
    land on k / fps (before: resumed from 2, final time 0.21 s instead of 4/24 s)."""
    out = _copy(three_frames, tmp_path)
    (out / "progress.json").write_text(json.dumps({"frames_done": 2, "time": 2 / 24}))
    done = _render(out, 4, "--resume")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "4 frames (resumed from 3)" in done.stdout
    with np.load(out / "state.npz") as state:
        assert abs(float(state["time"]) - 4 / 24) < 1e-12
        assert int(state["extra_frames_done"]) == 4


def test_resume_refuses_an_inconsistent_or_damaged_checkpoint(three_frames, tmp_path):
    out = _copy(three_frames, tmp_path)
    with np.load(out / "state.npz") as state:
        arrays = {k: state[k] for k in state.files}
    np.savez(out / "state.npz", **{**arrays, "extra_frames_done": np.array(2)})  # time says 3 frames
    done = _render(out, 4, "--resume")
    assert done.returncode == 2
    assert f"{out / 'state.npz'}: inconsistent checkpoint: 2 frames done" in done.stderr
    (out / "state.npz").write_bytes((out / "state.npz").read_bytes()[:300])  # truncated
    done = _render(out, 4, "--resume")
    assert done.returncode == 2 and f"{out / 'state.npz'}: not a readable checkpoint" in done.stderr
    assert "Traceback" not in done.stderr


def test_shot_fits_dt_to_the_frame_and_refuses_dt_past_a_frame():
    shot = Shot(fps=24, dt=1e-3)
    assert shot.steps_per_frame == 42 and shot.frame_dt <= shot.dt
    assert abs(shot.steps_per_frame * shot.frame_dt - 1 / 24) < 1e-15  # before: 42 ms per 41.67 ms frame
    assert Shot(fps=25, dt=1e-3).steps_per_frame == 40 and Shot(fps=24, dt=1 / 24).steps_per_frame == 1
    with pytest.raises(ValueError, match=r"dt must be at most one frame, 1/fps = 0.04167 s at fps = 24, got 0.5"):
        Shot(fps=24, dt=0.5)


# ---- 7. CLI: every user error is one line naming the file or parameter, exit code 2 ----------

def _error_lines(stderr):
    return [line for line in stderr.splitlines() if "error:" in line]


@pytest.mark.parametrize("case", ["unwritable out", "build returns an int", "script raises"])
def test_cli_user_errors_are_one_line_naming_the_file(tmp_path, case):
    scene, out = CANTILEVER, tmp_path / "out"
    if case == "unwritable out":
        (tmp_path / "blocker").write_text("a file, not a folder")
        out = tmp_path / "blocker" / "out"
        expected = f"{out}: cannot create the output folder (--out)"
    elif case == "build returns an int":
        scene = tmp_path / "scene.py"
        scene.write_text("def build():\n    return 42\n")
        expected = f"scene script {scene}: build() must return a taichi_hair Scene, got int"
    else:
        scene = tmp_path / "scene.py"
        scene.write_text("import taichi_hair as th\ndef build():\n    return th.Groom.straight(length=-1)\n"
                         "raise KeyError('typo')\n")
        expected = f"scene script {scene} failed to load: KeyError"
    done = _taichi_hair("run", str(scene), "--out", str(out), "--no-progress", cwd=tmp_path)
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    lines = _error_lines(done.stderr)
    assert len(lines) == 1 and expected in lines[0], done.stderr[-2000:]
    debug = _taichi_hair("run", str(scene), "--out", str(out), "--no-progress", "--debug", cwd=tmp_path)
    assert debug.returncode != 0 and "Traceback" in debug.stderr


# ---- 8. API inputs: folds, numpy scalars, NaN forces ---------------------------------------

def test_set_positions_rejects_coincident_nodes_and_folds():
    sim = th.Simulator(_hair(6), th.Material(), gravity=(0, 0, 0))
    x = sim.positions()
    coincident = x.copy()
    coincident[0, 3] = coincident[0, 2]
    with pytest.raises(ValueError, match=r"positions: strand 0 segment 2 \(nodes 2-3\) has length 0 m"):
        sim.set_positions(coincident)
    folded = x.copy()
    folded[0, 4] = folded[0, 2]  # node 3 turns back by 180 degrees
    with pytest.raises(ValueError, match=r"positions: strand 0 turns by 180.0 degrees at node 3; turning "
                                         r"angles must be <= 170 degrees"):
        sim.set_positions(folded)
    np.testing.assert_array_equal(sim.positions(), x)  # refused, not half-applied
    assert np.isfinite(sim.elastic_energy())  # before: the fold was accepted and the energy was NaN


def test_numpy_scalars_are_accepted_wherever_numbers_are():
    f32, i64 = np.float32, np.int64
    material = th.Material(youngs_modulus=f32(3e9), radius=f32(4e-5), ellipticity=np.float64(1.2))
    assert type(material.radius) is float and material.radius == pytest.approx(4e-5, rel=1e-6)
    groom = th.Groom.straight(length=f32(0.2), n_nodes=i64(11))
    head = th.Head.sphere(radius=f32(0.05), centre=(0, 0, 0.1), margin=f32(0.002))
    sim = th.Simulator(groom, material, dt=f32(1e-3), drag=f32(1e-4), projection_iterations=i64(50),
                       max_substeps=i64(100), colliders=head.colliders)
    sim.step(i64(2))
    sim.run(f32(0.002), progress=False)
    assert sim.steps_taken == 4 and sim.dt == pytest.approx(1e-3)
    assert Shot(dt=f32(1e-3), fps=24).steps_per_frame == 42
    for bad in (True, "1e-3", None):  # still refused: not real numbers
        with pytest.raises(ValueError, match="dt must be > 0 and < 1 s"):
            th.Simulator(groom, material, dt=bad)


def test_user_forces_with_nan_say_what_is_wrong():
    sim = th.Simulator(_hair(11), th.Material())
    force = np.zeros((1, 11, 3))
    force[0, 7, 2] = np.nan
    with pytest.raises(ValueError, match=r"user forces must be finite; strand 0 node 7 is \[ 0.  0. nan\] N"):
        sim.set_user_forces(force)
    with pytest.raises(ValueError, match=r"must have shape \[1, 11, 3\] \(strands, nodes, xyz\) N, got \[11, 3\]"):
        sim.set_user_forces(force[0])


# ---- 9. projection stalls are reported as what they are ------------------------------------

def test_projection_stalls_in_contact_are_finished_and_rounding_stalls_reported_with_their_bound():
    """float64. In contact: hair combed round a sphere and pressed on it by a 50 m/s wind (DER
    strain measure), where contacts pushing back against the edge lengths stalled the
    alternation (546 stalls in 100 steps, residual 1.0e-3 against tolerance 1e-6, before the
    length-only iterations that finish a projection in contact): no stall, every step within
    the tolerance (measured 1.0e-6). Without contacts, a tolerance below float64's rounding
    floor (1e-15; the floor is about 1e-14) stalls every step, and stats() says where a stall
    stops (projection_stall_below) with the residual under it, no iteration cap hit."""
    angle = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    roots = 0.1 * np.stack([0.5 * np.cos(angle), 0.5 * np.sin(angle), np.full(8, 0.75 ** 0.5)], axis=1)
    combed = np.cross(roots, [0.0, 0.0, 1.0]) + 0.05 * roots  # along the head, nearly tangent
    groom = th.Groom.straight(roots=roots, directions=combed, length=0.25, n_nodes=26)
    scene = th.Scene(groom=groom, head=th.Head.sphere(radius=0.1), wind=th.Wind(velocity=(50.0, 0, 0)),
                     drag=5e-4, strain="der")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sim = th.Simulator.from_scene(scene, dt=1e-3)
    sim.step(100)
    stats = sim.stats()
    assert stats["projection_stalls"] == 0 and stats["projection_cap_hits"] == 0
    assert stats["projection_residual_max"] <= stats["projection_tol"]

    strand = th.Groom.straight(roots=[[0, 0, 0]], directions=[[1, 0, 0]], length=0.3, n_nodes=31)
    sim = th.Simulator.from_scene(th.Scene(groom=strand), dt=1e-3, projection_tol=1e-15)
    sim.step(100)
    stats = sim.stats()
    assert stats["projection_stalls"] > 50 and stats["projection_cap_hits"] == 0
    assert stats["projection_tol"] < stats["projection_residual_max"] <= stats["projection_stall_below"] == STALL_BELOW


def test_float32_fine_hair_keeps_its_energy(tmp_path):
    """Undamped float32 strands with tiny substeps gained energy from rounding read back as
    velocity ((x - x_prev) / h) and from the projection's loose float32 tolerance: 1 mm segments
    (61 substeps) +21 % of the energy in play in 0.2 s, a tight elliptic curl under Kmoch's rule
    (196 substeps) +6.6 %; and from the rounding of float32 positions themselves: E 1e10 at 1 mm
    segments (222 substeps of a 2 ms step) +2.0 %. Run in float32 (a worker process), judged by
    the stability report's own rule (ENERGY_RISE_FAIL)."""
    from taichi_hair.app import stability_cases, stability_report
    cases = [stability_cases.StabilityCase(name="1 mm segments", segment=0.001),
             stability_cases.StabilityCase(name="tight elliptic curl", curl_radius=0.005, segment=0.0025,
                                   ellipticity=4.0, twist="kmoch"),
             stability_cases.StabilityCase(name="stiff, 1 mm segments, 2 ms", youngs_modulus=1e10, segment=0.001,
                                   dt=2e-3)]
    result = stability_report.stability_report(False, tmp_path, cases=cases, duration=0.2)
    for row in result["cases"]:
        assert row["precision"] == "float32"
        assert row["status"] == "substepped", row["outcome"]
        assert row["energy_max_rise"] < stability_report.ENERGY_RISE_FAIL, row


def test_float32_hair_far_from_the_origin_moves_as_at_the_origin():
    """float32 positions 100 m from the origin carry rounding of 8e-6 m, 8e-4 of a 1 cm edge:
    the projection could not resolve the lengths there and stiff modes heat. Positions are
    float64 (arrays.Points2): the same swinging strand at the origin and 100 m away follows the
    same path to float32's precision of the motion itself, and holds its lengths to 1e-6."""
    script = textwrap.dedent("""
        import json, numpy as np, taichi_hair as th
        th.init(arch="cpu", precision="float32")
        tips, residuals = [], []
        for offset in (0.0, 100.0):
            groom = th.Groom.straight(roots=[[offset, 0.0, 0.0]], directions=[[1.0, 0.0, 0.0]],
                                      length=0.2, n_nodes=21)
            sim = th.Simulator(groom, th.Material(), dt=1e-3)
            sim.step(200)
            x = sim.positions()[0]
            tips.append((x[-1] - [offset, 0.0, 0.0]).tolist())
            lengths = np.linalg.norm(np.diff(x, axis=0), axis=1)
            residuals.append(float(np.abs(lengths ** 2 / 0.01 ** 2 - 1).max()))
            assert sim.stats()["projection_tol"] == 1e-6
        print(json.dumps({"tips": tips, "residuals": residuals}))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    near, far = np.array(result["tips"])
    print(f"\nfloat32 tip at the origin {near}, 100 m away {far} (relative), residuals {result['residuals']}")
    assert np.linalg.norm(near - far) < 1e-4 * 0.2
    assert max(result["residuals"]) < 2e-6
