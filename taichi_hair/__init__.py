"""taichi_hair: strand hair simulation after Kmoch, Bonanni & Magnenat-Thalmann (2009).

Public API (see README.md):
    th.init(arch="cpu", precision="float32")
    th.Groom.from_polylines / straight / wavy / curly
    th.Material(youngs_modulus=..., shear_modulus=..., radius=..., density=..., ellipticity=1.0)
    th.Simulator(groom, material, twist="quasistatic"), th.Simulator.from_scene(scene, dt=...)
    th.sag_free(groom, material, gravity, head) -> (groom, SagFreeReport)
    th.Scene(head=..., groom=..., material=..., solver=th.SolverOptions(...), environment=th.Environment(...))
        (or the options' fields flat: th.Scene(groom=..., twist=..., motion=..., wind=...))
    th.Shot(frames=..., fps=..., dt=..., width=..., height=..., dense_strands=...): how a scene script is filmed
    th.Differentiable(groom, material, dt=..., seconds=...).value_and_grad(th.losses.positions(target, times), wrt=[...])
"""

from . import runtime as _runtime  # first: imports Taichi with its banner off (th.init prints it on stderr)

from .app.runner import Shot
from .world.colliders import Capsule, Ellipsoid, MeshCollider, Plane, Sphere
from .world.forces import Grab, Hand, Wind
from .rods.groom import Groom
from .hair.guides import GuideSelection, animate_style, pick_guides, style_interpolator
from .hair.hairfile import HairFile, HairFileError, read_hair, read_obj_polylines, write_hair, write_obj_polylines
from .world.headmesh import HeadModel, default_head, read_obj_mesh, write_obj_mesh
from .hair.interpolate import Interpolator
from .world.motion import Jerk, Keyframes, Nod, Shake, Still, Turntable, compose
from .hair.roots import sample_scalp, scalp_groom
from .world.sdf import SignedDistanceGrid
from .world.forces import HairInteraction, StrandContact
from .rods.materials import Material
from .runtime import init
from .hair.sagfree import SagFreeReport, sag_free
from .world.scene import Head, Scene
from .world.options import Environment, SolverOptions
from .rods.modes import Integrator, Projection, Root, Strain, Twist
from .solver.simulator import Simulator
from .diff.problem import Differentiable
from .diff import losses
from .solver.stability import SimulationDiverged
from .hair.usd import UsdCurves, UsdCurvesWriter, read_usd_curves, write_usd_curves

__all__ = ["init", "Shot", "Groom", "Material", "Simulator", "SimulationDiverged", "Scene", "Head",
           "SolverOptions", "Environment", "Integrator", "Projection", "Root", "Strain", "Twist",
           "Sphere", "Ellipsoid", "Capsule", "Plane", "MeshCollider", "Wind", "Hand", "Grab",
           "HairInteraction", "StrandContact", "Still", "Nod", "Shake", "Turntable", "Jerk", "Keyframes", "compose",
           "HeadModel", "default_head", "read_obj_mesh", "write_obj_mesh", "SignedDistanceGrid",
           "sample_scalp", "scalp_groom", "Interpolator", "HairFile", "HairFileError", "read_hair",
           "write_hair", "read_obj_polylines", "write_obj_polylines", "GuideSelection",
           "pick_guides", "animate_style", "style_interpolator", "sag_free", "SagFreeReport", "read_usd_curves",
           "write_usd_curves", "UsdCurvesWriter", "UsdCurves", "Differentiable", "losses"]
