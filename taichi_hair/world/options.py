"""The options of a simulation as typed, frozen data, each checked once when it is made:

- `SolverOptions`: how the guide strands are stepped (integrator, projection, root, twist,
  strain, tolerances and caps, the stability bound's factor, strand-strand and hair-hair
  coupling). Every refusal of one option beside another lives here (`SolverOptions.__post_init__`
  for the options alone, `SolverOptions.for_groom` for those that depend on the groom and its
  materials).
- `Environment`: what acts on the hair from outside: gravity, air drag, wind, the head's motion
  and touch tools.

A `Scene` holds both; `Simulator(groom, material, dt=..., solver=..., environment=..., head=...)`
takes them; the solver's stage plan is derived from them. The older flat keywords
(`Simulator(twist="kmoch", drag=5e-4)`) build these objects (`split_keywords`).
"""

from dataclasses import dataclass, fields, replace

import numpy as np

from .forces import Grab, HairInteraction, Hand, StrandContact, Wind
from ..rods.materials import per_strand_materials
from ..rods.modes import Integrator, Projection, Root, Strain, Twist
from ..validation import integer, real, vector3

DEFAULT_PROJECTION_TOL = 1e-6  # max |C_j| / |ebar_j|^2: positions are float64 in both precisions
DEFAULT_PROJECTION_ITERATIONS = 100
# the quasistatic solve's default iteration cap: shaken elliptic curls snapping through between
# branches took up to 112 Newton iterations under the rotation measure (48 under DER), where the
# Hessian is indefinite and its Gauss-Newton fallback converges linearly
DEFAULT_TWIST_ITERATIONS = 300
DEFAULT_MAX_SUBSTEPS = 1000  # automatic substeps per step at most: past it a scene is refused
DEFAULT_MAX_SPEED = 100.0  # [m/s] a node faster than this counts as a blow-up
SCENE_DRAG = 5e-4  # [N s/m per metre] a Scene's default drag: still air on hair plus its damping

IMPLICIT_KMOCH_REFUSAL = (
    "twist='kmoch' on elliptic strands (ellipticity > 1) runs with integrator='explicit': the rule's "
    "twist forces are stiffer than bending and the implicit step's matrix does not hold them (use "
    "twist='quasistatic' with the implicit step; docs/model.md, \"The implicit step\")")

IMPLICIT_FROZEN_ELLIPTIC_REFUSAL = (
    "twist='none' on elliptic strands (ellipticity > 1) runs with integrator='explicit': with the "
    "angles frozen the implicit step's matrix has no angle columns and leaves out how the material "
    "frames turn with the positions, which an elliptic section's bending feels; in its stability "
    "matrix (float32) a 5 mm curl of ellipticity 1.5 gained all of its energy in play within 0.2 s and "
    "curls of ellipticity 4 diverged (use twist='quasistatic' with the implicit step; docs/model.md, "
    "\"The implicit step\")")

ROTATION_KMOCH_REFUSAL = (
    "twist='kmoch' on elliptic strands runs with strain='der' (or strain=None): Kmoch's rule was built "
    "on the DER measure, and under strain='rotation' an undamped elliptic curl (ellipticity 4) swinging "
    "for 0.5 s gained 1.1e-7 J, a quarter of its peak kinetic energy, at every step size tried (DER: no "
    "gain); use twist='quasistatic' for the rotation measure (docs/model.md, \"Strains from rotations\")")


