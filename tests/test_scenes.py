"""Scenes end to end: every scene script runs from the command line, and a run killed mid-way
resumes from its checkpoint without losing a frame and ends where an uninterrupted run ends."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENES = sorted(p.name for p in (ROOT / "scenes").glob("*.py"))


def run(args, cwd, **kwargs):
    return subprocess.run([sys.executable, "-m", "taichi_hair", "run", *args, "--no-progress"],
                          cwd=cwd, capture_output=True, text=True, timeout=900, **kwargs)


@pytest.mark.parametrize("scene", SCENES)
def test_scene_runs_a_few_frames(scene, tmp_path):
    if scene == "usd_groom.py":
        pytest.importorskip("pxr", reason="usd-core is not installed: pip install 'taichi_hair[usd]'")
    out = tmp_path / "out"
    result = run([str(ROOT / "scenes" / scene), "--out", str(out), "--frames", "2", "--width", "96",
                  "--height", "72", "--dense", "300"], cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    frames = sorted((out / "frames").glob("frame_*.png"))
    assert len(frames) == 2
    image = imageio.imread(frames[-1])
    assert image.shape == (72, 96, 3) and image.std() > 1.0  # a picture, not a blank
    video = imageio.get_reader(out / f"{Path(scene).stem}.mp4")
    assert video.count_frames() == 2
    state = np.load(out / "state.npz")
    assert np.all(np.isfinite(state["x"])) and float(state["time"]) > 0
    assert "median ms per frame" in result.stdout


def test_killed_run_resumes_and_matches_an_uninterrupted_run(tmp_path):
    scene = str(ROOT / "scenes" / "cantilever.py")
    args = ["--frames", "60", "--width", "64", "--height", "48"]
    whole = tmp_path / "whole"
    assert run([scene, "--out", str(whole), *args], cwd=tmp_path).returncode == 0

    broken = tmp_path / "broken"
    proc = subprocess.Popen([sys.executable, "-m", "taichi_hair", "run", scene, "--out", str(broken),
                             *args, "--no-progress"], cwd=tmp_path, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    progress = broken / "progress.json"
    deadline = time.time() + 600
    while time.time() < deadline:
        if progress.exists():
            try:
                if json.loads(progress.read_text())["frames_done"] >= 10:
                    break
            except (ValueError, KeyError):
                pass
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done = json.loads(progress.read_text())["frames_done"]
    assert 10 <= done < 60, "the run was not killed mid-way"
    kept = {p.name: p.read_bytes() for p in (broken / "frames").glob("frame_*.png")
            if int(p.stem.split("_")[1]) < done}
    assert len(kept) == done

    resumed = run([scene, "--out", str(broken), *args, "--resume"], cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resumed from {done}" in resumed.stdout
    for name, data in kept.items():  # finished frames were kept, not redone
        assert (broken / "frames" / name).read_bytes() == data
    assert len(list((broken / "frames").glob("frame_*.png"))) == 60
    a, b = np.load(whole / "state.npz"), np.load(broken / "state.npz")
    assert float(a["time"]) == pytest.approx(float(b["time"]))
    assert np.abs(a["x"] - b["x"]).max() < 1e-6 and np.abs(a["v"] - b["v"]).max() < 1e-5
