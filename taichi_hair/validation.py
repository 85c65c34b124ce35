"""Type tests shared by the input checks: a real number is any real of any numeric type
(Python int or float, numpy integer or floating scalar: np.float32(1e-3) is a valid dt), never a bool."""

import numbers


def is_real(value) -> bool:
    """True for a real number of any numeric type (not bool); finiteness is the caller's check."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_integer(value) -> bool:
    """True for an integer of any integer type (int, numpy integers), not bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


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
    import math

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
