"""Pixar's USD (`pxr`, from the optional extra `usd`), imported by the first call that needs it
rather than at module import time."""

EXTRA_HINT = "pip install 'taichi_hair[usd]'"


def require_pxr():
    """(Usd, UsdGeom, Sdf, Vt, Gf), or ImportError naming the extra."""
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, Vt
    except ImportError as exc:
        raise ImportError(f"USD support needs Pixar's usd-core: {EXTRA_HINT}") from exc
    return Usd, UsdGeom, Sdf, Vt, Gf
