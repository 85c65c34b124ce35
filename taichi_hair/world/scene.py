"""A scene is data: head (colliders and a mesh to draw), groom, material, head motion, wind,
touch tools and hair-hair interaction, handed to `Simulator.from_scene`."""

from dataclasses import dataclass, field

import numpy as np

from .colliders import Capsule, Ellipsoid, MeshCollider, Plane, Sphere, host_distance
from .forces import Grab, Hand, Wind
from ..rods.groom import Groom
from .forces import HairInteraction, StrandContact
from ..rods.materials import Material, per_strand_materials
from ..rods.state import STRAINS
from ..rods.twist import TWIST_MODES
from ..validation import real

STRAIN_CHOICES = (None,) + STRAINS  # None: rotation, or der for a groom with its own rest curvatures

COLLIDERS = (Sphere, Ellipsoid, Capsule, Plane, MeshCollider)


@dataclass(frozen=True, kw_only=True)
class Head:
    """A rigid head: colliders (in head coordinates when attached="head", else world) and
    optionally its triangle mesh (vertices [V, 3] m, faces [F, 3]) for rendering, and the
    `HeadModel` it came from (scalp marks, for growing roots)."""

    colliders: tuple = ()
    mesh: tuple | None = None
    model: object = None

    def __post_init__(self):
        for k, c in enumerate(self.colliders):
            if not isinstance(c, COLLIDERS):
                raise ValueError(f"head.colliders[{k}] must be a Sphere, Ellipsoid, Capsule, Plane or "
                                 f"MeshCollider, got {type(c).__name__}")
        if self.mesh is not None:
            vertices, faces = (np.asarray(a) for a in self.mesh)
            if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
                raise ValueError("head.mesh must be (vertices [V, 3], faces [F, 3])")
            if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
                raise ValueError("head.mesh faces index vertices out of range")

    def distance_field(self):
        """The head's colliders as one host-side distance field (object with sample(points [M, 3])
        -> [M] m and gradient(points) -> [M, 3]) in head coordinates, for grooming: strands grown
        with it avoid the neck and shoulders as well as the skull. World-attached colliders count
        at the rest pose."""
        return ColliderUnion(self.colliders)

    @classmethod
    def sphere(cls, radius: float = 0.1, centre=(0.0, 0.0, 0.0), margin: float = 0.002,
               friction: float = 0.3) -> "Head":
        return cls(colliders=(Sphere(centre=centre, radius=radius, margin=margin, friction=friction),))

    @classmethod
    def ellipsoid(cls, radii=(0.08, 0.1, 0.115), centre=(0.0, 0.0, 0.0), margin: float = 0.002,
                  friction: float = 0.3) -> "Head":
        return cls(colliders=(Ellipsoid(centre=centre, radii=radii, margin=margin, friction=friction),))

    @classmethod
    def default(cls, margin: float = 0.002, friction: float = 0.3, spacing: float = 0.004) -> "Head":
        """The project's own head mesh (taichi_hair.world.headmesh) as a distance-grid collider riding
        on the head; its neck capsule turns with the head (a shake turns the neck too), the
        shoulder capsules stay with the body (world)."""
        from .headmesh import default_head
        from .sdf import SignedDistanceGrid
        model = default_head()
        grid = SignedDistanceGrid.from_mesh(model.vertices, model.faces, spacing=spacing)
        colliders = [MeshCollider(grid=grid, margin=margin, friction=friction, attached="head")]
        colliders += [Capsule(p0=tuple(p0), p1=tuple(p1), radius=float(r), margin=margin,
                              friction=friction, attached="head" if k == 0 else "world")
                      for k, (p0, p1, r) in enumerate(model.capsules)]
        return cls(colliders=tuple(colliders), mesh=(model.vertices, model.faces), model=model)


class ColliderUnion:
    """Signed distance to the union of colliders (min over them), on the host."""

    def __init__(self, colliders):
        self.colliders = tuple(colliders)

    def _distances(self, points):
        return np.stack([host_distance(c, points) for c in self.colliders])

    def sample(self, points):
        points = np.asarray(points, dtype=np.float64)
        return self._distances(points).min(axis=0) if self.colliders else np.full(len(points), np.inf)

    def gradient(self, points, h=1e-4):
        points = np.asarray(points, dtype=np.float64)
        return np.stack([(self.sample(points + h * e) - self.sample(points - h * e)) / (2 * h)
                         for e in np.eye(3)], axis=1)


INTEGRATORS = ("explicit", "implicit")  # symplectic Euler; linearised BDF2 (solver/implicit.py)
# the explicit step's inextensibility projection (solver/step.py): "fast" (Goldenthal et al.'s
# fast projection: first order, it damps) or "shake" (constraint forces along the start-of-step
# gradient: keeps an undamped swing's energy)
PROJECTIONS = ("fast", "shake")
# how node 0 is held (solver/step.py ROOT_CODES): "free" holds no node (a loose strand, or one
# held only by pins and clips)
ROOT_MODES = ("clamped", "pinned", "edge", "free")


