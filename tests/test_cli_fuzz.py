"""The command line fuzzed: every subcommand and numeric option with wrong types, zero, negative,
NaN, infinite, huge and empty values, bad choices, unknown and missing arguments, and missing
files. Each must end in exit code 2 with ONE line on stderr naming the option (or the file), no
traceback, nothing written outside --out, and quickly (before any simulation starts).

The allowed ranges below are written out here from the documented limits (README "Command
line"), not read from the parser, so a range the parser loses is caught. Most cases call the
CLI's main(argv) in this process (parsing and the checks before any work); a few run the real
`python -m taichi_hair` to check the process's exit code and output."""

import math
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

from taichi_hair.app.cli import main

ROOT = Path(__file__).resolve().parents[1]
MISSING = "no/such/scene.py"

# (subcommand words, option, kind, low, high, low_open): the documented ranges
OPTIONS = [
    (["run", MISSING, "--out", "OUT"], "--frames", int, 1, 1_000_000, False),
    (["run", MISSING, "--out", "OUT"], "--width", int, 1, 16384, False),
    (["run", MISSING, "--out", "OUT"], "--height", int, 1, 16384, False),
    (["run", MISSING, "--out", "OUT"], "--dense", int, 0, 10_000_000, False),
    (["run", MISSING, "--out", "OUT"], "--workers", int, 1, 256, False),
    (["sweep", MISSING, "--out", "OUT"], "--width", int, 1, 16384, False),
    (["sweep", MISSING, "--out", "OUT"], "--height", int, 1, 16384, False),
    (["sweep", MISSING, "--out", "OUT"], "--dense", int, 0, 10_000_000, False),
    (["sweep", MISSING, "--out", "OUT"], "--workers", int, 1, 256, False),
    (["demo"], "--nodes", int, 3, 10_000, False),
    (["demo"], "--length", float, 0.0, 10.0, True),
    (["demo"], "--curl-radius", float, 0.0, 1.0, True),
    (["demo"], "--curl-pitch", float, 0.0, 1.0, False),
    (["demo"], "--ellipticity", float, 1.0, 10.0, False),
    (["demo"], "--bend", float, -360.0, 360.0, False),
    (["bench"], "--strands", list, 1, 1_000_000, False),  # comma-separated integers
    (["bench"], "--repeats", int, 1, 1000, False),
    (["bench"], "--stage-steps", int, 1, 10_000, False),
    (["bench"], "--head-guides", int, 0, 100_000, False),
    (["bench"], "--dense", int, 0, 10_000_000, False),
    (["bench"], "--compile-timeout", int, 10, 100_000, False),
    (["bench"], "--n-elements", int, 2, 100_000, False),
    (["bench"], "--jobs", int, 1, 256, False),
    (["report", "stability"], "--duration", float, 0.0, 100.0, True),
    (["report", "sagfree"], "--guides", int, 1, 100_000, False),
    (["report", "sagfree"], "--seconds", float, 0.0, 1000.0, True),
    (["report", "sagfree"], "--drag", float, 0.0, 1.0, False),
    (["report", "implicit"], "--frames", int, 0, 100_000, False),
    (["report", "implicit"], "--every", int, 1, 100_000, False),
    (["report", "implicit"], "--seconds", float, 0.0, 100.0, True),
    (["report", "implicit"], "--reference-dt", float, 0.0, 0.1, True),
    (["report", "accuracy"], "--workers", int, 1, 256, False),
    (["report", "stability"], "--workers", int, 1, 256, False),
]
VALUES = ["abc", "", "0", "-1", "0.5", "nan", "inf", "-inf", "1e309", "-1e309", "1e12", "99999999999999999999",
          "1,2", "0x10", " 3"]


def _valid(kind, low, high, low_open, text):
    """Whether `text` is in the documented range (then the case would start real work: skipped)."""
    if kind is list:
        return bool(text) and all(_valid(int, low, high, low_open, t) for t in text.split(","))
    try:
        value = int(text, 10) if kind is int else float(text)
    except ValueError:
        return False
    if not math.isfinite(value):
        return False
    return (value > low if low_open else value >= low) and value <= high


