"""A dependency-free progress report on stderr: a bar redrawn in place on a terminal, one line
per update (at most one every `interval` seconds) anywhere else (a log file, CI)."""

import sys
import threading
import time


def is_terminal(stream) -> bool:
    """True if `stream` is an interactive terminal (a bar may redraw itself there with \\r)."""
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except (ValueError, OSError):  # a closed or detached stream
        return False


class ProgressBar:
    """`with ProgressBar(total, label) as bar: bar.update(k)`; silent when disabled.

    Until the first non-zero update the work is compiling kernels (the first chunk of a
    simulation compiles them, for minutes on a cold cache): the bar says "compiling kernels" with
    the time elapsed and gives no estimate. The estimate of time left comes from the rate after
    that first chunk, once a later one has been timed. On a terminal the bar redraws itself with
    a carriage return; on any other stream (terminal=None asks the stream) each update is one
    line, at most one every `interval` s, and the last one always. While compiling, a daemon
    thread redraws the elapsed time (every second on a terminal)."""

    def __init__(self, total: float, label: str = "", enabled: bool = True, stream=None, width: int = 30,
                 terminal: bool | None = None, interval: float = 10.0, done: float = 0.0):
        """done: work finished before this bar (a resumed run's frames): not a timed chunk."""
        self.total = max(float(total), 1e-300)
        self.label = label
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.terminal = is_terminal(self.stream) if terminal is None else terminal
        self.interval = interval
        self.width = width
        self.done = min(self.total, float(done))
        self.start = time.perf_counter()
        self._first = None  # (time, done) at the end of the first chunk, which also compiled kernels
        self._last_line = None  # when a line was last written (not a terminal)
        self._lock = threading.Lock()
        self._closed = threading.Event()

    def __enter__(self):
        self._draw()
        if self.enabled:
            threading.Thread(target=self._tick_while_compiling, daemon=True).start()
        return self

    def _tick_while_compiling(self):
        while not self._closed.wait(1.0 if self.terminal else self.interval):
            if self._first is not None:
                return
            self._draw()

    def update(self, amount: float = 1.0) -> None:
        self.done = min(self.total, self.done + amount)
        if self._first is None and amount > 0:
            self._first = (time.perf_counter(), self.done)
        self._draw()

    def line(self) -> str:
        """The report as it stands: label, bar, percent, time elapsed and the phase or estimate."""
        frac = self.done / self.total
        filled = int(round(frac * self.width))
        now = time.perf_counter()
        elapsed = now - self.start
        if self._first is None:
            state = "compiling kernels (minutes on a cold cache)"
        elif frac >= 1.0:
            state = "done"
        elif self.done > self._first[1]:
            rate = (self.done - self._first[1]) / max(now - self._first[0], 1e-9)
            state = f"{(self.total - self.done) / rate:.1f} s left"
        else:
            state = "timing (no estimate until a chunk after the compile is timed)"
        return (f"{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {100 * frac:5.1f}%  "
                f"{elapsed:6.1f} s elapsed, {state}")

    def _draw(self):
        if not self.enabled:
            return
        with self._lock:
            self._write()

    def _write(self):
        if self._closed.is_set():
            return
        if self.terminal:
            self.stream.write(f"\r{self.line()}\033[K")
        else:
            now = time.perf_counter()
            if self._last_line is not None and now - self._last_line < self.interval and self.done < self.total:
                return
            self._last_line = now
            self.stream.write(self.line() + "\n")
        self.stream.flush()

    def __exit__(self, *exc):
        with self._lock:
            self._closed.set()
            if self.enabled and self.terminal:
                self.stream.write("\n")
                self.stream.flush()
        return False
