"""Runs, sweeps and reports on a Dask cluster (the optional extra `cluster`), and the sweep's
settings. Tests that need dask skip without it (`pytest.importorskip("distributed")`); CI
installs the extra, so they run there.

Parity: a cluster run's PNGs, MP4, state and progress record equal a serial run's byte for byte
(with Taichi single-threaded everywhere, see `one_taichi_thread`);
a sweep's table equals the serial sweep's (wall times apart); the stability and accuracy reports
give the serial rows. Robustness: a real `dask scheduler` and two `dask worker` processes, one
SIGKILLed mid-job: the job finishes with every frame written once; a cluster run killed whole
resumes (frames simulated but not rendered are rendered from their saved guides)."""

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
from helpers import kill_run_after
from helpers import run_cli as run

import taichi_hair as th
from taichi_hair.app import cli
from taichi_hair.app import cluster
from taichi_hair.app import accuracy_report, stability_cases, stability_report
from taichi_hair.app.runner import Shot
from taichi_hair.app.settings import apply_settings, parse_setting, point_name, sweep_points
from taichi_hair.app.sweep import contact_sheet

ROOT = Path(__file__).resolve().parents[1]
TINY = str(ROOT / "tests" / "data" / "tiny_head.py")
CANTILEVER = str(ROOT / "scenes" / "cantilever.py")
FRAMES = 16
RUN_ARGS = ["--frames", str(FRAMES), "--width", "96", "--height", "72", "--dense", "1500"]
try:  # with usd-core, the serial reference and the killed-worker run also write the guides as USD
    import pxr  # noqa: F401
    USD = ["--usd", "usda"]
except ImportError:
    USD = []


def digests(out: Path) -> dict:
    """sha1 of every frame, the MP4, the state and the progress record of a run folder."""
    files = sorted((out / "frames").glob("*")) + sorted(out.glob("*.mp4")) + [out / "state.npz",
                                                                            out / "progress.json"]
    return {str(p.relative_to(out)): hashlib.sha1(p.read_bytes()).hexdigest() for p in files}


