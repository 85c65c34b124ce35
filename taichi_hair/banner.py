"""Taichi's start-up banner ("[Taichi] version ...") on stderr, once, when Taichi starts.

Importing Taichi prints its banner on stdout, which belongs to the caller's data (the CLI's
--json documents) and which `--help` should not carry. `import_taichi_quietly` imports it with
the banner off; `print_banner` prints it on stderr when `taichi_hair.init` starts Taichi, unless
ENABLE_TAICHI_HEADER_PRINT switches it off (Taichi's own setting)."""

import contextlib
import os
import sys

_shown = {"wanted": True, "printed": False}


def import_taichi_quietly() -> None:
    """Import Taichi with its banner off; sys.stdout is left alone while Taichi imports (Taichi
    would take a replaced stdout for a notebook and wrap every kernel call)."""
    if "taichi" in sys.modules:
        _shown["printed"] = True  # imported before us: Taichi printed it already
        return
    wanted = os.environ.get("ENABLE_TAICHI_HEADER_PRINT")
    os.environ["ENABLE_TAICHI_HEADER_PRINT"] = "0"
    try:
        import taichi  # noqa: F401
    finally:
        if wanted is None:
            del os.environ["ENABLE_TAICHI_HEADER_PRINT"]
        else:
            os.environ["ENABLE_TAICHI_HEADER_PRINT"] = wanted
    _shown["wanted"] = (wanted or "True").lower() not in ("false", "0", "f")


def print_banner() -> None:
    """Taichi's banner on stderr, the first time only."""
    if _shown["printed"] or not _shown["wanted"]:
        return
    _shown["printed"] = True
    from taichi._lib import utils
    with contextlib.redirect_stdout(sys.stderr):
        utils._print_taichi_header()
