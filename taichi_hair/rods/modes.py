"""The named modes of the model and its solver, as `str` enums: each member equals (and hashes
as) its lower-case name, so `Twist.KMOCH == "kmoch"` and a scene may spell a mode either way.
Kernels see a mode's `code` (its place in the class) as a compile-time constant.

The models behind them are in docs/model.md: the twist solve ("Twist"), the strain measure
("Strains from rotations"), how node 0 is held ("The clamp at the root"), the integrator ("The
implicit step") and the explicit step's projection ("Time step").
"""

from enum import Enum


class Mode(str, Enum):
    """A mode: a str equal to its value, printed as its value."""

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec) -> str:
        return format(self.value, spec)

    def __hash__(self) -> int:
        return hash(self.value)

    def __repr__(self) -> str:
        return repr(self.value)

    @property
    def code(self) -> int:
        """The mode's place in its class: the number a kernel compiles against."""
        return list(type(self)).index(self)

    @classmethod
    def names(cls) -> tuple:
        """The values a user may write, in the class's order."""
        return tuple(m.value for m in cls)

    @classmethod
    def parse(cls, name: str, value):
        """`value` (a member or its string) as a member; ValueError naming `name` and the allowed
        values otherwise."""
        if isinstance(value, str):
            for member in cls:
                if member.value == value:
                    return member
        raise ValueError(f"{name} must be one of {cls.names()}, got {value!r}")


class Twist(Mode):
    """How the material angles follow the centreline each step."""

    NONE = "none"  # the angles stay as they are
    KMOCH = "kmoch"  # Kmoch et al.'s rule for elliptic hair: cheap, not an energy minimum
    QUASISTATIC = "quasistatic"  # Newton on dE/dtheta = 0 per strand: the energy's minimum


class Strain(Mode):
    """The strain measure of bending and twist."""

    DER = "der"  # Discrete Elastic Rods' curvature binormal and twist as a difference of angles
    ROTATION = "rotation"  # the rotation vector between consecutive material frames (exact on helices)


class Root(Mode):
    """How node 0 of each strand is held."""

    CLAMPED = "clamped"  # node 0 rides on the head; bending and twist against the head's root frame
    PINNED = "pinned"  # node 0 rides on the head; the strand swings freely about it
    EDGE = "edge"  # the first edge rides rigidly on the head; bending starts at node 1
    FREE = "free"  # nothing held: loose strands, or strands held by pins and clips only


class Integrator(Mode):
    """The time integrator."""

    EXPLICIT = "explicit"  # symplectic Euler, substepped within the stability bound
    IMPLICIT = "implicit"  # linearised BDF2, bending solved per strand: any dt


class Projection(Mode):
    """The explicit step's inextensibility projection."""

    FAST = "fast"  # Goldenthal et al.'s fast projection (first order, damps)
    SHAKE = "shake"  # constraint forces along the start-of-step edges (keeps a swing's energy)
