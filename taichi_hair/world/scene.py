"""A scene is data: head (colliders and a mesh to draw), groom, material, head motion, wind,
touch tools and hair-hair interaction, handed to `Simulator.from_scene`."""

from dataclasses import dataclass

import numpy as np

from .colliders import ATTACHMENTS, Capsule, Ellipsoid, MeshCollider, Plane, Sphere, host_distance
from ..rods.groom import Groom
from ..rods.materials import Material, per_strand_materials
from ..rods.modes import Integrator, Projection, Root, Strain
from ..validation import choice
from .options import (ENVIRONMENT_KEYWORDS, SCENE_DRAG, SOLVER_KEYWORDS, Environment, SolverOptions,
                      split_keywords)

STRAIN_CHOICES = (None,) + Strain.names()  # None: rotation, or der for a groom with its own rest curvatures

COLLIDERS = (Sphere, Ellipsoid, Capsule, Plane, MeshCollider)


@dataclass(frozen=True, kw_only=True)
class Head:
    """A rigid head: colliders (in head coordinates when attached="head", else world) and
    optionally its triangle mesh (vertices [V, 3] m, faces [F, 3]) for rendering, the
    `HeadModel` it came from (scalp marks, for growing roots), and a body mesh (vertices [V, 3]
    m, faces [F, 3]: the default head's bust) in the coordinates of `body_attached`: "world"
    (drawn where it is while the head turns on it) or "head" (turned with the head, as on a
    turntable); its collider, if any, is one of `colliders`, attached the same way."""

    colliders: tuple = ()
    mesh: tuple | None = None
    model: object = None
    body: tuple | None = None
    body_attached: str = "world"

    def __post_init__(self):
        for k, c in enumerate(self.colliders):
            if not isinstance(c, COLLIDERS):
                raise ValueError(f"head.colliders[{k}] must be a Sphere, Ellipsoid, Capsule, Plane or "
                                 f"MeshCollider, got {type(c).__name__}")
        choice("body_attached", self.body_attached, ATTACHMENTS)
        for name in ("mesh", "body"):
            if getattr(self, name) is not None:
                vertices, faces = (np.asarray(a) for a in getattr(self, name))
                if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
                    raise ValueError(f"head.{name} must be (vertices [V, 3], faces [F, 3])")
                if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
                    raise ValueError(f"head.{name} faces index vertices out of range")

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
    def default(cls, margin: float = 0.002, friction: float = 0.3, spacing: float = 0.004,
                body: str = "world") -> "Head":
        """The project's own head mesh (taichi_hair.world.headmesh) as a distance-grid collider riding
        on the head, with its neck capsule, which turns with the head (a shake turns the neck
        too), on the bust (taichi_hair.world.bust: neck, shoulders and chest, one smooth mesh),
        drawn as it is and colliding through its own distance grid. body: "world", the bust
        stays where it is while the head shakes or nods on it; "head", it turns with the head
        (a turntable shot turns the whole model)."""
        choice("body", body, ATTACHMENTS)
        from .bust import default_bust, default_bust_grid
        from .headmesh import default_head
        from .sdf import SignedDistanceGrid
        model = default_head()
        grid = SignedDistanceGrid.from_mesh(model.vertices, model.faces, spacing=spacing)
        colliders = [MeshCollider(grid=grid, margin=margin, friction=friction, attached="head")]
        colliders += [Capsule(p0=tuple(p0), p1=tuple(p1), radius=float(r), margin=margin,
                              friction=friction, attached="head") for p0, p1, r in model.capsules]
        colliders.append(MeshCollider(grid=default_bust_grid(), margin=margin, friction=friction,
                                      attached=body))
        return cls(colliders=tuple(colliders), mesh=(model.vertices, model.faces), model=model,
                   body=default_bust(), body_attached=body)


@dataclass(frozen=True, eq=False)
class ColliderUnion:
    """Signed distance to the union of colliders (min over them), on the host."""

    colliders: tuple

    def __post_init__(self):
        object.__setattr__(self, "colliders", tuple(self.colliders))

    def _distances(self, points):
        return np.stack([host_distance(c, points) for c in self.colliders])

    def sample(self, points):
        points = np.asarray(points, dtype=np.float64)
        return self._distances(points).min(axis=0) if self.colliders else np.full(len(points), np.inf)

    def gradient(self, points, h=1e-4):
        points = np.asarray(points, dtype=np.float64)
        return np.stack([(self.sample(points + h * e) - self.sample(points - h * e)) / (2 * h)
                         for e in np.eye(3)], axis=1)


INTEGRATORS = Integrator.names()
PROJECTIONS = Projection.names()
ROOT_MODES = Root.names()

# a Scene's flat keywords and the option each one sets (`Scene(twist="kmoch")` is
# `Scene(solver=SolverOptions(twist="kmoch"))`); `--set drag=...` follows the same map
FIELD_ALIASES = {**{name: f"solver.{name}" for name in SOLVER_KEYWORDS},
                 **{name: f"environment.{name}" for name in ENVIRONMENT_KEYWORDS}}


@dataclass(frozen=True, init=False)
class Scene:
    """Everything a simulation needs, as data.

    groom: the rest shapes; material: one Material or one per strand; head: a Head (colliders
    and a mesh to draw) or None; solver: a SolverOptions (integrator, projection, root, twist,
    strain, strand contact, hair interaction, ...); environment: an Environment (gravity, drag,
    wind, the head's motion, touch tools; a Scene's default drag is SCENE_DRAG, 5e-4 N s/m per
    metre: still air on hair plus the damping real hair shows).

    Every field of SolverOptions and Environment may also be given flat, as a keyword
    (`Scene(groom=g, twist="kmoch", drag=1e-3, motion=Shake())`): it replaces that field of
    `solver` / `environment`, and reads back as an attribute (`scene.twist`, `scene.motion`)."""

    FIELD_ALIASES = FIELD_ALIASES

    groom: Groom
    material: object
    head: Head | None
    solver: SolverOptions
    environment: Environment

    def __init__(self, *, groom: Groom, material=None, head: Head | None = None,
                 solver: SolverOptions | None = None, environment: Environment | None = None, **options):
        if not isinstance(groom, Groom):
            raise ValueError(f"groom must be a taichi_hair.Groom, got {type(groom).__name__}")
        material = Material() if material is None else material
        per_strand_materials(material, groom.n_strands)
        if head is not None and not isinstance(head, Head):
            raise ValueError(f"head must be a taichi_hair.Head or None, got {type(head).__name__}")
        if environment is None:
            environment = Environment(drag=options.pop("drag", SCENE_DRAG), wind=options.pop("wind", None))
        solver, environment = split_keywords(solver, environment, options, "Scene")
        for name, value in (("groom", groom), ("material", material), ("head", head), ("solver", solver),
                            ("environment", environment)):
            object.__setattr__(self, name, value)

    def __getattr__(self, name):
        """The flat names of the options (scene.twist, scene.drag, scene.motion, ...)."""
        path = FIELD_ALIASES.get(name)
        if path is None:
            raise AttributeError(f"Scene has no attribute {name!r}")
        part, field_name = path.split(".")
        return getattr(object.__getattribute__(self, part), field_name)

    def simulator_options(self) -> dict:
        """Keyword arguments of `Simulator` that this scene sets."""
        return {"solver": self.solver, "environment": self.environment, "head": self.head}