def _cases():
    cases = []
    for words, option, kind, low, high, low_open in OPTIONS:
        for text in VALUES:
            if not _valid(kind, low, high, low_open, text.strip() if kind is float else text):
                cases.append(pytest.param([*words, f"{option}={text}"], option, id=f"{' '.join(words[:2])} {option}={text!r}"))
    # bad choices, unknown options, missing arguments, malformed lists and settings
    more = [
        (["run", MISSING, "--out", "OUT", "--usd", "ply"], "--usd"),
        (["run", MISSING, "--out", "OUT", "--integrator", "rk4"], "--integrator"),
        (["run", MISSING, "--out", "OUT", "--projection", "slow"], "--projection"),
        (["run", MISSING, "--out", "OUT", "--strain", "euler"], "--strain"),
        (["run", MISSING, "--out", "OUT", "--workers", "2", "--scheduler", "tcp://x:1"], "--scheduler"),
        (["run", MISSING, "--out", "OUT", "--bogus", "1"], "--bogus"),
        (["run", MISSING], MISSING),  # --out defaults to out/<scene name>
        (["run"], "scene"),
        (["sweep", MISSING, "--out", "OUT", "--set", "drag"], "--set"),
        (["sweep", MISSING, "--out", "OUT", "--set", "drag="], "drag"),
        (["sweep", MISSING, "--out", "OUT", "--set", "drag=1,,2"], "drag"),
        (["sweep", MISSING, "--out", "OUT", "--set", "drag=1e-4,1e-4"], "drag"),
        (["sweep", MISSING, "--out", "OUT", "--set", "drag=(1"], "drag"),
        (["sweep", MISSING, "--out", "OUT", "--set", "9x=1"], "--set"),
        (["sweep", MISSING, "--out", "OUT", "--set", "drag=1", "--set", "drag=2"], "--set"),
        (["demo", "--precision", "float16"], "--precision"),
        (["demo", "--twist", "lots"], "--twist"),
        (["bench", "--strands", "1,,2"], "--strands"),
        (["bench", "--strands", ","], "--strands"),
        (["bench", "--precision", "float8"], "--precision"),
        (["bench", "--integrator", "rk4"], "--integrator"),
        (["report", "accuracy", "--precision", "half"], "--precision"),
        (["report", "stability", "--integrator", "rk4"], "--integrator"),
        (["report", "implicit", "--steps-ms", "0"], "--steps-ms"),
        (["report", "implicit", "--steps-ms", "abc"], "--steps-ms"),
        (["report", "implicit", "--steps-ms", ""], "--steps-ms"),
        (["report", "implicit", "--cantilever-only", "--no-cantilever"], "--no-cantilever"),
        (["report", "implicit", "--scene", MISSING, "--no-cantilever", "--out", "OUT"], MISSING),
        (["report", "markdown", "--reports", MISSING], "--reports"),
        (["report", "markdown", "--reports", ".", "--out", "OUT/x.md"], "--reports"),
        (["report", "nothing"], "report"),
        (["report"], "report"),
        (["frobnicate"], "frobnicate"),
        ([], "command"),
        (["run", MISSING, "--out", "OUT"], MISSING),
        (["sweep", MISSING, "--out", "OUT", "--set", "drag=1e-4"], MISSING),
    ]
    cases += [pytest.param(argv, name, id=" ".join(argv) or "(nothing)") for argv, name in more]
    return cases


CASES = _cases()
SEEN = Counter()


@pytest.mark.parametrize("argv, names", CASES)
def test_bad_command_line_is_one_line_naming_the_option(argv, names, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    start = time.perf_counter()
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's exit
        rc = exc.code
    elapsed = time.perf_counter() - start
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == 2, f"exit code {rc}: {err}"
    assert len(lines) == 1, f"{len(lines)} lines on stderr:\n{err}"
    assert "Traceback" not in err
    assert names in lines[0], f"{names!r} not named in: {lines[0]}"
    assert elapsed < 5.0, f"took {elapsed:.1f} s"
    assert {p.name for p in tmp_path.iterdir()} <= {"OUT"}, "wrote outside --out"
    SEEN[argv[0] if argv else "(none)"] += 1


def test_fuzz_counts():
    """Every subcommand is fuzzed (the counts go in the report)."""
    by_command = Counter(c.values[0][0] if c.values[0] else "(none)" for c in CASES)
    assert set(by_command) >= {"run", "sweep", "demo", "bench", "report"}
    assert sum(by_command.values()) > 300


@pytest.mark.parametrize("argv, names", [
    (["run", "scenes/wind_straight.py", "--out", "OUT", "--width", "100000"], "--width"),
    (["bench", "--strands", "abc"], "--strands"),
    (["report", "sagfree", "--seconds", "-1"], "--seconds"),
])
def test_bad_command_line_in_a_real_process(argv, names, tmp_path):
    """The real process: exit code 2, one stderr line naming the option (besides Taichi's
    banner), nothing written."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "taichi_hair", *argv], cwd=tmp_path, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    # Taichi's version banner goes to stderr on import (taichi_hair/__init__.py), before any parsing
    lines = [line for line in done.stderr.strip().splitlines() if not line.startswith("[Taichi] version")]
    assert len(lines) == 1 and names in lines[0], done.stderr
    assert not list(tmp_path.iterdir())
    assert time.perf_counter() - start < 30


MODULE_MAINS = [
    ("taichi_hair.app.cluster", ["x.py"], [("--frames", 1, 100_000), ("--workers", 1, 256), ("--rounds", 1, 1000),
                                          ("--width", 1, 16384), ("--height", 1, 16384), ("--dense", 0, 10_000_000)]),
    ("taichi_hair.hair.interpolate", [], [("--n-dense", 1, 10_000_000), ("--n-nodes", 3, 10_000),
                                          ("--n-guides", 1, 1_000_000), ("--repeats", 1, 1000)]),
    ("taichi_hair.app.reports", ["stability"], [("--duration", 0.0, 100.0)]),
]


@pytest.mark.parametrize("module, words, option, low, high", [
    (m, w, o, lo, hi) for m, w, opts in MODULE_MAINS for o, lo, hi in opts])
def test_module_entry_points_check_their_options(module, words, option, low, high, capsys):
    """`python -m taichi_hair.app.cluster` (render timing), `...hair.interpolate` (its benchmark)
    and `...app.reports`: the same parse-time ranges and one-line errors."""
    import importlib
    entry = importlib.import_module(module)
    run = getattr(entry, "_main", None) or entry.main
    kind = float if isinstance(low, float) else int
    for text in VALUES:
        if _valid(kind, low, high, kind is float, text.strip() if kind is float else text):
            continue
        with pytest.raises(SystemExit) as exc:
            run([*words, f"{option}={text}"])
        lines = capsys.readouterr().err.strip().splitlines()
        assert exc.value.code == 2 and len(lines) == 1 and option in lines[0], (text, lines)


# ---- user errors in a run: one line naming the file, exit code 2 -----------------------------

CANTILEVER = str(ROOT / "scenes" / "cantilever.py")  # 24 fps, dt 1 ms


def _taichi_hair(*args, cwd):
    return subprocess.run([sys.executable, "-m", "taichi_hair", *args], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


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
