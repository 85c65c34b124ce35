"""Hair material: elastic moduli, cross-section and density, and the rod stiffnesses they give.

The cross-section is an ellipse of equal area to a circle of `radius`, with semi-axes
a = r sqrt(e) (major, along the material direction m1) and b = r / sqrt(e) (minor), where e is
the ellipticity a/b >= 1. Stiffnesses (docs/model.md):
    EI1 = E pi a^3 b / 4   [N m^2]  pairs with w1 = kb . m2 (bending about m2: the stiff axis)
    EI2 = E pi a b^3 / 4   [N m^2]  pairs with w2 = -kb . m1 (bending about m1: the soft axis)
    GJ  = G pi a^3 b^3 / (a^2 + b^2)   [N m^2]   torsional stiffness
"""

from dataclasses import dataclass
import math

import numpy as np

from ..validation import is_real, real


@dataclass(frozen=True, kw_only=True)
class Material:
    """Elastic hair material (SI units). Defaults model human hair.

    youngs_modulus: E [Pa], > 0 (hair: 2e9 to 5e9).
    shear_modulus: G [Pa], > 0 (hair: about E / 3).
    radius: equivalent circular radius r [m], > 0 (hair: 20e-6 to 100e-6).
    density: rho [kg/m^3], > 0 (hair: about 1300).
    ellipticity: major/minor axis ratio a/b, >= 1 (1 round; curly hair up to about 1.5-2).
    """

    youngs_modulus: float = 3.0e9
    shear_modulus: float = 1.0e9
    radius: float = 40e-6
    density: float = 1300.0
    ellipticity: float = 1.0

    def __post_init__(self):
        real("youngs_modulus", self.youngs_modulus, "Pa", low=0.0, low_open=True)
        real("shear_modulus", self.shear_modulus, "Pa", low=0.0, low_open=True)
        real("radius", self.radius, "m", low=0.0, low_open=True)
        real("density", self.density, "kg/m^3", low=0.0, low_open=True)
        e = self.ellipticity
        if not (is_real(e) and math.isfinite(e) and e >= 1.0):
            raise ValueError(f"ellipticity must be a finite number >= 1 (major/minor axis ratio), got {e!r}")
        for name in ("youngs_modulus", "shear_modulus", "radius", "density", "ellipticity"):
            object.__setattr__(self, name, float(getattr(self, name)))  # np.float32 in, float64 math
        try:
            derived = (*self.bending_stiffness, self.twist_stiffness, self.linear_density)
        except OverflowError:
            derived = (math.inf,)
        if not all(math.isfinite(v) and v > 0 for v in derived):
            raise ValueError(f"youngs_modulus, shear_modulus, radius, density and ellipticity give a "
                             f"bending or twist stiffness or a linear density out of floating-point range "
                             f"(radius {self.radius!r} m, youngs_modulus {self.youngs_modulus!r} Pa); "
                             f"use physical values (hair: radius 20e-6 to 100e-6 m, E 2e9 to 5e9 Pa)")

    @property
    def semi_axes(self) -> tuple[float, float]:
        """(a, b) [m]: major and minor semi-axes of the equal-area ellipse."""
        root_e = math.sqrt(self.ellipticity)
        return self.radius * root_e, self.radius / root_e

    @property
    def area(self) -> float:
        """Cross-section area pi a b = pi r^2 [m^2]."""
        return math.pi * self.radius**2

    @property
    def linear_density(self) -> float:
        """Mass per unit length rho A [kg/m]."""
        return self.density * self.area

    @property
    def axial_stiffness(self) -> float:
        """EA [N]: stretch stiffness (used only by extensible strands, Simulator(extensible=True))."""
        return self.youngs_modulus * self.area

    @property
    def bending_stiffness(self) -> tuple[float, float]:
        """(EI1, EI2) [N m^2]: stiff (about m2) and soft (about m1) bending stiffness."""
        a, b = self.semi_axes
        return (self.youngs_modulus * math.pi * a**3 * b / 4.0,
                self.youngs_modulus * math.pi * a * b**3 / 4.0)

    @property
    def twist_stiffness(self) -> float:
        """GJ [N m^2]: torsional stiffness of the elliptic section."""
        a, b = self.semi_axes
        return self.shear_modulus * math.pi * a**3 * b**3 / (a**2 + b**2)


def per_strand_materials(material, n_strands: int) -> list[Material]:
    """Expand `material` (one Material, or a sequence with one per strand) to a list of length S."""
    if isinstance(material, Material):
        return [material] * n_strands
    materials = list(material)
    if len(materials) != n_strands:
        raise ValueError(f"material must be one Material or a sequence of {n_strands} (one per strand), "
                         f"got a sequence of {len(materials)}")
    for k, m in enumerate(materials):
        if not isinstance(m, Material):
            raise ValueError(f"material[{k}] must be a taichi_hair.Material, got {type(m).__name__}")
    return materials


def stiffness_table(materials: list[Material]) -> dict[str, np.ndarray]:
    """Per-strand arrays [S] of EI1, EI2, GJ [N m^2], linear density [kg/m] and EA [N]."""
    return {
        "ei1": np.array([m.bending_stiffness[0] for m in materials]),
        "ei2": np.array([m.bending_stiffness[1] for m in materials]),
        "gj": np.array([m.twist_stiffness for m in materials]),
        "linear_density": np.array([m.linear_density for m in materials]),
        "axial": np.array([m.axial_stiffness for m in materials]),
    }
