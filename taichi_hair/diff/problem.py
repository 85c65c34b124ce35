"""`Differentiable`: a simulated motion of guide strands whose loss has reverse-mode gradients
with respect to the material, air drag, the rest shape, the initial velocities and the head's
motion (docs/differentiable.md).

The forward model is the simulator's explicit step (docs/model.md, "Time step") with a clamped
root, the DER strain measure and the quasistatic twist, written as kernels for Taichi's autodiff:
a fixed number of projection iterations and of twist Newton steps per step (so the function
differentiated is exactly the one computed), and a frictionless sphere for the head."""

import math

import numpy as np
import taichi as ti

from ..rods.groom import Groom
from ..rods.materials import Material, per_strand_materials
from ..rods.state import align_to_curvature, perpendicular_unit
from ..solver.stability import SimulationDiverged, stable_time_step
from ..validation import integer, real, vector3
from ..world.colliders import Sphere
from .dynamics import DynamicsKernels
from .fields import DERIVED_FIELDS, INPUT_FIELDS, allocate, slot_bytes
from .frames import FrameKernels
from .tape import SegmentKernels
from .tridiagonal import SolveOp, TridiagonalKernels

WRT = ("youngs_modulus", "shear_modulus", "density", "radius", "drag", "rest_positions", "initial_velocities",
       "motion")
MATERIAL_WRT = ("youngs_modulus", "shear_modulus", "density", "radius")
# a step whose edge lengths are off by more than this (relative) after its projection failed
FAILED_RESIDUAL = 1e-2


