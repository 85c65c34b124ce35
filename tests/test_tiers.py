"""The two test tiers: conftest.py's hook recognises a slow test by what it calls, through the
helpers and fixtures of its module at any depth, and leaves the others in the fast tier."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from conftest import slow_functions

ROOT = Path(__file__).resolve().parents[1]


def test_slow_tests_are_recognised_through_helpers(tmp_path):
    module = tmp_path / "test_example.py"
    module.write_text(textwrap.dedent("""
        import subprocess, sys
        from cosseratbench.experiment import run as experiment
        from helpers import run_cli as run
        from taichi_hair.app import reports

        def _launch(args):
            return subprocess.run(args, capture_output=True)

        def _twice(args):
            return [_launch(args), _launch(args)]

        def test_through_two_helpers():
            assert _twice(["true"])

        def test_python_child():
            assert [sys.executable, "-c", "pass"]

        def test_report_sweep(tmp_path):
            reports.stability_report(False, tmp_path)

        def test_scene_run(tmp_path):
            assert run(["scenes/cantilever.py"], cwd=tmp_path).returncode == 0

        def bench(name):
            return experiment(name, None)

        def test_benchmark_experiment():
            assert bench("pile")

        def test_in_process():
            def run(x):  # a local name that launches nothing
                return x + 1
            assert run(1) == 2
        """))
    assert slow_functions(module) == {"_launch", "_twice", "test_through_two_helpers", "test_python_child",
                                      "test_report_sweep", "test_scene_run", "bench",
                                      "test_benchmark_experiment"}


def test_the_fast_tier_collects_no_test_that_launches_a_process():
    """`pytest -q` (pyproject's addopts) collects none of the tests the hook recognises, and
    `-m slow` collects them; the tiers together are the whole suite."""
    def collected(*options):
        done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                               *options], cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
        return {line for line in done.stdout.splitlines() if "::" in line}

    fast, slow, every = collected(), collected("-m", "slow"), collected("-m", "")
    assert len(fast) > 300 and len(slow) > 30 and fast | slow == every and not fast & slow
    for nodeid in fast:
        path, name = nodeid.split("::")[0], nodeid.split("::")[-1].split("[")[0]
        assert name not in slow_functions(ROOT / path), nodeid
    assert "tests/test_tiers.py::test_an_explicit_mark_is_kept" in slow


@pytest.mark.slow
def test_an_explicit_mark_is_kept(request):
    assert request.node.get_closest_marker("slow") is not None
