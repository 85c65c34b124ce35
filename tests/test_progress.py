"""The progress bar's estimate of time left is measured after the first update, whose chunk
also pays for compiling kernels."""

import io
import time

from taichi_hair.progress import ProgressBar


def test_time_left_ignores_the_slow_first_chunk():
    out = io.StringIO()
    with ProgressBar(10.0, "work", stream=out) as bar:
        time.sleep(1.0)  # "compiling"
        bar.update(1.0)
        for _ in range(3):
            time.sleep(0.01)
            bar.update(1.0)
        last = out.getvalue().rsplit("\r", 1)[-1]
    left = float(last.split("elapsed,")[1].split("s left")[0])
    # 6 units at ~0.01 s each: well under a second; counting the first chunk would say ~1.5 s
    assert left < 0.8, last
    assert "? s left" in out.getvalue().split("\r")[1]  # before any update: no estimate
