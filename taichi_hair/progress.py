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
        self._first = None  # (time, done) at the first update: the rate is measured from there,
        # since the first chunk also pays for compiling kernels

    def __enter__(self):
        self._draw()
        return self

    def update(self, amount: float = 1.0) -> None:
        self.done = min(self.total, self.done + amount)
        if self._first is None:
            self._first = (time.perf_counter(), self.done)
        self._draw()

    def _draw(self):
        if not self.enabled:
            return
        frac = self.done / self.total
        filled = int(round(frac * self.width))
        elapsed = time.perf_counter() - self.start
        left = "   ? s left"
        if self._first is not None and self.done > self._first[1]:
            rate = (self.done - self._first[1]) / max(time.perf_counter() - self._first[0], 1e-9)
            left = f"{(self.total - self.done) / rate:6.1f} s left"
        elif frac >= 1.0:
            left = "   0.0 s left"
        self.stream.write(f"\r{self.label} [{'#' * filled}{'.' * (self.width - filled)}] "
                          f"{100 * frac:5.1f}%  {elapsed:6.1f} s elapsed, {left}")
        self.stream.flush()

    def __exit__(self, *exc):
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
        return False