@dataclass(frozen=True, kw_only=True)
class Scene:
    """Everything a simulation needs, as data.

    groom: the rest shapes; material: one Material or one per strand; head: a Head or None;
    motion: callable t -> (R, t) moving the head (taichi_hair.world.motion has nod, shake, turntable,
    jerk and keyframes) or None; wind: a Wind, a 3-vector [m/s] or None; touch: Hand and Grab
    tools; hair_interaction: a HairInteraction or None; strand_contact: a StrandContact (strands
    that do not pass through each other: braids, ponytails, loose strands) or None; gravity [m/s^2]; drag [N s/m per metre
    of strand] (default 5e-4: still air on hair plus the damping real hair shows); twist mode;
    integrator: "explicit" (default) or "implicit" (see Simulator); projection: the explicit
    step's projection, "fast" (default) or "shake" (see Simulator); root: how node 0 is held,
    "clamped" (default), "pinned", "edge" or "free" (loose strands: see Simulator); extensible:
    the edges stretch with axial stiffness EA (ropes, soft rods; see Simulator); strain: the
    strain measure, "rotation", "der" or None (default: rotation, or der for a groom with its
    own rest curvatures; see Simulator)."""

    groom: Groom
    material: object = field(default_factory=Material)
    head: Head | None = None
    motion: object = None
    wind: object = None
    touch: tuple = ()
    hair_interaction: HairInteraction | None = None
    strand_contact: StrandContact | None = None
    gravity: tuple = (0.0, 0.0, -9.81)
    drag: float = 5e-4
    twist: str = "quasistatic"
    integrator: str = "explicit"
    projection: str = "fast"
    root: str = "clamped"
    extensible: bool = False
    strain: str | None = None

    def __post_init__(self):
        if self.root not in ROOT_MODES:
            raise ValueError(f"root must be one of {ROOT_MODES}, got {self.root!r}")
        check_common_inputs(groom=self.groom, twist=self.twist, motion=self.motion, motion_name="motion",
                            wind=(0.0, 0.0, 0.0) if self.wind is None else self.wind, touch=self.touch,
                            hair_interaction=self.hair_interaction, gravity=self.gravity, drag=self.drag,
                            integrator=self.integrator, strand_contact=self.strand_contact,
                            projection=self.projection, extensible=self.extensible, strain=self.strain)
        per_strand_materials(self.material, self.groom.n_strands)
        if self.head is not None and not isinstance(self.head, Head):
            raise ValueError(f"head must be a taichi_hair.Head or None, got {type(self.head).__name__}")

    def simulator_options(self) -> dict:
        """Keyword arguments of `Simulator` that this scene sets."""
        return {"gravity": tuple(self.gravity), "drag": self.drag,
                "wind": (0.0, 0.0, 0.0) if self.wind is None else self.wind,
                "root_motion": self.motion, "touch": tuple(self.touch),
                "colliders": () if self.head is None else self.head.colliders,
                "hair_interaction": self.hair_interaction, "twist": self.twist,
                "integrator": self.integrator, "strand_contact": self.strand_contact,
                "root": self.root, "projection": self.projection, "extensible": self.extensible,
                "strain": self.strain}


def check_common_inputs(*, groom, twist, motion, motion_name, wind, touch, hair_interaction, gravity, drag,
                        integrator="explicit", strand_contact=None, projection="fast", extensible=False,
                        strain=None):
    """The inputs a Scene and a Simulator share, checked in one place: ValueError naming the
    parameter and what it allows. motion_name: what the caller calls the head motion."""
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
    if projection not in PROJECTIONS:
        raise ValueError(f"projection must be one of {PROJECTIONS}, got {projection!r}")
    if projection == "shake" and integrator == "implicit":
        raise ValueError("projection='shake' is the explicit step's projection: it runs with "
                         "integrator='explicit' (the implicit step keeps energy by itself)")
    if strain not in STRAIN_CHOICES:
        raise ValueError(f"strain must be one of {STRAIN_CHOICES}, got {strain!r}")
    if not isinstance(extensible, (bool, np.bool_)):
        raise ValueError(f"extensible must be True or False, got {extensible!r}")
    if extensible and integrator == "implicit":
        raise ValueError("extensible=True runs with integrator='explicit' (the implicit step holds "
                         "the edge lengths inside its solve)")
    if not isinstance(groom, Groom):
        raise ValueError(f"groom must be a taichi_hair.Groom, got {type(groom).__name__}")
    if twist not in TWIST_MODES:
        raise ValueError(f"twist must be one of {TWIST_MODES}, got {twist!r}")
    if motion is not None and not callable(motion):
        raise ValueError(f"{motion_name} must be a callable t -> (rotation 3x3, translation [3]) or None")
    if not isinstance(wind, Wind) and not _finite_vector3(wind):
        raise ValueError(f"wind must be a Wind or a finite 3-vector in m/s, got {wind!r}")
    for k, tool in enumerate(touch):
        if not isinstance(tool, (Hand, Grab)):
            raise ValueError(f"touch[{k}] must be a Hand or a Grab, got {type(tool).__name__}")
    if hair_interaction is not None and not isinstance(hair_interaction, HairInteraction):
        raise ValueError(f"hair_interaction must be a HairInteraction or None, got {type(hair_interaction).__name__}")
    if strand_contact is not None and not isinstance(strand_contact, StrandContact):
        raise ValueError(f"strand_contact must be a StrandContact or None, got {type(strand_contact).__name__}")
    if strand_contact is not None and integrator == "implicit":
        raise ValueError("strand_contact runs with integrator='explicit' (the implicit step has no "
                         "strand-strand contact)")
    if not _finite_vector3(gravity):
        raise ValueError(f"gravity must be a finite 3-vector in m/s^2, got {gravity!r}")
    real("drag", drag, "N s/m per metre", low=0.0)


def _finite_vector3(value) -> bool:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return v.shape == (3,) and bool(np.all(np.isfinite(v)))
