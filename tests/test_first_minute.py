"""A new user's first minute: the CLI's help shows every default, `doctor` describes the
installation, `--help` and `doctor` print no Taichi banner, scenes import only taichi_hair,
`sim.run(t)` ends at t, and a fresh run does not claim to be resumed."""

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.app import cli, run_command, run_output, runner

ROOT = Path(__file__).resolve().parents[1]


def _parsers(parser, name="taichi-hair"):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield from _parsers(sub, f"{name} {sub_name}")


def test_every_option_shows_its_default_in_help():
    """--width, --height and others had no help and no shown default; --out had no default."""
    parser = cli.build_parser()
    missing = []
    for name, p in _parsers(parser):
        formatter = p._get_formatter()
        for action in p._actions:
            if (not action.option_strings or action.nargs == 0 or action.required
                    or action.help == argparse.SUPPRESS):
                continue  # flags are off unless given; required options have none; hidden ones are not shown
            text = formatter._expand_help(action)
            if "default" not in text or "(default: None)" in text:
                missing.append(f"{name} {action.option_strings[0]}: {text!r}")
    assert not missing, "\n".join(missing)
    run_help = next(p for n, p in _parsers(parser) if n == "taichi-hair run").format_help()
    assert "out/<scene name>" in run_help


def test_out_defaults_to_out_slash_scene_name():
    args = cli.build_parser().parse_args(["run", "scenes/shake_curly.py"])
    assert args.out is None and run_command.default_out(args.scene) == Path("out") / "shake_curly"


def test_a_fresh_run_is_not_called_resumed():
    summary = {"scene": "s.py", "frames": 2, "resumed_from": 0, "video": "v.mp4", "simulated_s": 0.1,
               "ms_per_frame": {"simulation": 1.0, "interpolation": 1.0, "rendering": 1.0}}
    assert "resumed" not in run_output.format_summary(summary)
    assert "(resumed from 5)" in run_output.format_summary({**summary, "resumed_from": 5})


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "taichi_hair", *args], capture_output=True, text=True,
                          timeout=300)


def test_help_and_doctor_print_no_taichi_banner():
    """The banner ("[Taichi] version ...") comes when Taichi starts (th.init), on stderr: --help
    and doctor start no Taichi program and print none; stdout stays the command's own."""
    for args in (["--help"], ["run", "--help"], ["doctor"]):
        done = _cli(*args)
        assert done.returncode == 0, done.stderr
        assert "[Taichi]" not in done.stdout + done.stderr, (args, done.stdout[:300], done.stderr[:300])


def test_doctor_names_versions_cache_and_extras():
    done = _cli("doctor")
    assert done.returncode == 0, done.stderr
    import taichi
    assert "taichi" in done.stdout and ".".join(map(str, taichi.__version__)) in done.stdout
    for extra in ("test", "usd", "bench", "mitsuba", "cluster"):
        assert f"extra [{extra}]" in done.stdout
    assert "kernel cache" in done.stdout and "cpu" in done.stdout


def test_scenes_import_only_taichi_hair():
    """A scene script is user code: it needs `import taichi_hair as th` and nothing private
    (th.Shot is exported; scenes imported it from taichi_hair.app.runner)."""
    assert th.Shot is runner.Shot
    for path in sorted((ROOT / "scenes").glob("*.py")):
        text = path.read_text()
        imports = [line for line in text.splitlines() if line.startswith(("import ", "from "))]
        assert not [line for line in imports if "taichi_hair." in line or "taichi_hair import" in line], path.name


def test_run_ends_at_exactly_the_time_asked():
    """sim.run(1/24) 24 times ended at t = 1.008 s (42 whole steps of 1 ms per call); the step
    is now fitted (42 steps of 0.992 ms) and dt restored after."""
    groom = th.Groom.straight(length=0.1, n_nodes=11)
    sim = th.Simulator(groom, th.Material(), dt=1e-3)
    substeps = sim.substeps
    for _ in range(24):
        sim.run(1 / 24, progress=False)
    assert sim.time == pytest.approx(1.0, abs=1e-12)
    assert sim.steps_taken == 24 * 42 and sim.dt == 1e-3 and sim.substeps == substeps
    assert np.all(np.isfinite(sim.positions()))


def test_bench_is_quick_by_default_and_whole_with_full():
    """`taichi-hair bench` with no arguments runs the quick table (the whole one takes 12 minutes:
    10000 guides, the implicit step's cold compile), --full the whole one, and an option given
    on the line wins over either."""
    from taichi_hair.app import bench
    parser = cli.build_parser()

    def resolved(*argv):
        args = parser.parse_args(["bench", *argv])
        bench.apply_preset(args)
        return args

    quick, full = resolved(), resolved("--full")
    assert "10000" not in quick.strands.split(",") and quick.integrator == "explicit"
    assert "10000" in full.strands.split(",") and full.integrator == "both"
    assert quick.dense < full.dense and quick.head_guides < full.head_guides
    assert resolved("--full", "--strands", "7").strands == [7]


# ---- stdout belongs to the caller: --json prints JSON only -----------------------------------

def test_bench_json_stdout_is_one_json_document():
    # both integrators compile from a cold cache: over 300 s on CI's 2 cores
    done = subprocess.run([sys.executable, "-m", "taichi_hair", "bench", "--json", "--strands", "1", "--repeats", "1",
                           "--stage-steps", "1", "--head-guides", "0", "--dense", "0"],
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    results = json.loads(done.stdout)  # Taichi's banner ("[Taichi] version ...") is kept off stdout
    assert results[0]["precision"] == "float32"
    assert "[Taichi]" in done.stderr


def test_library_keeps_stdout_for_the_caller():
    script = ("import taichi_hair as th; th.init(); import taichi.lang.shell as shell; "
              "print('data', shell.pybuf_enabled)")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    # the banner went to stderr without Taichi mistaking a replaced stdout for a notebook's
    assert done.stdout == "data False\n" and "[Taichi] version" in done.stderr


@pytest.mark.parametrize("package", ["taichi_hair", "render"])
def test_init_starts_no_python_thread(package):
    """Starting Taichi leaves no Python thread running beside the main one (Taichi's version
    check would be one: a thread loading modules while the main thread loads pxr can deadlock
    with it, `runtime.skip_version_check`); TI_SKIP_VERSION_CHECK set by the user stands."""
    script = ("import os, threading\n"
              "os.environ.pop('TI_SKIP_VERSION_CHECK', None)\n"
              f"import {package} as p\n"
              "started, start = [], threading.Thread.start\n"
              "threading.Thread.start = lambda t: (started.append(t.name), start(t))[1]\n"
              "p.init()\n"
              "print(started, os.environ.get('TI_SKIP_VERSION_CHECK'))\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.splitlines()[-1] == "[] ON"   # (render.init's banner goes to stdout)
    kept = subprocess.run([sys.executable, "-c", script.replace("os.environ.pop('TI_SKIP_VERSION_CHECK', None)",
                                                                "os.environ['TI_SKIP_VERSION_CHECK'] = 'OFF'")],
                          capture_output=True, text=True, timeout=300)
    assert kept.stdout.endswith(" OFF\n"), kept.stderr[-2000:]
