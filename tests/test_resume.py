"""A simulator ends in the same state, bit for bit, whatever the grouping of its steps into
`step` calls and launches, and a checkpoint-resumed simulator continues exactly as the
uninterrupted one. What breaks it: on scenes/wind_straight.py a wind time summed from launch to
launch put `sim.step(21); sim.step(21)` 2.4e-9 m from `sim.step(42)`, and a resume that recomputes
the last step's frames in another kernel and reseeds the implicit history ends 2.8e-15 m from the
uninterrupted run."""

import json
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.app.runner import Shot, load_scene_module
from taichi_hair.solver.simulator import Simulator

from helpers import kill_run_after, run_cli

ROOT = Path(__file__).resolve().parents[1]
WIND_STRAIGHT = ROOT / "scenes" / "wind_straight.py"


def _state(sim):
    return {"x": sim.positions(), "v": sim.velocities(), "theta": sim.material_angles(),
            "time": np.array(sim.time)}


def _assert_same(a, b):
    for name in a:
        assert np.array_equal(a[name], b[name]), (
            f"{name} differs by up to {np.nanmax(np.abs(a[name] - b[name])):.3g}")


@pytest.fixture(scope="module")
def wind_scene():
    return load_scene_module(WIND_STRAIGHT).build()


def _wind_sim(scene):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the scene's substepping notice
        return Simulator.from_scene(scene, dt=Shot().frame_dt)


@pytest.mark.slow  # a long run: 15-60 s on 2 cores
def test_step_grouping_does_not_change_wind_straight(wind_scene, tmp_path):
    """sim.step(21) twice == sim.step(42) == a sim stepped 21, checkpointed, and a fresh sim
    loading it stepped 21: gusty turbulent wind, the head's distance field."""
    whole = _wind_sim(wind_scene)
    whole.step(42)
    split = _wind_sim(wind_scene)
    split.step(21)
    split.save_state(tmp_path / "half.npz")
    split.step(21)
    _assert_same(_state(whole), _state(split))
    resumed = _wind_sim(wind_scene)
    resumed.load_state(tmp_path / "half.npz")
    resumed.step(21)
    _assert_same(_state(whole), _state(resumed))


def _moving_scene(integrator):
    """A small scene with every per-call input: a nodding head, gusty wind, hair-hair interaction
    (the staged driver, a launch per step) or the implicit step (its BDF2 history)."""
    groom = th.Groom.from_polylines([np.stack([np.full(9, 0.01 * k), np.zeros(9), -np.linspace(0, 0.12, 9)], 1)
                                     for k in range(4)])
    interaction = th.HairInteraction(cell_size=0.02) if integrator == "explicit" else None
    return th.Scene(groom=groom, motion=th.Nod(amplitude_deg=20.0, frequency_hz=2.0), integrator=integrator,
                    wind=th.Wind(velocity=(2.0, 0.0, 0.0), gust_amplitude=0.5, turbulence=0.5, seed=2),
                    drag=5e-4, hair_interaction=interaction)


@pytest.mark.parametrize("integrator", ["explicit", pytest.param("implicit", marks=pytest.mark.slow)])  # 13 s idle
def test_step_grouping_and_resume_with_head_motion(integrator, tmp_path):
    scene = _moving_scene(integrator)
    whole = Simulator.from_scene(scene, dt=2e-3)
    whole.step(12)
    split = Simulator.from_scene(scene, dt=2e-3)
    for n in (1, 4, 2):
        split.step(n)
    split.save_state(tmp_path / "s.npz")
    split.step(5)
    _assert_same(_state(whole), _state(split))
    resumed = Simulator.from_scene(scene, dt=2e-3)
    resumed.load_state(tmp_path / "s.npz")
    resumed.step(5)
    _assert_same(_state(whole), _state(resumed))


RUN_ARGS = ["--frames", "6", "--width", "64", "--height", "48", "--dense", "0"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("wind_whole") / "out"
    done = run_cli([str(WIND_STRAIGHT), "--out", str(out), *RUN_ARGS], cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    return out


@pytest.mark.slow
@pytest.mark.parametrize("kill_after", [1, 2, 4])
def test_killed_wind_straight_resumes_byte_for_byte(uninterrupted, kill_after, tmp_path):
    """`run scenes/wind_straight.py` SIGKILLed once `kill_after` frames are done, then rerun
    with --resume: state.npz and every PNG equal the uninterrupted run's byte for byte."""
    out = tmp_path / "out"
    args = [str(WIND_STRAIGHT), "--out", str(out), *RUN_ARGS]
    done = kill_run_after(args, out, ROOT, kill_after, timeout=300)
    assert kill_after <= done < 6, f"the run was not killed mid-way ({done} frames done)"
    resumed = run_cli([*args, "--resume"], cwd=ROOT)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resumed from {done}" in resumed.stdout
    assert (out / "state.npz").read_bytes() == (uninterrupted / "state.npz").read_bytes()
    for k in range(6):
        name = f"frames/frame_{k:05d}.png"
        assert (out / name).read_bytes() == (uninterrupted / name).read_bytes(), name
    shutil.rmtree(out)


# ---- the run's checkpoint: one atomic record, frames on exact times --------------------------

CANTILEVER = str(ROOT / "scenes" / "cantilever.py")  # 24 fps, dt 1 ms


def _run(args, timeout=300, **kwargs):
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, **kwargs)


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
    land on k / fps (trusting progress.json resumes from 2 and ends at 0.21 s instead of 4/24 s)."""
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
    assert abs(shot.steps_per_frame * shot.frame_dt - 1 / 24) < 1e-15  # 42 steps of a whole 1 ms: 42 ms per 41.67 ms frame
    assert Shot(fps=25, dt=1e-3).steps_per_frame == 40 and Shot(fps=24, dt=1 / 24).steps_per_frame == 1
    with pytest.raises(ValueError, match=r"dt must be at most one frame, 1/fps = 0.04167 s at fps = 24, got 0.5"):
        Shot(fps=24, dt=0.5)
