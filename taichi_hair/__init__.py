"""taichi_hair: strand hair simulation after Kmoch, Bonanni & Magnenat-Thalmann (2009).

Public API (see README.md):
    th.init(arch="cpu", precision="float32")
    th.Groom.from_polylines / straight / wavy / curly
    th.Material(youngs_modulus=..., shear_modulus=..., radius=..., density=..., ellipticity=1.0)
    th.Simulator(groom, material, twist="kmoch")
"""

from .groom import Groom
from .materials import Material
from .runtime import init
from .simulator import Simulator
from .stability import SimulationDiverged

__all__ = ["init", "Groom", "Material", "Simulator", "SimulationDiverged"]
