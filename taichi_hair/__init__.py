"""taichi_hair: strand hair simulation after Kmoch, Bonanni & Magnenat-Thalmann (2009)."""

from .runtime import init

__all__ = ["init"]
