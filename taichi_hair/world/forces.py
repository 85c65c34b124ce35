"""Scene forces beyond gravity: wind (gusts in time, a smooth noise field in space) acting
through air drag, and touch: a moving sphere ("hand") that pushes hair, and a grab tool that
pulls the nodes within a radius toward a moving point."""

from dataclasses import dataclass
import math

import numpy as np
import taichi as ti

from ..rods.arrays import vec3
from ..validation import real, vector3

N_GUSTS = 3  # sinusoids summed for the gust signal
N_MODES = 8  # Fourier modes of the spatial noise field


@dataclass(frozen=True, kw_only=True)
class Wind:
    """Air velocity u(x, t) = velocity * (1 + gust(t)) + turbulence * noise(x, t) [m/s].

    velocity: mean wind [m/s]. gust_amplitude: relative size of the gusts (0 = steady; gust(t)
    sums three seeded sinusoids near gust_frequency [Hz], normalised to peak gust_amplitude).
    turbulence: rms speed [m/s] of a smooth divergence-free-ish noise field of eddy size
    turbulence_scale [m], advected by the mean wind. Wind acts through the simulator's drag,
    so it needs drag > 0."""

    velocity: tuple = (1.0, 0.0, 0.0)
    gust_amplitude: float = 0.0
    gust_frequency: float = 0.5
    turbulence: float = 0.0
    turbulence_scale: float = 0.1
    seed: int = 0

    def __post_init__(self):
        vector3("velocity", self.velocity)
        real("gust_amplitude", self.gust_amplitude, "(relative)", low=0.0)
        real("gust_frequency", self.gust_frequency, "Hz", low=0.0, low_open=True)
        real("turbulence", self.turbulence, "m/s", low=0.0)
        real("turbulence_scale", self.turbulence_scale, "m", low=0.0, low_open=True)

    def tables(self):
        """Kernel tables: gusts [N_GUSTS] vec3 (amplitude, angular frequency, phase) and noise
        modes [N_MODES, 2] vec3: (wavevector [1/m], (omega [1/s], phase, 0)) and amplitude [m/s]."""
        rng = np.random.default_rng(self.seed)
        freqs = self.gust_frequency * rng.uniform(0.6, 1.6, N_GUSTS)
        gusts = np.stack([np.full(N_GUSTS, self.gust_amplitude / N_GUSTS), 2 * np.pi * freqs,
                          rng.uniform(0, 2 * np.pi, N_GUSTS)], axis=1)
        directions = rng.normal(size=(N_MODES, 3))
        directions /= np.linalg.norm(directions, axis=1)[:, None]
        k = 2 * np.pi / self.turbulence_scale * rng.uniform(0.7, 1.4, N_MODES)[:, None] * directions
        omega = k @ np.asarray(self.velocity, dtype=np.float64)  # frozen turbulence carried by the wind
        amplitude = np.cross(directions, rng.normal(size=(N_MODES, 3)))  # transverse: div-free
        amplitude *= self.turbulence * math.sqrt(2.0 / N_MODES) / np.linalg.norm(amplitude, axis=1)[:, None]
        modes = np.zeros((N_MODES, 3, 3))
        modes[:, 0] = k
        modes[:, 1, 0] = omega
        modes[:, 1, 1] = rng.uniform(0, 2 * np.pi, N_MODES)
        modes[:, 2] = amplitude
        return gusts, modes

    def at(self, points, t):
        """Air velocity [M, 3] at points [M, 3] and time t, on the host (same formula as kernels)."""
        gusts, modes = self.tables()
        factor = 1.0 + np.sum(gusts[:, 0] * np.sin(gusts[:, 1] * t + gusts[:, 2]))
        u = np.tile(np.asarray(self.velocity, dtype=np.float64) * factor, (len(points), 1))
        for k, (w, phase, _), a in modes:
            u += np.sin(points @ k - w * t + phase)[:, None] * a
        return u


@ti.func
def gusting_wind(base, gusts: ti.template(), t):
    """The mean wind [m/s] at time t [s]: base (1 + sum_g a_g sin(omega_g t + phi_g)), the same
    everywhere (gusts [G] vec3: amplitude, omega [1/s], phase)."""
    factor = 1.0
    for g in range(gusts.shape[0]):
        factor += gusts[g][0] * ti.sin(gusts[g][1] * t + gusts[g][2])
    return base * factor


@ti.func
def air_velocity(wind, modes: ti.template(), t, p):
    """The air's velocity [m/s] at point p [m] and time t [s]: the gusting wind (gusting_wind)
    plus the turbulence's Fourier modes (Wind.tables)."""
    u = wind
    for m in range(modes.shape[0]):
        u += ti.sin(modes[m, 0].dot(p) - modes[m, 1][0] * t + modes[m, 1][1]) * modes[m, 2]
    return u


@dataclass(frozen=True, kw_only=True)
class Hand:
    """A moving sphere of `radius` [m] whose centre follows `path(t) -> [3]` m (world
    coordinates): hair cannot enter it and slides over it with `friction`."""

    path: object
    radius: float = 0.04
    margin: float = 0.001
    friction: float = 0.5

    def __post_init__(self):
        _check_path(self.path)
        real("radius", self.radius, "m", low=0.0, low_open=True)
        real("margin", self.margin, "m", low=0.0)
        real("friction", self.friction, "(Coulomb coefficient)", low=0.0)


