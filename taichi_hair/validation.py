"""One vocabulary for checking inputs, used by every option class and function that takes user
values: `real`, `integer`, `vector3`, `choice` for Python values, `cli_int`, `cli_real`,
`cli_int_list` for command-line text. Each refuses a bad value with one line naming the parameter,
the allowed range (and unit) and the value received, before any work starts.

A real number is any real of any numeric type (Python int or float, numpy integer or floating
scalar: np.float32(1e-3) is a valid dt), never a bool."""

import math
import numbers

import numpy as np


def is_real(value) -> bool:
    """True for a real number of any numeric type (not bool); finiteness is the caller's check."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_integer(value) -> bool:
    """True for an integer of any integer type (int, numpy integers), not bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _bounds_text(low, high, low_open, high_open) -> str:
    """' > 0', ' >= 1 and <= 10', '' (no bounds)."""
    bounds = [f"{'>' if low_open else '>='} {_number_text(low)}"] if low is not None else []
    bounds += [f"{'<' if high_open else '<='} {_number_text(high)}"] if high is not None else []
    return (" " + " and ".join(bounds)) if bounds else ""


def _within(value, low, high, low_open, high_open) -> bool:
    return ((low is None or (value > low if low_open else value >= low))
            and (high is None or (value < high if high_open else value <= high)))


def real(name: str, value, unit: str = "", *, low=None, high=None, low_open=False, high_open=False) -> float:
    """float(value) for a finite real number within [low, high] (an open end with low_open /
    high_open; None: unbounded); otherwise ValueError "NAME must be a finite number > LOW UNIT, got
    VALUE". `unit` is written after the range, e.g. "m", "Pa", "(relative)"."""
    if not (is_real(value) and math.isfinite(value) and _within(value, low, high, low_open, high_open)):
        rule = f"a finite number{_bounds_text(low, high, low_open, high_open)}"
        raise ValueError(f"{name} must be {rule}{' ' + unit if unit else ''}, got {value!r}")
    return float(value)


def integer(name: str, value, *, low=None, high=None) -> int:
    """int(value) for an integer (any integer type, not bool) within [low, high]; otherwise
    ValueError "NAME must be an integer >= LOW, got VALUE"."""
    if not (is_integer(value) and _within(value, low, high, False, False)):
        raise ValueError(f"{name} must be an integer{_bounds_text(low, high, False, False)}, got {value!r}")
    return int(value)


def vector3(name: str, value, unit: str = "", *, positive=False, nonzero=False, normalise=False) -> np.ndarray:
    """value as a float64 array of shape (3,), every entry finite (> 0 with positive; not the
    zero vector with nonzero or normalise; scaled to length 1 with normalise); otherwise
    ValueError "NAME must be a finite 3-vector [UNIT], got VALUE"."""
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = None
    nonzero = nonzero or normalise
    ok = v is not None and v.shape == (3,) and bool(np.all(np.isfinite(v)))
    ok = ok and not (positive and np.any(v <= 0)) and not (nonzero and np.linalg.norm(v) < 1e-12)
    if not ok:
        rule = ("a finite" + (" non-zero" if nonzero else "") + " 3-vector" + (f" [{unit}]" if unit else "")
                + (" with every entry > 0" if positive else "") + (" (it is normalised)" if normalise else ""))
        raise ValueError(f"{name} must be {rule}, got {value!r}")
    return v / np.linalg.norm(v) if normalise else v


def choice(name: str, value, options):
    """value when it is one of `options` (a sequence); otherwise ValueError "NAME must be one of
    (...), got VALUE"."""
    if not any(isinstance(value, type(option)) and value == option for option in options):
        raise ValueError(f"{name} must be one of {tuple(options)}, got {value!r}")
    return value


# ---- command-line options: argparse `type=` checkers ---------------------------------------------
# Each returns a function str -> value that raises argparse.ArgumentTypeError with the allowed
# range (argparse puts "argument --OPTION:" before it), so a bad number ends the command at parse
# time (exit code 2, one line with OneLineParser) before any work starts. `option` names the
# function (argparse's own messages use it).

def _number_text(v) -> str:
    return str(v) if isinstance(v, int) else f"{v:g}"


def _range_text(low, high, low_open=False):
    if high is None:
        return f"{'>' if low_open else '>='} {_number_text(low)}"
    return f"in {'(' if low_open else '['}{_number_text(low)}, {_number_text(high)}]"


def cli_int(option: str, low: int = 1, high: int | None = None):
    """An integer option in [low, high] (high None: no upper bound)."""
    import argparse

    def parse(text):
        try:
            value = int(text, 10)
        except (TypeError, ValueError):
            value = None
        if value is None or value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be an integer {_range_text(low, high)}, got {text!r}")
        return value
    parse.__name__ = option  # argparse names the type in some messages
    return parse


def cli_real(option: str, low: float = 0.0, high: float | None = None, *, low_open: bool = True, unit: str = ""):
    """A finite real option in (low, high] (low_open) or [low, high]; high None: no upper bound."""
    import argparse

    def parse(text):
        try:
            value = float(text)
        except (TypeError, ValueError):
            value = math.nan
        bad = (not math.isfinite(value) or value < low or (low_open and value == low)
               or (high is not None and value > high))
        if bad:
            where = _range_text(low, high, low_open)
            raise argparse.ArgumentTypeError(
                f"must be a finite number {where}{' ' + unit if unit else ''}, got {text!r}")
        return value
    parse.__name__ = option
    return parse


def cli_int_list(option: str, low: int = 1, high: int | None = None):
    """A comma-separated list of integers, each in [low, high]; at least one."""
    import argparse
    one = cli_int(option, low, high)

    def parse(text):
        items = [t.strip() for t in str(text).split(",")]
        if not any(items) or not all(items):
            raise argparse.ArgumentTypeError(f"must be comma-separated integers "
                                             f"{_range_text(low, high)}, got {text!r}")
        try:
            return [one(t) for t in items]
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(f"must be comma-separated integers "
                                             f"{_range_text(low, high)}, got {text!r}") from None
    parse.__name__ = option
    return parse


def one_line_parser_class():
    """argparse.ArgumentParser whose errors are one line on stderr ("PROG: error: MESSAGE", exit
    code 2) instead of the usage block and the message; subparsers inherit it."""
    import argparse
    import sys

    class OneLineParser(argparse.ArgumentParser):
        def error(self, message):
            self.exit(2, f"{self.prog}: error: {' '.join(str(message).split())}\n")

        def exit(self, status=0, message=None):
            if message:
                sys.stderr.write(message)
            raise SystemExit(status)
    return OneLineParser
