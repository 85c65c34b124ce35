"""`taichi-hair bench --against REV` (app/history.py): the same bench from an older commit in a
temporary worktree, alternating, with each row's ratio."""

import os

import pytest

from taichi_hair.app import history


def test_against_refuses_what_is_not_a_commit():
    with pytest.raises(ValueError, match="--against must name a commit"):
        history.resolve("no-such-revision-anywhere")


def test_rows_are_named_by_precision_integrator_and_size():
    results = [{"precision": "float32",
                "cases": [{"strands": 100, "integrator": "explicit", "ms_per_frame": 12.0}],
                "full_head": {"rows": [{"guides": 200, "integrator": "explicit", "style": "curly",
                                        "hair_interaction": False, "ms_per_frame": 300.0}]}}]
    assert history.row_times(results) == {"float32 explicit 100 guides": 12.0,
                                          "float32 explicit full head 200 curly": 300.0}


@pytest.mark.slow
def test_bench_against_head_times_both_trees_alike():
    # HEAD against itself: the same rows from both trees, each a positive time, and ratios near 1
    # only as far as timing noise goes (not asserted: speed is measured, never asserted)
    result = history.compare("HEAD", ["--strands", "1", "--repeats", "1", "--integrator", "explicit",
                                      "--precision", "float32", "--head-guides", "0", "--dense", "0",
                                      "--stage-steps", "1"], rounds=1)
    rows = {r["row"]: r for r in result["rows"]}
    assert list(rows) == ["float32 explicit 1 guides"]
    row = rows["float32 explicit 1 guides"]
    assert row["this_ms"] > 0 and row["against_ms"] > 0 and row["ratio"] > 0
    assert "against" in history.format_comparison(result)


def test_scene_must_be_a_script_inside_the_repository(tmp_path):
    outside = tmp_path / "scene.py"
    outside.write_text("")
    with pytest.raises(ValueError, match="--scene must be a scene script inside this repository"):
        history.check_scene(str(outside))
    with pytest.raises(ValueError, match=r"--scene must be an existing \.py scene script"):
        history.check_scene("scenes/no_such_scene.py")
    assert history.check_scene("scenes/cantilever.py") == "scenes/cantilever.py"


def test_bench_scene_needs_against():
    from taichi_hair.app.cli import build_parser
    from taichi_hair.app.bench import main
    args = build_parser().parse_args(["bench", "--scene", "scenes/cantilever.py"])
    with pytest.raises(ValueError, match="--scene compares a scene's run against an older commit: give --against"):
        main(args)


@pytest.mark.slow
def test_scene_against_head_times_both_runs():
    # a scene's run from both trees (HEAD against itself): wall time, CPU time and the three
    # per-frame medians its summary prints, each positive; CPU time at most what the machine's
    # cores can give in the wall time
    result = history.compare("HEAD", [], rounds=1, scene="scenes/cantilever.py", frames=2)
    rows = {r["row"]: r for r in result["rows"]}
    assert list(rows) == ["scenes/cantilever.py wall s (2 frames)", "scenes/cantilever.py CPU s (2 frames)",
                          "simulation ms per frame", "interpolation ms per frame", "rendering ms per frame"]
    assert all(r["this_ms"] > 0 and r["against_ms"] > 0 for name, r in rows.items() if "interpolation" not in name)
    wall, cpu = rows["scenes/cantilever.py wall s (2 frames)"], rows["scenes/cantilever.py CPU s (2 frames)"]
    for side in ("this_ms", "against_ms"):
        assert cpu[side] <= wall[side] * (os.cpu_count() or 1) * 1.05 + 0.5, (cpu, wall)
    assert "taichi-hair run scenes/cantilever.py --frames 2" in history.format_comparison(result)