def _flag(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


@dataclass(frozen=True, kw_only=True)
class SolverOptions:
    """How the guide strands are stepped. Modes take a member or its string; a string is kept
    as the member (`SolverOptions(twist="kmoch").twist is Twist.KMOCH`).

    integrator: "explicit" (symplectic Euler within the stability bound) or "implicit"
        (linearised BDF2, any dt; needs a held root; no SHAKE, no extensible edges, no strand
        contact).
    projection: the explicit step's inextensibility projection, "fast" or "shake".
    root: how node 0 is held: "clamped", "pinned", "edge" or "free".
    twist: "quasistatic", "kmoch" or "none".
    strain: "rotation", "der" or None (rotation, but der for a groom carrying its own rest
        curvatures or under twist="kmoch"; `for_groom` resolves it).
    extensible: edges stretch with axial stiffness EA (explicit integrator).
    projection_tol: max |C_j| / |ebar_j|^2 left by the projection (None: 1e-6, both precisions);
        projection_iterations: its cap.
    twist_tol: the quasistatic solve's scaled residual (None: 1e-10 float64, 1e-5 float32);
        twist_iterations: its cap.
    stability_factor: c of the explicit bound h = c ds^2 sqrt(rho A / EI), in (0, 2) (None: 0.5,
        or 0.4 with strand contact). max_substeps: automatic substeps per step at most.
    max_speed [m/s]: a node faster than this is a blow-up. strict: refuse a dt past the bound
        instead of substepping. strand_steps: past the bound, each strand takes as many of the
        substeps as its own bound needs (a divisor of them; explicit step without hair
        interaction, strand contact or touch tools); False: every strand takes every substep.
    hair_interaction: a HairInteraction or None; strand_contact: a StrandContact or None."""

    integrator: Integrator = Integrator.EXPLICIT
    projection: Projection = Projection.FAST
    root: Root = Root.CLAMPED
    twist: Twist = Twist.QUASISTATIC
    strain: Strain | None = None
    extensible: bool = False
    projection_tol: float | None = None
    projection_iterations: int = DEFAULT_PROJECTION_ITERATIONS
    twist_tol: float | None = None
    twist_iterations: int = DEFAULT_TWIST_ITERATIONS
    stability_factor: float | None = None
    max_substeps: int = DEFAULT_MAX_SUBSTEPS
    max_speed: float = DEFAULT_MAX_SPEED
    strict: bool = False
    strand_steps: bool = True
    hair_interaction: HairInteraction | None = None
    strand_contact: StrandContact | None = None

    def __post_init__(self):
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731 (frozen)
        for name, mode in (("integrator", Integrator), ("projection", Projection), ("root", Root),
                           ("twist", Twist)):
            put(name, mode.parse(name, getattr(self, name)))
        if self.strain is not None:
            if self.strain not in Strain.names():
                raise ValueError(f"strain must be one of {Strain.names()} or None (rotation, or der for a "
                                 f"groom with its own rest curvatures or under twist='kmoch'), got {self.strain!r}")
            put("strain", Strain.parse("strain", self.strain))
        put("extensible", _flag("extensible", self.extensible))
        put("strict", _flag("strict", self.strict))
        put("strand_steps", _flag("strand_steps", self.strand_steps))
        for name in ("projection_iterations", "twist_iterations", "max_substeps"):
            put(name, integer(name, getattr(self, name), low=1))
        if self.projection_tol is not None:
            put("projection_tol", real("projection_tol", self.projection_tol, low=0.0, high=1.0, low_open=True,
                                       high_open=True))
        if self.twist_tol is not None:
            put("twist_tol", real("twist_tol", self.twist_tol, low=0.0, low_open=True))
        if self.stability_factor is not None:
            put("stability_factor", real("stability_factor", self.stability_factor, low=0.0, high=2.0,
                                         low_open=True, high_open=True))
        put("max_speed", real("max_speed", self.max_speed, "m/s", low=0.0, low_open=True))
        if self.hair_interaction is not None and not isinstance(self.hair_interaction, HairInteraction):
            raise ValueError(f"hair_interaction must be a HairInteraction or None, got "
                             f"{type(self.hair_interaction).__name__}")
        if self.strand_contact is not None and not isinstance(self.strand_contact, StrandContact):
            raise ValueError(f"strand_contact must be a StrandContact or None, got "
                             f"{type(self.strand_contact).__name__}")
        self._refuse_pairs()

    def _refuse_pairs(self):
        """The pairs of options that do not run together, each refused in its own words."""
        if self.integrator is not Integrator.IMPLICIT:
            return
        if self.projection is Projection.SHAKE:
            raise ValueError("projection='shake' is the explicit step's projection: it runs with "
                             "integrator='explicit' (the implicit step keeps energy by itself)")
        if self.extensible:
            raise ValueError("extensible=True runs with integrator='explicit' (the implicit step holds "
                             "the edge lengths inside its solve)")
        if self.strand_contact is not None:
            raise ValueError("strand_contact runs with integrator='explicit' (the implicit step has no "
                             "strand-strand contact)")
        if self.root is Root.FREE:
            raise ValueError("integrator='implicit' needs a held root (root='clamped', 'pinned' or "
                             "'edge'); a free root (root='free') runs with integrator='explicit'")

    def for_groom(self, groom, material) -> "SolverOptions":
        """These options for `groom` made of `material` (one Material or one per strand): the
        strain measure resolved, and the refusals that depend on the groom's rest curvatures or
        on elliptic strands applied."""
        elliptic = any(m.ellipticity > 1.0 for m in per_strand_materials(material, groom.n_strands))
        strain = self.strain
        if strain is None:
            strain = Strain.DER if groom.rest_curvature is not None or self.twist is Twist.KMOCH else Strain.ROTATION
        elif strain is Strain.ROTATION and groom.rest_curvature is not None:
            raise ValueError("strain='rotation' cannot take this groom's own rest curvatures (e.g. from "
                             "sag_free): they are the DER measure's; use strain='der' or strain=None")
        elif strain is Strain.ROTATION and self.twist is Twist.KMOCH and elliptic:
            raise ValueError(ROTATION_KMOCH_REFUSAL)
        if self.integrator is Integrator.IMPLICIT and elliptic:
            # measured: every elliptic kmoch case of the stability matrix diverged or gained energy
            if self.twist is Twist.KMOCH:
                raise ValueError(IMPLICIT_KMOCH_REFUSAL)
            if self.twist is Twist.NONE:
                raise ValueError(IMPLICIT_FROZEN_ELLIPTIC_REFUSAL)
        return replace(self, strain=strain)


@dataclass(frozen=True, kw_only=True)
class Environment:
    """What acts on the hair from outside.

    gravity [m/s^2]; drag: air-drag coefficient nu [N s/m per metre of strand] (each node feels
    -nu l_i (v - u_air)); default 0 here, SCENE_DRAG (5e-4) in a Scene; wind: None (still air),
    a 3-vector [m/s] or a `Wind` (gusts, turbulence), which acts through drag (needs drag > 0);
    motion: None or a callable t [s] -> (R [3, 3], t [3] m) moving the head (taichi_hair.world.
    motion); touch: Hand and Grab tools."""

    gravity: tuple = (0.0, 0.0, -9.81)
    drag: float = 0.0
    wind: object = None
    motion: object = None
    touch: tuple = ()

    def __post_init__(self):
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731 (frozen)
        put("gravity", tuple(float(g) for g in vector3("gravity", self.gravity, "m/s^2")))
        put("drag", real("drag", self.drag, "N s/m per metre", low=0.0))
        if self.wind is not None and not isinstance(self.wind, Wind):
            try:
                put("wind", tuple(float(w) for w in vector3("wind", self.wind, "m/s")))
            except ValueError:
                raise ValueError(f"wind must be a Wind or a finite 3-vector in m/s, got {self.wind!r}") from None
        if self.motion is not None and not callable(self.motion):
            raise ValueError("motion must be a callable t -> (rotation 3x3, translation [3]) or None")
        if not isinstance(self.touch, (tuple, list)):
            raise ValueError(f"touch must be a tuple of Hand and Grab tools, got {type(self.touch).__name__}")
        put("touch", tuple(self.touch))
        for k, tool in enumerate(self.touch):
            if not isinstance(tool, (Hand, Grab)):
                raise ValueError(f"touch[{k}] must be a Hand or a Grab, got {type(tool).__name__}")
        if self.has_wind and self.drag == 0:
            raise ValueError("wind acts through air drag: give drag > 0 N s/m per metre of strand "
                             "(human hair in air: about 1e-4 to 1e-3)")

    @property
    def has_wind(self) -> bool:
        """A Wind, or a non-zero air velocity."""
        return isinstance(self.wind, Wind) or (self.wind is not None and any(self.wind))

    @property
    def air_velocity(self):
        """The wind as the solver takes it: a Wind, or a float64 [3] array (zeros in still air)."""
        return self.wind if isinstance(self.wind, Wind) else np.array(self.wind or (0.0, 0.0, 0.0))


SOLVER_KEYWORDS = tuple(f.name for f in fields(SolverOptions))
ENVIRONMENT_KEYWORDS = tuple(f.name for f in fields(Environment))


def split_keywords(solver, environment, keywords: dict, owner: str, aliases=None):
    """(SolverOptions, Environment) from base objects (None: the defaults) and flat keywords
    naming their fields, which replace the base's (`aliases` maps an older spelling to a field,
    e.g. root_motion -> motion). TypeError naming `owner` for a keyword that is neither."""
    aliases = aliases or {}
    solver = SolverOptions() if solver is None else solver
    environment = Environment() if environment is None else environment
    if not isinstance(solver, SolverOptions):
        raise ValueError(f"solver must be a SolverOptions or None, got {type(solver).__name__}")
    if not isinstance(environment, Environment):
        raise ValueError(f"environment must be an Environment or None, got {type(environment).__name__}")
    solver_changes, environment_changes = {}, {}
    for name, value in keywords.items():
        field_name = aliases.get(name, name)
        if field_name in SOLVER_KEYWORDS:
            solver_changes[field_name] = value
        elif field_name in ENVIRONMENT_KEYWORDS:
            environment_changes[field_name] = value
        else:
            allowed = ", ".join(SOLVER_KEYWORDS + ENVIRONMENT_KEYWORDS + tuple(aliases))
            raise TypeError(f"{owner} got an unexpected keyword {name!r} (allowed: {allowed})")
    if solver_changes:
        solver = replace(solver, **solver_changes)
    if environment_changes:
        environment = replace(environment, **environment_changes)
    return solver, environment
