"""Taichi initialisation: once per process, with the precision chosen for every field.

`init` wraps `ti.init`. Fields and kernels use Taichi's `float`, which resolves to the
precision chosen here, so one call decides float32 or float64 for the whole process.

Importing Taichi prints its banner ("[Taichi] version ...") on stdout, which belongs to the
caller's data (the CLI's --json documents) and which `--help` should not carry: this module
imports Taichi with the banner off and `init` prints it on stderr when it starts Taichi, unless
ENABLE_TAICHI_HEADER_PRINT (Taichi's own setting) switches it off.
"""

import contextlib
import os
import sys

_banner = {"wanted": True, "printed": False}


def import_taichi_quietly() -> None:
    """Import Taichi with its banner off; sys.stdout is left alone while Taichi imports (Taichi
    would take a replaced stdout for a notebook and wrap every kernel call)."""
    if "taichi" in sys.modules:
        _banner["printed"] = True  # imported before us: Taichi printed it already
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
    _banner["wanted"] = (wanted or "True").lower() not in ("false", "0", "f")


def print_banner() -> None:
    """Taichi's banner on stderr, the first time only."""
    if _banner["printed"] or not _banner["wanted"]:
        return
    _banner["printed"] = True
    from taichi._lib import utils
    with contextlib.redirect_stdout(sys.stderr):
        utils._print_taichi_header()


import_taichi_quietly()

import taichi as ti  # noqa: E402  (after the quiet import above)

from . import source_positions  # noqa: E402

_ARCHES = {"cpu": ti.cpu, "cuda": ti.cuda, "gpu": ti.gpu, "vulkan": ti.vulkan, "metal": ti.metal}
_PRECISIONS = {"float32": ti.f32, "float64": ti.f64}
_state = {"arch": None, "precision": None}


def taichi_is_initialized() -> bool:
    """True once `ti.init` has run in this process (by us or by anyone else)."""
    return ti.lang.impl.get_runtime().prog is not None


def skip_version_check() -> None:
    """Ask `ti.init` not to start its version check (TI_SKIP_VERSION_CHECK=ON, unless the
    environment says otherwise). The check is a Python thread that posts to Taichi's server
    while the scene starts; a run that then imports pxr (a USD groom) could hang for good: pxr's
    libraries take the GIL in their initialisers, inside dlopen, while that thread, holding the
    GIL, waits to load a module of its own (its host name's codec) behind dlopen's lock. Offline,
    the check fails without recording the day, so it ran at every start."""
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")


def init(arch: str = "cpu", precision: str = "float32", *, debug: bool = False, **kwargs) -> None:
    """Initialise Taichi once for this process.

    arch: "cpu" (default), "cuda", "gpu", "vulkan" or "metal".
    precision: "float32" (default) or "float64"; the float type of every simulator field.
    Calling again with the same settings is a no-op; with different settings it raises,
    because Taichi fields and compiled kernels cannot change precision mid-process.
    Extra keyword arguments go to `ti.init` unchanged.
    """
    if arch not in _ARCHES:
        raise ValueError(f"arch must be one of {sorted(_ARCHES)}, got {arch!r}")
    if precision not in _PRECISIONS:
        raise ValueError(f"precision must be one of {sorted(_PRECISIONS)}, got {precision!r}")
    if _state["precision"] is not None:
        if (_state["arch"], _state["precision"]) != (arch, precision):
            raise RuntimeError(
                f"taichi_hair is already initialised with arch={_state['arch']!r}, "
                f"precision={_state['precision']!r}; Taichi can only be initialised once per process"
            )
        return
    if taichi_is_initialized():
        raise RuntimeError(
            "Taichi was initialised before taichi_hair.init(); call taichi_hair.init() first "
            "so that the simulator's precision is known"
        )
    options = dict(arch=_ARCHES[arch], default_fp=_PRECISIONS[precision], debug=debug,
                   log_level=ti.WARN, random_seed=0)
    if arch != "cpu" and precision == "float64":
        # fast_math rewrites float64 sqrt as float32 on CUDA
        options["fast_math"] = False
    options.update(kwargs)
    print_banner()
    skip_version_check()
    source_positions.install()
    with contextlib.redirect_stdout(sys.stderr):  # "[Taichi] Starting on arch=...": not data
        ti.init(**options)
    _state["arch"], _state["precision"] = arch, precision


def ensure_init() -> None:
    """Initialise with the defaults (CPU, float32) unless `init` already ran."""
    if _state["precision"] is None:
        init()


def precision() -> str:
    """"float32" or "float64": the precision of this process's fields (initialising if needed)."""
    ensure_init()
    return _state["precision"]


def arch() -> str:
    """The arch name passed to `init` (initialising if needed)."""
    ensure_init()
    return _state["arch"]
