"""A dependency-free text progress bar on stderr."""

import sys
import time


class ProgressBar:
    """`with ProgressBar(total, label) as bar: bar.update(k)`; silent when disabled."""

    def __init__(self, total: float, label: str = "", enabled: bool = True, stream=None, width: int = 30):
        self.total = max(float(total), 1e-300)
        self.label = label
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.width = width
        self.done = 0.0
        self.start = time.perf_counter()

    def __enter__(self):
        self._draw()
        return self

    def update(self, amount: float = 1.0) -> None:
        self.done = min(self.total, self.done + amount)
        self._draw()

    def _draw(self):
        if not self.enabled:
            return
        frac = self.done / self.total
        filled = int(round(frac * self.width))
        elapsed = time.perf_counter() - self.start
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
        self.stream.write(f"\r{self.label} [{'#' * filled}{'.' * (self.width - filled)}] "
                          f"{100 * frac:5.1f}%  {elapsed:6.1f} s elapsed, {eta:6.1f} s left")
        self.stream.flush()

    def __exit__(self, *exc):
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
        return False
