"""`taichi-hair bench --compile`: the cold first-frame compile table (issue 45). Speed is
measured by the command, never asserted here: the tests check that a cell really compiles in
a cache of its own and reports its seconds, and that bad input is refused before any work."""

import json
import os
import subprocess
import sys

import pytest

from taichi_hair.app import cli


def test_an_unknown_scene_is_refused_in_one_line(capsys):
    assert cli.main(["bench", "--compile", "--scenes", "cantilever,nosuch"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--scenes" in err[0] and "cantilever" in err[0]


@pytest.mark.slow
def test_a_cell_compiles_in_a_fresh_cache_and_reports_its_seconds(tmp_path):
    """The smallest shipped scene, implicit: the cell's kernels compile in the child, in a cache
    of its own (the caller's cache stays untouched; a warm one would answer them in
    microseconds), and the frame's compile time is a positive part of its first frame."""
    warm = tmp_path / "parent_cache"
    env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=str(warm))
    cmd = [sys.executable, "-m", "taichi_hair", "bench", "--compile", "--scenes", "cantilever", "--integrator",
           "implicit", "--json"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800)
    assert done.returncode == 0, done.stderr
    (cell,) = json.loads(done.stdout[done.stdout.index("["):])
    assert cell["scene"] == "cantilever" and cell["integrator"] == "implicit"
    assert 0.0 < cell["compile_cpu_s"] <= cell["first_frame_cpu_s"]
    parts = cell["kernels"]["implicit_part"]
    assert parts["instances"] >= 4  # assemble and finish, each for the predictor and a correction
    assert parts["back_cpu_s"] > 0.5  # compiled here, not loaded from a cache
    assert not warm.exists() or not any(warm.iterdir())