@dataclass(frozen=True, kw_only=True)
class Grab:
    """A grab tool: while active(t) is true (default: always) every free node within `radius`
    [m] of the point `path(t) -> [3]` m is pulled toward it by a spring of `stiffness` [N/m]
    per node, fading linearly to zero at the radius."""

    path: object
    radius: float = 0.03
    stiffness: float = 0.05
    active: object = None

    def __post_init__(self):
        _check_path(self.path)
        real("radius", self.radius, "m", low=0.0, low_open=True)
        real("stiffness", self.stiffness, "N/m", low=0.0, low_open=True)
        if self.active is not None and not callable(self.active):
            raise ValueError("active must be a callable t -> bool, or None (always active)")

    def is_active(self, t) -> bool:
        return True if self.active is None else bool(self.active(t))


def _check_path(path):
    if not callable(path):
        raise ValueError("path must be a callable t [s] -> position [3] in metres")
    vector3("path(0)", path(0.0))


HAND, GRAB = 0, 1


def touch_table(tools, times):
    """Per-step tool state for kernels: positions [len(times), T] vec3 (centres / grab points, or
    far away while a grab is inactive) and params [T] vec4 (kind, radius, margin or stiffness,
    friction)."""
    params = np.zeros((max(len(tools), 1), 4))
    positions = np.zeros((len(times), max(len(tools), 1), 3))
    for k, tool in enumerate(tools):
        if isinstance(tool, Hand):
            params[k] = [HAND, tool.radius, tool.margin, tool.friction]
        else:
            params[k] = [GRAB, tool.radius, tool.stiffness, 0.0]
        for step, t in enumerate(times):
            p = vector3(f"touch[{k}].path({t:g})", tool.path(t))
            inactive = isinstance(tool, Grab) and not tool.is_active(t)
            positions[step, k] = np.full(3, 1e6) if inactive else p
    return params, positions


@ti.func
def grab_force(tools: ti.template(), points: ti.template(), now, p):
    """Sum of the grab springs on a node at p [m] -> force [N]."""
    f = vec3(0.0)
    for k in range(tools.shape[0]):
        if ti.cast(tools[k][0], ti.i32) == GRAB:
            q = points[now, k] - p
            dist = q.norm()
            if dist < tools[k][1]:
                f += tools[k][2] * (1.0 - dist / tools[k][1]) * q
    return f


@ti.func
def grab_stiffness(tools: ti.template(), points: ti.template(), now, p):
    """-d grab_force / d p at p [N/m] (float64 3x3), made positive semi-definite for the
    implicit step: a spring k (1 - d/R) q toward the grab point (q = point - p, d = |q|) has
    stiffness k (1 - d/R) across q and k (1 - 2 d/R) along it, which turns negative past half
    the radius (the pull fades faster than it grows); that part is clamped at 0."""
    out = ti.types.matrix(3, 3, ti.f64)(0.0)
    for k in range(tools.shape[0]):
        if ti.cast(tools[k][0], ti.i32) == GRAB:
            q = ti.cast(points[now, k] - p, ti.f64)
            dist = q.norm()
            radius = ti.cast(tools[k][1], ti.f64)
            if dist < radius:
                across = 1.0 - dist / radius
                along = ti.max(0.0, 1.0 - 2.0 * dist / radius)
                qq = ti.types.matrix(3, 3, ti.f64)(0.0)
                if dist > 0.0:
                    qq = (q / dist).outer_product(q / dist)
                out += ti.cast(tools[k][2], ti.f64) * (across * (ti.Matrix.identity(ti.f64, 3) - qq) + along * qq)
    return out


@dataclass(frozen=True, kw_only=True)
class HairInteraction:
    """Grid hair-hair interaction. cell_size [m]; repulsion c^2 [m^2/s^2]: a node in hair denser
    than max_density feels the acceleration -c^2 grad(rho) / max_density; friction [1/s]: the rate
    at which node velocities relax toward the local hair velocity; max_density [kg/m^3] (None:
    the 90th percentile of the occupied cells' density in the groomed pose)."""

    cell_size: float = 0.02
    repulsion: float = 1.0
    friction: float = 5.0
    max_density: float | None = None

    def __post_init__(self):
        real("cell_size", self.cell_size, "m", low=0.0, low_open=True)
        real("repulsion", self.repulsion, "m^2/s^2", low=0.0)
        real("friction", self.friction, "1/s", low=0.0)
        if self.max_density is not None:
            real("max_density", self.max_density, "kg/m^3", low=0.0, low_open=True)


@dataclass(frozen=True, kw_only=True)
class StrandContact:
    """Strand-strand contact (rod-rod): segments of different strands, and of one strand further
    apart along it than `neighbour_gap` allows, are kept at least the sum of their contact radii
    apart, inside the projection (docs/model.md, "Strand contact"), with Coulomb friction.

    radius [m]: the contact radius of every strand (None: each strand's material radius).
    friction: Coulomb coefficient (0: frictionless; >= 0). self_contact: whether a strand
    collides with itself. iterations: contact passes per step, each followed by the length
    projection (>= 1). tolerance: relative penetration (of the radius sum) a step may leave."""

    radius: float | None = None
    friction: float = 0.0
    self_contact: bool = True
    iterations: int = 10
    tolerance: float = 0.05

    def __post_init__(self):
        if self.radius is not None:
            real("radius", self.radius, "m", low=0.0, low_open=True)
        real("friction", self.friction, "(Coulomb coefficient)", low=0.0)
        if not isinstance(self.self_contact, (bool, np.bool_)):
            raise ValueError(f"self_contact must be True or False, got {self.self_contact!r}")
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, (int, np.integer)) \
                or not 1 <= self.iterations <= 1000:
            raise ValueError(f"iterations must be an integer in [1, 1000], got {self.iterations!r}")
        real("tolerance", self.tolerance, "(relative)", low=0.0, low_open=True)
        if self.tolerance >= 1.0:
            raise ValueError(f"tolerance must be in (0, 1) (relative to the radius sum), got {self.tolerance!r}")
