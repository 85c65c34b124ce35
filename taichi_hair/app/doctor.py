"""`taichi-hair doctor`: what this installation runs on, for a bug report or a first check:
versions, the arches this Taichi build has, the kernel cache and which extras are installed."""

import importlib.metadata
import importlib.util
import os
import platform
import sys
from pathlib import Path

from ..diskcache import CACHE_ENV, cache_folder

# extra name -> (module it brings, distribution whose version is shown, what it is for)
EXTRAS = {
    "test": ("pytest", "pytest", "the test suite"),
    "usd": ("pxr", "usd-core", "USD grooms in, animated USD curves out (--usd)"),
    "bench": ("cosseratbench", "cosseratbench", "taichi-hair bench --cosseratbench"),
    "mitsuba": ("mitsuba", "mitsuba", "the fibre shading's reference in tests/test_fibre.py"),
    "cluster": ("distributed", "distributed", "--workers / --scheduler (Dask)"),
}
ARCH_BUILDS = ("cuda", "vulkan", "metal")  # asked of Taichi (opengl's probe crashes without a display)


def _version(distribution: str) -> str | None:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return None


def cache_location() -> Path:
    """Where Taichi keeps compiled kernels between runs: TI_OFFLINE_CACHE_FILE_PATH, else
    Taichi's default (~/.cache/taichi/ticache)."""
    import taichi as ti
    return Path(os.environ.get("TI_OFFLINE_CACHE_FILE_PATH") or ti.lang.impl.default_cfg().offline_cache_file_path)


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else 0


def _geometry_cache() -> str:
    folder = cache_folder()
    if folder is None:
        return f"off ({CACHE_ENV}=off): head and bust distance grids and grooms are computed in every run"
    return (f"{folder} ({_size(folder) / 1e6:.1f} MB; {CACHE_ENV} moves it, {CACHE_ENV}=off turns it off; "
            f"distance grids and grooms computed once)")


def report() -> list[tuple[str, str]]:
    """(label, value) rows; starts no Taichi program (no kernels, no ti.init)."""
    import taichi as ti
    from taichi._lib import core
    cache = cache_location()
    ti.set_logging_level(ti.ERROR)  # the probes log "libcuda.so lib not found" where there is no GPU
    try:
        arches = ["cpu"] + [a for a in ARCH_BUILDS if getattr(core, f"with_{a}")()]
    finally:
        ti.set_logging_level(ti.WARN)
    rows = [("taichi_hair", _version("taichi_hair") or "not installed (run from a checkout)"),
            ("python", f"{platform.python_version()} ({sys.executable})"),
            ("platform", f"{platform.platform()}, {os.cpu_count()} CPU cores"),
            ("taichi", _version("taichi") or "?"),
            ("numpy", _version("numpy") or "?"),
            ("arches available", ", ".join(arches) + " (taichi_hair's default: cpu)"),
            ("kernel cache", f"{cache} ({_size(cache) / 1e6:.1f} MB; TI_OFFLINE_CACHE_FILE_PATH moves it; "
                             f"a cold cache compiles kernels again on the first frame)"),
            ("geometry cache", _geometry_cache())]
    for extra, (module, distribution, purpose) in EXTRAS.items():
        found = importlib.util.find_spec(module) is not None
        state = f"installed ({distribution} {_version(distribution) or '?'})" if found else \
            f"not installed: pip install -e '.[{extra}]'"
        rows.append((f"extra [{extra}]", f"{state}; {purpose}"))
    return rows


def main(args) -> int:
    rows = report()
    width = max(len(label) for label, _ in rows)
    for label, value in rows:
        print(f"{label:<{width}}  {value}")
    return 0


def add_parser(sub):
    p = sub.add_parser("doctor", help="print versions, arches, the kernel cache and the installed extras")
    p.set_defaults(func=main)
