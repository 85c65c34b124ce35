"""The progress report: a compile phase with its elapsed time, an estimate of time left only
once a chunk after the compile has been timed, and plain lines (no carriage returns) where the
stream is not a terminal."""

import io
import time

from taichi_hair.progress import ProgressBar


def _states(text):
    return [part.split("elapsed, ", 1)[1].replace("\033[K", "").strip()
            for part in text.replace("\r", "\n").split("\n") if "elapsed, " in part]


def test_no_estimate_until_a_chunk_after_the_compile_is_timed():
    """The runner opens the bar with update(0): a bar that started its clock there would count
    the first frame's compile as work time (a first estimate of 2690 s for a run of minutes).
    The first non-zero chunk is the compile; the estimate starts after it."""
    out = io.StringIO()
    with ProgressBar(10.0, "work", stream=out, terminal=True) as bar:
        bar.update(0)  # what a fresh run's runner does
        time.sleep(1.0)  # "compiling"
        bar.update(1.0)
        after_compile = _states(out.getvalue())[-1]
        for _ in range(3):
            time.sleep(0.01)
            bar.update(1.0)
        last = _states(out.getvalue())[-1]
    assert _states(out.getvalue())[0].startswith("compiling kernels")
    assert "s left" not in after_compile, after_compile
    left = float(last.split(" s left")[0])
    # 6 units at ~0.01 s each: well under a second; counting the compile would say ~2 s
    assert left < 0.8, last


def test_compiling_phase_redraws_its_elapsed_time():
    """A compile of minutes is not silent: the bar redraws the time elapsed every second."""
    out = io.StringIO()
    with ProgressBar(10.0, "work", stream=out, terminal=True):
        time.sleep(2.5)
    states = _states(out.getvalue())
    elapsed = [float(p.split("%")[1].split("s elapsed")[0]) for p in out.getvalue().split("\r") if "elapsed" in p]
    assert sum(s.startswith("compiling kernels") for s in states) >= 3, states
    assert max(elapsed) >= 1.5


def test_no_carriage_returns_where_the_stream_is_not_a_terminal():
    """A redirected run wrote ~400 updates as one line of carriage returns; now each update is a
    line, at most one per interval, and the last always."""
    out = io.StringIO()  # not a terminal
    with ProgressBar(400.0, "work", stream=out, interval=10.0) as bar:
        for _ in range(400):
            bar.update(1.0)
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert 2 <= len(lines) <= 3, lines
    assert lines[0].startswith("work") and "compiling kernels" in lines[0]
    assert "100.0%" in lines[-1] and lines[-1].endswith("done")


def test_a_resumed_runs_frames_are_not_a_timed_chunk():
    out = io.StringIO()
    with ProgressBar(10.0, "work", stream=out, terminal=True, done=5.0) as bar:
        assert "50.0%" in out.getvalue() and "compiling kernels" in _states(out.getvalue())[-1]
        time.sleep(0.5)
        bar.update(1.0)
        assert "s left" not in _states(out.getvalue())[-1]