@pytest.fixture(scope="module", autouse=True)
def one_taichi_thread():
    """Taichi single-threaded in every process these tests start (runs, local and real workers):
    the renderer sums far fragments and shadow opacity with float atomic adds, whose order
    follows the threads, so multi-threaded runs (serial ones too) can differ in a few pixels."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("TI_CPU_MAX_NUM_THREADS", "1")
        yield


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory):
    """The tiny head scene run serially: the reference every cluster run must equal (its folder)."""
    out = tmp_path_factory.mktemp("serial") / "out"
    result = run([TINY, "--out", str(out), *RUN_ARGS, *USD], cwd=out.parent)
    assert result.returncode == 0, result.stderr[-3000:]
    return out


# ---- settings: no dask needed ---------------------------------------------------------------------
def test_parse_setting_reads_paths_and_values():
    assert parse_setting("material.youngs_modulus=1e9,3e9,1e10") == ("material.youngs_modulus", [1e9, 3e9, 1e10])
    assert parse_setting("shot.frames=48") == ("shot.frames", [48])
    assert parse_setting("twist=quasistatic,kmoch") == ("twist", ["quasistatic", "kmoch"])
    assert parse_setting("wind.velocity=(1,0,0),(2.5,0,0)") == ("wind.velocity", [(1, 0, 0), (2.5, 0, 0)])
    assert parse_setting(" drag = 1e-4 , 'x'") == ("drag", [1e-4, "x"])


@pytest.mark.parametrize("text, named", [
    ("material.youngs_modulus", "PATH=VALUE"), ("=1,2", "not a parameter path"),
    ("material..radius=1", "not a parameter path"), ("drag=1,,2", "drag: empty value"),
    ("drag=", "drag: empty value"), ("wind.velocity=(1,0", "wind.velocity: unbalanced"),
    ("drag=1e-3$", "drag: cannot read the value"), ("shot=3", "must be shot.FIELD"),
])
def test_parse_setting_refuses_bad_input_naming_the_parameter(text, named):
    with pytest.raises(ValueError, match=named.replace("(", r"\(").replace("$", r"\$")):
        parse_setting(text)


def test_apply_settings_sets_fields_and_names_bad_paths_and_values():
    scene = th.Scene(groom=th.Groom.straight(length=0.1, n_nodes=6), material=th.Material(), drag=1e-4)
    shot = Shot(frames=4)
    new_scene, new_shot = apply_settings(scene, shot, {"material.youngs_modulus": 1e9, "shot.frames": 48,
                                                       "scene.drag": 2e-4})
    assert new_scene.material.youngs_modulus == 1e9 and new_scene.drag == 2e-4 and new_shot.frames == 48
    assert scene.material.youngs_modulus != 1e9 and shot.frames == 4  # the originals are untouched
    per_strand = th.Scene(groom=th.Groom.concatenate([scene.groom, scene.groom]),
                          material=[th.Material(), th.Material(radius=5e-5)])
    assert [m.density for m in apply_settings(per_strand, shot, {"material.density": 1000.0})[0].material] == [
        1000.0, 1000.0]
    for point, named in [({"material.stiffness": 1.0}, "material.stiffness: unknown parameter"),
                         ({"shot.fames": 3}, "shot.fames: unknown parameter"),
                         ({"wind.turbulence": 0.5}, "wind.turbulence: this scene has no wind"),
                         ({"material.youngs_modulus": -1.0}, r"material.youngs_modulus=-1.0: youngs_modulus"),
                         ({"shot.frames": 0}, "shot.frames=0: frames must be an integer >= 1")]:
        with pytest.raises(ValueError, match=named):
            apply_settings(scene, shot, point)


def test_sweep_points_are_the_cartesian_product_with_stable_names():
    points = sweep_points([("a.x", [1, 2]), ("shot.frames", [3, 4, 5])])
    assert len(points) == 6 and points[0] == {"a.x": 1, "shot.frames": 3} and points[-1] == {"a.x": 2, "shot.frames": 5}
    assert point_name(points[0]) == "a.x=1_shot.frames=3" and point_name({}) == "base"
    assert point_name({"wind.velocity": (1.0, 0, 0)}) == "wind.velocity=(1,0,0)"
    assert len(point_name({"x": "y" * 500})) <= 120
    with pytest.raises(ValueError, match="drag is given more than once"):
        sweep_points([("drag", [1]), ("drag", [2])])


def test_contact_sheet_tiles_every_run_with_its_label():
    images = [np.full((48, 64, 3), 40 * k, np.uint8) for k in range(5)]
    sheet = contact_sheet(images, [[f"run {k}", f"drag={k}"] for k in range(5)])
    assert sheet.dtype == np.uint8 and sheet.shape == (2 * (48 + 24 + 4) + 4, 3 * (64 + 4) + 4, 3)
    assert (sheet[4:52, 4 + 68:4 + 68 + 64] == 40).all()  # run 1's tile, top row, second column
    assert (sheet[52:72, 4:68] == 0).any()  # its label, drawn in black under the tile


@pytest.mark.parametrize("command", [["run", CANTILEVER, "--out", "OUT", "--workers", "2"],
                                     ["sweep", CANTILEVER, "--out", "OUT", "--scheduler", "tcp://127.0.0.1:1"],
                                     ["report", "stability", "--workers", "2", "--out", "OUT"]])
def test_cluster_options_without_the_extra_name_it(command, monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    assert cli.main([str(tmp_path) if a == "OUT" else a for a in command]) == 2
    err = capsys.readouterr().err
    assert "needs the optional extra 'cluster'" in err and "pip install 'taichi_hair[cluster]'" in err
    assert len(err.strip().splitlines()) == 1


# ---- on a cluster ------------------------------------------------------------------------------------
def test_killed_cluster_run_resumes_like_a_serial_run(serial_run, tmp_path):
    """`run --workers 2` killed whole (client and workers) once it has simulated 6 frames, then
    `--resume --workers 2` (and, on a copy, a serial `--resume`): frames simulated before the
    kill (rendered then, or afterwards from their saved guides) equal the uninterrupted serial
    run's byte for byte; the resumed simulation ends where it does (a resumed state is not
    bit-identical: as for serial runs)."""
    pytest.importorskip("distributed")
    out = tmp_path / "out"
    args = [TINY, "--out", str(out), *RUN_ARGS, "--workers", "2"]
    done = kill_run_after(args, out, tmp_path, 6, timeout=300)
    assert 6 <= done < FRAMES, "the run was not killed mid-way"
    pending = sorted(p.name for p in (out / "guides").glob("*.npz"))
    assert pending, "every simulated frame was already drawn: nothing to resume the drawing of"
    shutil.copytree(out, tmp_path / "serially")  # the same broken run, resumed without a cluster
    resumed = run([*args, "--resume"], cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resumed from {done}" in resumed.stdout
    rendered = FRAMES - done + len(pending)  # the rest, and those simulated but not drawn before
    assert f"({rendered} frames rendered on 2 Dask workers)" in resumed.stdout
    serially = run([TINY, "--out", str(tmp_path / "serially"), *RUN_ARGS, "--resume"], cwd=tmp_path)
    assert serially.returncode == 0, serially.stderr[-3000:]
    reference = digests(serial_run)
    for folder in (out, tmp_path / "serially"):
        ours = digests(folder)
        assert ours.keys() == reference.keys() and not (folder / "guides").exists()
        assert all(ours[f"frames/frame_{k:05d}.png"] == reference[f"frames/frame_{k:05d}.png"] for k in range(done))
        a, b = np.load(folder / "state.npz"), np.load(serial_run / "state.npz")
        assert float(a["time"]) == pytest.approx(float(b["time"])) and np.abs(a["x"] - b["x"]).max() < 1e-5


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(args, log, env):
    return subprocess.Popen([sys.executable, "-m", "dask", *args], stdout=log, stderr=subprocess.STDOUT,
                            env=env, start_new_session=True)


def test_worker_killed_mid_job_on_a_real_scheduler(serial_run, tmp_path):
    distributed = pytest.importorskip("distributed")
    port, env = _free_port(), {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    address, log = f"tcp://127.0.0.1:{port}", open(tmp_path / "dask.log", "w")
    procs = [_start(["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"], log, env)]
    try:
        time.sleep(1.0)
        procs += [_start(["worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                          "--local-directory", str(tmp_path / f"w{k}")], log, env) for k in range(2)]
        with distributed.Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=60)
        out = tmp_path / "out"
        job = subprocess.Popen([sys.executable, "-m", "taichi_hair", "run", TINY, "--out", str(out), *RUN_ARGS,
                                *USD, "--scheduler", address, "--no-progress"], cwd=tmp_path, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.time() + 300
        while len(list((out / "frames").glob("frame_*.png"))) < 2 and time.time() < deadline:
            time.sleep(0.02)
        os.kill(procs[1].pid, signal.SIGKILL)  # one worker, mid-job
        written_at_kill = len(list((out / "frames").glob("frame_*.png")))
        stdout, stderr = job.communicate(timeout=300)
        assert 2 <= written_at_kill < FRAMES, "the worker was not killed mid-job"
        assert job.returncode == 0, stderr[-3000:]
        assert f"({FRAMES} frames rendered on 1 Dask workers)" in stdout  # each frame written once
        names = sorted(p.name for p in (out / "frames").iterdir())
        assert names == [f"frame_{k:05d}.png" for k in range(FRAMES)]  # none missing, no stray .part
        assert all(imageio.imread(out / "frames" / n).shape == (72, 96, 3) for n in names)
        assert imageio.get_reader(out / "tiny_head.mp4").count_frames() == FRAMES
        assert json.loads((out / "progress.json").read_text())["frames_done"] == FRAMES
        assert digests(out) == digests(serial_run)  # byte for byte: PNGs, MP4, state, progress
        if USD:  # the guides' USD file, written by the client as a serial run writes it
            assert (out / "tiny_head.usda").read_bytes() == (serial_run / "tiny_head.usda").read_bytes()
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()
        log.close()


def test_sweep_on_a_cluster_gives_the_serial_table_and_keeps_finished_runs(tmp_path):
    pytest.importorskip("distributed")
    sets = ["--set", "material.youngs_modulus=1e6,3e6", "--set", "drag=0.02,0.05", "--set", "shot.frames=3"]
    args = [CANTILEVER, *sets, "--width", "48", "--height", "36", "--json", "--no-progress"]
    tables = {}
    for name, extra in (("serial", []), ("cluster", ["--workers", "2"])):
        done = subprocess.run([sys.executable, "-m", "taichi_hair", "sweep", *args, "--out", str(tmp_path / name),
                               *extra], capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        tables[name] = json.loads(done.stdout)["rows"]
    assert len(tables["serial"]) == 4 and {r["material.youngs_modulus"] for r in tables["serial"]} == {"1e+06", "3e+06"}
    strip = [[{k: v for k, v in r.items() if k != "wall_s"} for r in t] for t in tables.values()]
    assert strip[0] == strip[1]  # same settings, frames, substeps, max strain, energy per run
    assert tables["serial"][0]["max_strain"] > 0 and tables["serial"][0]["energy_j"] < 0
    stiff = [r for r in tables["serial"] if r["material.youngs_modulus"] == "3e+06" and r["drag"] == "0.02"][0]
    soft = [r for r in tables["serial"] if r["material.youngs_modulus"] == "1e+06" and r["drag"] == "0.02"][0]
    assert stiff["energy_j"] > soft["energy_j"]  # the stiffer beam sags less: less gravity energy lost
    sheet = imageio.imread(tmp_path / "serial" / "contact_sheet.png")
    assert sheet.shape[2] == 3 and sheet.shape[0] > 2 * 36
    summaries = {p: p.stat().st_mtime_ns for p in (tmp_path / "serial" / "runs").glob("*/summary.json")}
    assert len(summaries) == 4
    again = subprocess.run([sys.executable, "-m", "taichi_hair", "sweep", *args[:-1], "--out",
                            str(tmp_path / "serial")], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and "4 runs, 4 already finished" in again.stderr
    assert {p: p.stat().st_mtime_ns for p in summaries} == summaries  # not redone
    bad = subprocess.run([sys.executable, "-m", "taichi_hair", "sweep", CANTILEVER, "--set", "material.stifness=1",
                          "--out", str(tmp_path / "bad")], capture_output=True, text=True, timeout=600)
    assert bad.returncode == 2 and "material.stifness: unknown parameter" in bad.stderr


@pytest.fixture(scope="module")
def client():
    pytest.importorskip("distributed")
    with cluster.connect(workers=2) as c:
        yield c


def _without_wall(rows):
    return [{k: v for k, v in r.items() if k not in ("wall_s", "runs")} for r in rows]


def test_stability_report_on_a_cluster_gives_the_serial_rows(client, tmp_path):
    cases = [c for c in stability_cases.stability_cases(True) if c.precision == "float64"][:3]
    cases.append([c for c in stability_cases.stability_cases(True) if c.precision == "float32"][0])
    serial = stability_report.stability_report(True, tmp_path / "s", cases=cases, duration=0.02)
    spread = stability_report.stability_report(True, tmp_path / "c", cases=cases, duration=0.02, client=client)
    assert _without_wall(spread["cases"]) == _without_wall(serial["cases"])
    assert spread["counts"] == serial["counts"] and spread["precisions"] == serial["precisions"]


def test_accuracy_report_on_a_cluster_gives_the_serial_errors(client, tmp_path):
    sweep = accuracy_report.AccuracySweep(cantilever_segments=(8,), frequency_segments=(8,), helix_segments=(6,),
                                  curl_segments=(), dts=(), twists=("quasistatic",), reference_factor=2, repeats=1)
    serial = accuracy_report.accuracy_report(True, ["float64"], tmp_path / "s", sweep=sweep)
    spread = accuracy_report.accuracy_report(True, ["float64"], tmp_path / "c", sweep=sweep, client=client)
    assert [r["case"] for r in spread["rows"]] == ["cantilever", "frequency", "helix"]
    assert _without_wall(spread["rows"]) == _without_wall(serial["rows"])
    assert spread["helix_reference"]["tip"] == serial["helix_reference"]["tip"]