@ti.data_oriented
class Differentiable(FrameKernels, DynamicsKernels, TridiagonalKernels, SegmentKernels):
    """A differentiable run of `groom` (th.Groom, the rest shape at the head's rest pose) made of
    `material` (a th.Material, or one per strand) for `seconds` [s] in steps of `dt` [s].

    gravity [m/s^2]; drag: air drag nu [N s/m per metre of strand]; head: None or a th.Sphere
    (the head's collider, frictionless, at the rest pose); motion: None (still) or pose
    parameters [M, 6] (rotation vector [rad], translation [m]) at M >= 2 times evenly spread
    over [0, seconds], linear in between, turning about `pivot` [m]; initial_velocities: None or
    [S, N, 3] m/s; initial_positions: None (the rest positions) or [S, N, 3] m, the start at the
    rest pose, held fixed (the rest shape stays a separate input); projection_iterations,
    twist_iterations: fixed per step (the forward run's residuals are in `health` after a
    run); memory: bytes the segment arrays may take (their
    length, hence the number of checkpoints, follows from it); segment_steps: that length
    chosen directly (default: about the square root of the step count, within `memory`)."""

    def __init__(self, groom: Groom, material, *, dt: float, seconds: float, gravity=(0.0, 0.0, -9.81),
                 drag: float = 0.0, head=None, motion=None, pivot=(0.0, 0.0, 0.0), initial_velocities=None,
                 initial_positions=None,
                 projection_iterations: int = 3, twist_iterations: int = 2, memory: float = 2e9,
                 segment_steps: int | None = None):
        if not isinstance(groom, Groom):
            raise ValueError(f"groom must be a th.Groom, got {type(groom).__name__}")
        if groom.rest_curvature is not None or groom.rest_twist is not None:
            raise ValueError("groom must carry no rest_curvature or rest_twist of its own (e.g. sag_free's): "
                             "Differentiable measures the rest shape from rest_positions, which it differentiates")
        materials = per_strand_materials(material, groom.n_strands)
        self.per_strand = not isinstance(material, Material)
        self.dt = real("dt", dt, "s", low=0.0, low_open=True)
        self.seconds = real("seconds", seconds, "s", low=0.0, low_open=True)
        steps = self.seconds / self.dt
        if abs(steps - round(steps)) > 1e-6 * max(1.0, steps):
            raise ValueError(f"seconds must be a whole number of steps dt, got seconds={seconds!r}, dt={dt!r}")
        self.n_steps = int(round(steps))
        self.projection_iterations = integer("projection_iterations", projection_iterations, low=1, high=50)
        self.twist_iterations = integer("twist_iterations", twist_iterations, low=1, high=50)
        drag = real("drag", drag, "N s/m^2", low=0.0)
        bound = stable_time_step(groom, materials, drag)
        if self.dt > bound:
            raise ValueError(f"dt must be at most {bound:.3g} s (the explicit step's stability bound for this "
                             f"groom and material), got {dt!r}")
        if head is not None and not isinstance(head, Sphere):
            raise ValueError(f"head must be None or a th.Sphere, got {type(head).__name__}")
        self.collide = head is not None
        self.own_start = initial_positions is not None
        self.n_strands, self.n_nodes = groom.n_strands, groom.max_nodes
        self.groom, self.materials = groom, materials
        self.key_values = self._motion(motion)
        shape = (self.n_strands, self.n_nodes, 3)
        velocities = np.zeros(shape) if initial_velocities is None else \
            self._array("initial_velocities", initial_velocities, shape)
        start = None if initial_positions is None else self._array("initial_positions", initial_positions, shape)
        gravity, pivot = vector3("gravity", gravity, "m/s^2"), vector3("pivot", pivot, "m")
        budget = real("memory", memory, "bytes", low=0.0, low_open=True)
        per_slot = slot_bytes(self.n_strands, self.n_nodes, self.projection_iterations, self.twist_iterations)
        if segment_steps is None:
            segment_steps = min(self.n_steps, max(1, math.ceil(math.sqrt(self.n_steps))), max(1, budget // per_slot))
        self.segment_steps = integer("segment_steps", segment_steps, low=1, high=self.n_steps)
        self.n_segments = -(-self.n_steps // self.segment_steps)
        allocate(self, self.n_strands, self.n_nodes, len(self.key_values), self.segment_steps,
                 self.n_segments, self.projection_iterations, self.twist_iterations)
        self.length_solve = SolveOp(self, self.pdiag, self.pup, self.pres, self.pc, self.pd, self.lam)
        self.twist_solve = SolveOp(self, self.tdiag, self.tup, self.tres, self.tc, self.td, self.tstep)
        self._fill(groom, materials, gravity, drag, head, pivot, velocities)
        if start is not None:
            self.start_x.from_numpy(start)
        self.health = {}

    # ---------------------------------------------------------------- inputs
    def _motion(self, motion) -> np.ndarray:
        if motion is None:
            return np.zeros((2, 6))
        keys = np.asarray(motion, dtype=np.float64)
        if keys.ndim != 2 or keys.shape[1] != 6 or keys.shape[0] < 2 or not np.all(np.isfinite(keys)):
            raise ValueError(f"motion must be None or finite pose parameters [M >= 2, 6] (rotation vector rad, "
                             f"translation m), got shape {getattr(keys, 'shape', None)}")
        return keys

    def _array(self, name, value, shape) -> np.ndarray:
        array = np.asarray(value, dtype=np.float64)
        if array.shape != tuple(shape) or not np.all(np.isfinite(array)):
            raise ValueError(f"{name} must be finite with shape {list(shape)}, got {list(array.shape)}")
        return array

    def _fill(self, groom, materials, gravity, drag, head, pivot, velocities):
        self.node_count.from_numpy(groom.node_counts.astype(np.int32))
        for name in MATERIAL_WRT + ("ellipticity",):
            getattr(self, name).from_numpy(np.array([getattr(m, name) for m in materials]))
        self.drag[None] = drag
        self.gravity[None] = gravity
        self.pivot[None] = pivot
        if head is not None:
            self.sphere_centre[None] = np.asarray(head.centre, dtype=np.float64)
            self.sphere_radius[None] = head.radius
        self.keys.from_numpy(self.key_values)
        self.rest_x.from_numpy(np.nan_to_num(groom.positions))
        self.initial_v.from_numpy(velocities)
        self._rest_angles(groom, materials)

    def _rest_angles(self, groom, materials):
        """Rest angles and the root's reference as the simulator's build takes them (elliptic
        strands: m1 along the curvature; docs/model.md, "Energy"); held fixed when the rest
        positions change."""
        root_t = groom.positions[:, 1] - groom.positions[:, 0]
        root_t /= np.linalg.norm(root_t, axis=1)[:, None]
        root_u = perpendicular_unit(root_t)
        self.root_u_head.from_numpy(root_u)
        self.rest_theta.fill(0)
        rest_theta = np.zeros((self.n_strands, self.n_nodes - 1))
        elliptic = np.array([m.ellipticity > 1.0 for m in materials])
        if elliptic.any():
            for kernel in self.rest_kernels()[:4]:  # lengths and root tangent, masses, frames, binormals
                kernel()
            kb, u = self.rest_kb.to_numpy(), self.rest_u.to_numpy()
            edges = np.diff(groom.positions, axis=1)
            t = edges / np.linalg.norm(edges, axis=2, keepdims=True)
            aligned = align_to_curvature(kb, u, np.cross(t, u), groom.node_counts)
            rest_theta[elliptic] = aligned[elliptic]
            c, s_ = np.cos(rest_theta[:, :1]), np.sin(rest_theta[:, :1])
            root_u = c * root_u + s_ * np.cross(root_t, root_u)
            rest_theta -= rest_theta[:, :1]
            self.root_u_head.from_numpy(root_u)
        self.rest_theta.from_numpy(np.nan_to_num(rest_theta))
        rest_twist = np.zeros((self.n_strands, self.n_nodes))
        rest_twist[:, 1:-1] = np.diff(rest_theta, axis=1)
        self.rest_twist.from_numpy(np.nan_to_num(rest_twist))

    def update(self, **values) -> None:
        """Set inputs for the next run without rebuilding: any of youngs_modulus, shear_modulus,
        density, radius (a number, or [S] when the material was given per strand), drag, rest_positions
        [S, N, 3], initial_velocities [S, N, 3], motion [M, 6]."""
        for name, value in values.items():
            if name in MATERIAL_WRT:
                array = np.broadcast_to(np.asarray(value, dtype=np.float64), (self.n_strands,))
                if not np.all(np.isfinite(array)) or np.any(array <= 0):
                    raise ValueError(f"{name} must be finite and > 0, got {value!r}")
                getattr(self, name).from_numpy(np.ascontiguousarray(array))
            elif name == "drag":
                self.drag[None] = real("drag", value, "N s/m^2", low=0.0)
            elif name == "rest_positions":
                self.rest_x.from_numpy(self._array(name, value, (self.n_strands, self.n_nodes, 3)))
            elif name == "initial_velocities":
                self.initial_v.from_numpy(self._array(name, value, (self.n_strands, self.n_nodes, 3)))
            elif name == "motion":
                self.key_values = self._array(name, value, self.key_values.shape)
                self.keys.from_numpy(self.key_values)
            else:
                raise ValueError(f"update takes {', '.join(WRT)}; got {name!r}")

    # ---------------------------------------------------------------- runs
    def step_of(self, times) -> np.ndarray:
        """Step indices of `times` [s] (each a whole number of steps dt in [0, seconds])."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        steps = t / self.dt
        index = np.round(steps).astype(int)
        if t.ndim != 1 or np.any(np.abs(steps - index) > 1e-6 * np.maximum(1.0, steps)) or \
                np.any(index < 0) or np.any(index > self.n_steps):
            raise ValueError(f"times must be whole numbers of steps dt={self.dt} within [0, {self.seconds}] s, "
                             f"got {times!r}")
        return index

    def positions(self, times) -> np.ndarray:
        """Node positions [K, S, N, 3] m at `times` [K] s (NaN on padded nodes)."""
        steps = self.step_of(times)
        found = self.forward_pass(steps)
        return np.stack([found[n] for n in steps])

    def value_and_grad(self, loss, wrt=WRT, times=None):
        """(loss value, {name: d loss / d input}) for `loss`: th.losses.positions(target, times)
        or a callable taking positions [K, S, N, 3] at `times` and returning (value, d value /
        d positions). Each gradient has the shape of its input (a number for a material value
        given once for every strand)."""
        wrt = [wrt] if isinstance(wrt, str) else list(wrt)
        for name in wrt:
            if name not in WRT:
                raise ValueError(f"wrt entries must be among {', '.join(WRT)}, got {name!r}")
        times = getattr(loss, "times", times)
        if times is None:
            raise ValueError("times must be given for a loss without its own times (loss.times)")
        steps = self.step_of(times)
        found = self.forward_pass(steps)
        value, d_positions = loss(np.stack([found[n] for n in steps]))
        d_positions = np.nan_to_num(np.asarray(d_positions, dtype=np.float64))
        seeds = {}
        for n, g in zip(steps, d_positions):
            seeds[int(n)] = seeds.get(int(n), 0.0) + g
        for name in INPUT_FIELDS + DERIVED_FIELDS:
            getattr(self, name).grad.fill(0)
        self.backward_pass(seeds)
        return float(value), {name: self._gradient(name) for name in wrt}

    def _gradient(self, name):
        if name in MATERIAL_WRT:
            g = getattr(self, name).grad.to_numpy()
            return g if self.per_strand else float(g.sum())
        if name == "drag":
            return float(self.drag.grad[None])
        field = {"rest_positions": self.rest_x, "initial_velocities": self.initial_v, "motion": self.keys}[name]
        return field.grad.to_numpy()

    def check_health(self, step: int, k: int) -> None:
        """Refuse a run whose state at slot k (global step `step`) is not finite or whose edges
        are stretched past FAILED_RESIDUAL; record the largest residuals."""
        strain, twist_step = (float(value) for value in self.residuals(k))
        self.health["strain"] = max(self.health.get("strain", 0.0), strain)
        self.health["twist_step"] = max(self.health.get("twist_step", 0.0), twist_step)
        if not (strain <= FAILED_RESIDUAL and math.isfinite(twist_step)):
            raise SimulationDiverged(f"the differentiable run diverged at step {step} (edge strain {strain:.3g}); "
                                     f"take a smaller dt than {self.dt}", step=step, strand=-1)

    @ti.kernel
    def residuals(self, k: ti.i32) -> ti.types.vector(2, float):
        """(largest |e|/|ebar| - 1 at slot k, largest last twist Newton step [rad] into slot k)."""
        strain = ti.cast(0.0, float)
        step = ti.cast(0.0, float)
        for s in range(self.n_strands):
            n = self.node_count[s]
            for j in range(n - 1):
                length = (self.x[k, s, j + 1] - self.x[k, s, j]).norm()
                ti.atomic_max(strain, ti.abs(length / self.rest_length[s, j] - 1.0))
                if k > 0:
                    ti.atomic_max(step, ti.abs(self.tstep[k - 1, self.twist_iterations - 1, s, j]))
        return ti.Vector([strain, step])
