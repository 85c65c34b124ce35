"""cosseratbench solver adapter: taichi_hair scored by cosseratbench's scenarios and metrics.

Installed with the `bench` extra (`pip install taichi_hair[bench]`) and registered through the
entry point group `cosseratbench.solvers` as "taichi_hair" (the explicit step with the fast
projection, the default), "taichi_hair_shake" (the explicit step with `projection="shake"`),
"taichi_hair_stretch" (the explicit step with extensible edges, `extensible=True`) and
"taichi_hair_implicit", so `cosseratbench run -s taichi_hair` finds it. The core package never
imports this module (nor cosseratbench).

How a scenario maps onto taichi_hair (one rule for every scenario, no cases per name):

- Each rod is one strand of `n_elements` edges; E, G, radius, density become a round
  `Material`. Its stress-free shape is straight (explicit zero rest curvature), untwisted.
- The rod is unshearable and, as hair in Kmoch's model, inextensible; "taichi_hair_stretch"
  lets it stretch with EA = E A (`Simulator(extensible=True)`: each edge a compliant
  constraint in the projection) as the scenarios' Cosserat rods do, and there a rod that
  starts stretched (`rest_arc_length`) starts at the scenario's nodes, stretched. Otherwise
  such a rod starts at its unstretched length. The rest shape: every element keeps the direction it has in
  the scenario and gets length L / n_elements, walked from a clamped root, or both ways from
  the rod's middle node otherwise (two crossing ropes still cross there); the element at a
  clamped end points along the centerline's tangent there, to second order (the direction
  the clamp holds; the end chord is first order). Unstretched rods
  whose polyline chords fall short of L / n_elements get the same treatment, so the strand's
  length is always the scenario's unstretched length.
- Ends: the root is a held end (the driven one if its motion moves it, rather than only
  turning it about its axis); a rod whose start is free and end held is simulated from its end
  (nodes reversed and turned back on output). A clamped root is taichi_hair's clamped root
  (node 0 and the clamp's material frame held, bending from node 0); a pinned root is a pin on
  node 0 of a free strand (`root="free"`: held in place, free to turn and to spin; the implicit
  solver, which needs a held root, and the SHAKE solver take `root="pinned"`); both ends free
  is a free strand. A pinned tip is `add_pin` on the last node; a clamped tip is a clip on the
  last edge that holds its material frame (`hold_twist=True`), turned each frame by `turn_pin`
  when its motion turns it about its axis, and a slider (`slide=axis`) when it slides. A driven root's motion is the
  head motion.
- Contact between rods: several rods, or a scenario whose rods can reach themselves
  (`self_contact`), get `StrandContact` (radius = each rod's, the largest rod friction,
  self-contact as the scenario says).
- Loads are constant user forces on the end node, gravity is the simulator's gravity.
- Planes and cylinders are `Plane` and `Capsule` colliders in the world with margin = the
  rod's radius and the larger of the two Coulomb coefficients (taichi_hair's position-based
  friction). A capsule ends in hemispheres where the cylinder has flat ends: only different
  if a rod reaches past the cylinder's ends.
- Dynamic scenarios run with drag 0: no dissipation beyond the model's (the twist is
  quasistatic in Kmoch's model, which is its physics, not damping). Quasi-static scenarios
  add mass-proportional drag at twice the scenario's slowest frequency (critical damping of
  the slowest mode, PyElastica adapter's choice too): only the final state is scored.
- Time step: one simulator step per recorded frame; the simulator substeps to its explicit
  stability bound (`time_step_scale` scales its stability factor).
- Directors: d1 of each element is the material line m1 cos a + m2 sin a, a fixed per element
  at t = 0 so that d1 starts at `Rod.directors`: the same material line, carried by the
  material frame.

Not supported (NotImplementedError, reported "unsupported"): a root that slides, two driven ends
that both move, rods clamped and rods pinned or free at their roots in one scenario (one root
mode per simulator), ends held without twist-holding clips (older taichi_hair); with the implicit
solver, free rods, clamped tips and rod contact.
"""

from __future__ import annotations

import math
from importlib.metadata import PackageNotFoundError, version

import numpy as np

from cosseratbench.scenario import Cylinder, End, EndCondition, Motion, Plane, Rod, Scenario
from cosseratbench.solver import Capability, Diverged
from cosseratbench.trajectory import Trajectory

import taichi_hair as th
from taichi_hair import runtime
from taichi_hair.solver.stability import default_stability_factor

PRECISION = "float64"  # used when this adapter is the first to initialise Taichi
PROJECTION_ITERATIONS = 1000  # the projection's cap (the Simulator's default is 100)


def _version(package: str) -> str:
    try:
        return version(package)
    except PackageNotFoundError:
        return "unknown"


def _source_digest() -> str:
    """A short digest of taichi_hair's own sources (this adapter apart: cosseratbench digests it),
    so that saved runs are not reused after the simulator changes within one version number."""
    import hashlib
    from pathlib import Path

    here = Path(__file__).resolve()
    digest = hashlib.sha256()
    for path in sorted(here.parent.glob("*.py")):
        if path != here:
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:12]


def _ensure_taichi() -> str:
    """Initialise Taichi (CPU, float64) unless taichi_hair already did; returns the precision.
    A process whose Taichi was initialised by someone else cannot be used (its precision is
    unknown to taichi_hair)."""
    if runtime._state["precision"] is None:
        if runtime.taichi_is_initialized():
            raise RuntimeError("Taichi was initialised outside taichi_hair; the taichi_hair "
                               "adapter needs taichi_hair.init() (or to initialise it itself)")
        th.init(arch="cpu", precision=PRECISION)
    return runtime.precision()


def _twist_only(motion: Motion, axis: np.ndarray) -> bool:
    """Whether `motion` only turns its end about `axis` (no displacement): a clip can drive it."""
    displacement = np.asarray(motion.displacement, dtype=float)
    rotation = np.asarray(motion.rotation, dtype=float)
    across = rotation - np.outer(rotation @ axis, axis)
    return bool(np.all(np.abs(displacement) < 1e-12) and np.all(np.linalg.norm(across, axis=1) < 1e-9))


class _Strand:
    """One scenario rod as one strand: its nodes in simulation order and how ends map.

    The root is the end a head motion can carry: a held end, the driven one if its motion
    displaces it; with both ends free the strand has a free root. The other end is the tip: free,
    a pin (pinned), a twist-holding clip (clamped), turned in time if its motion only turns it
    about its axis, and sliding if it slides along an axis."""

    def __init__(self, rod: Rod, n_elements: int):
        self.rod = rod
        if n_elements < 2:
            raise NotImplementedError("taichi_hair needs at least 2 elements per rod")
        start, end = rod.condition(End.START), rod.condition(End.END)
        nodes = rod.nodes(n_elements)
        # the direction a clamp holds, the one its turns go about
        tangent = {End.START: _clamp_tangent(nodes), End.END: -_clamp_tangent(nodes[::-1])}
        self.axis = {}
        for e in End:
            motion = rod.motion(e)
            if motion is not None:
                self.axis[e] = (motion.axis if motion.slides_along is not None
                                else tangent[e])
        turns = {e: rod.motion(e) is not None and _twist_only(rod.motion(e), self.axis[e]) for e in End}
        if start is EndCondition.FREE or end is EndCondition.FREE:  # both free: a free root, as given
            self.reversed = start is EndCondition.FREE and end is not EndCondition.FREE
        else:  # both held: the root is the end a head motion must carry
            self.reversed = rod.end_motion is not None and not turns[End.END]
        self.root_end, self.tip_end = (End.END, End.START) if self.reversed else (End.START, End.END)
        self.motion = rod.motion(self.root_end)
        self.tip_motion = rod.motion(self.tip_end)
        if self.motion is not None and self.motion.slides_along is not None:
            raise NotImplementedError("a root that slides along an axis: taichi_hair's sliders are clips "
                                      "on a strand's last edge")
        if self.tip_motion is not None and not turns[self.tip_end]:
            raise NotImplementedError("a rod driven at both ends, or a driven end that moves rather than "
                                      "turns about its axis away from the root: taichi_hair drives one root "
                                      "and turns clips")
        if self.motion is not None and self.tip_motion is not None:
            raise NotImplementedError("a rod driven at both ends: taichi_hair drives only the root")
        d1 = rod.directors(n_elements)
        if self.reversed:
            nodes, d1 = nodes[::-1].copy(), d1[::-1].copy()
        self.scenario_nodes = nodes
        self.d1_start = d1
        # a clamped root stays where the scenario clamps it; any other strand keeps its middle
        # point in place (two ropes crossing still cross where they did, and a symmetric rope
        # stays symmetric)
        clamped_root = rod.condition(self.root_end) is EndCondition.CLAMPED
        clamped = (clamped_root, rod.condition(self.tip_end) is EndCondition.CLAMPED)
        self.rest_nodes = _unstretched(nodes, rod.length, 0 if clamped_root else None, clamped)
        # a clip turns about its own edge, which may point against the scenario's axis
        edge = self.rest_nodes[-1] - self.rest_nodes[-2]
        self.tip_sign = (float(np.sign(edge @ self.axis[self.tip_end])) if self.tip_motion is not None
                         else 1.0)

    def tip_angle(self, time: float) -> float:
        """The tip clip's turn [rad] about its axis at `time` (0 when the tip is not driven)."""
        motion = self.tip_motion
        if motion is None:
            return 0.0
        along = np.asarray(motion.rotation, dtype=float) @ self.axis[self.tip_end]
        return self.tip_sign * float(np.interp(time, motion.times, along))

    def to_scenario(self, values: np.ndarray) -> np.ndarray:
        """Per-node or per-element values [T, K, 3] back in the scenario's order."""
        return values[:, ::-1] if self.reversed else values

    def node_of(self, end: End) -> int:
        return 0 if end is self.root_end else len(self.rest_nodes) - 1


def _clamp_tangent(nodes: np.ndarray) -> np.ndarray:
    """The unit tangent of the curve through `nodes` [n + 1, 3] (evenly spaced along it) at
    node 0, to second order: (-3 x_0 + 4 x_1 - x_2) / 2h. The first chord is a first-order
    estimate: on twist's bump, height a (1 - cos 2 pi s / L) / 2 with zero slope at the clamps,
    it tilts by a pi^2 / n (2e-5 rad at 50 elements), this by a (2 pi)^4 L^3 / 8 n^3 (2e-7)."""
    if len(nodes) < 3:
        t = nodes[1] - nodes[0]
    else:
        t = -3.0 * nodes[0] + 4.0 * nodes[1] - nodes[2]
    return t / np.linalg.norm(t)


def _unstretched(nodes: np.ndarray, length: float, anchor: int | None = 0,
                 clamped: tuple[bool, bool] = (False, False)) -> np.ndarray:
    """The polyline with the same element directions and every element L / n long, walked both
    ways from node `anchor`, which stays where it is; anchor None: from the polyline's middle
    point (the middle node, or the middle of the middle element), so that a symmetric rope stays
    symmetric. Measured: anchored at node n // 2 of the 51-element crossing ropes, the walk
    shifted them by 0.1 mm off their symmetric start, and the upper rope then slid 6 mm along the
    lower one (a discrete rope rests lower with the load near a node), 6e-3 of shape error.

    clamped (first end, last end): a clamped end's element points along the curve's tangent
    at that end (`_clamp_tangent`), the direction the clamp holds. Measured on twist (50
    elements): with the first and last chords' tilt held by the clamps, a straight rod was not
    an equilibrium, and a rod held stable just below Greenhill's twist crept towards a bow that
    the twist amplified; the fit counted the creep as growth and read 0.987 of the twist."""
    e = np.diff(nodes, axis=0)
    t = e / np.linalg.norm(e, axis=1, keepdims=True)
    if clamped[0]:
        t[0] = _clamp_tangent(nodes)
    if clamped[1]:
        t[-1] = -_clamp_tangent(nodes[::-1])
    walked = np.vstack([np.zeros(3), np.cumsum(t * (length / len(e)), axis=0)])
    if anchor is not None:
        return nodes[anchor] + walked - walked[anchor]
    middle = [(len(nodes) - 1) // 2, len(nodes) // 2]  # one node twice, or the middle element's two
    return nodes[middle].mean(axis=0) + walked - walked[middle].mean(axis=0)


def _motion_callable(strand: _Strand):
    """Head motion x -> R x + t of the root: the Motion turns the end about its start point."""
    motion, p = strand.motion, strand.rest_nodes[0]

    def pose(time):
        displacement, rotation = motion.pose(float(time))
        return rotation, p + displacement - rotation @ p
    return pose


class TaichiHairSolver:
    """taichi_hair's Simulator (inextensible Discrete Elastic Rods, Kmoch et al. 2009) as a
    cosseratbench solver. See the module docstring for the mapping."""

    name = "taichi_hair"
    backend_version = (f"taichi_hair {_version('taichi_hair')} (sources {_source_digest()}), "
                       f"taichi {_version('taichi')}")
    # Inextensible and unshearable: no STRETCH (but taichi_hair_stretch), no SHEAR. Rod-rod and
    # self contact with Coulomb friction: StrandContact. Obstacles: Plane and Capsule colliders.
    capabilities = frozenset({Capability.CYLINDER_CONTACT, Capability.PLANE_CONTACT,
                              Capability.ROD_CONTACT, Capability.ROD_FRICTION})

    integrator = "explicit"
    projection = "fast"  # the explicit step's projection (Simulator's `projection`)
    extensible = False  # Simulator's `extensible` (explicit step)
    IMPLICIT_DT = 1e-3  # the implicit step's default dt [s] (Simulator's), at most

    def __init__(self, time_step_scale: float = 1.0) -> None:
        if not (math.isfinite(time_step_scale) and time_step_scale > 0):
            raise ValueError(f"time_step_scale must be > 0, got {time_step_scale!r}")
        self.time_step_scale = time_step_scale

    def _stability_factor(self, scenario: Scenario) -> float:
        """The Simulator's default factor for this scenario (0.4 with rod contact, else 0.5)
        scaled by `time_step_scale`."""
        return default_stability_factor(self._contact(scenario)) * self.time_step_scale

    @staticmethod
    def _contact(scenario: Scenario) -> bool:
        """Whether the rods get StrandContact: several rods, or rods that can reach themselves."""
        return len(scenario.rods) > 1 or scenario.self_contact

    # ---- what a run uses -----------------------------------------------------------------
    @staticmethod
    def _drag(scenario: Scenario) -> float:
        """Drag [N s/m per metre]: none for dynamics; for quasi-static scenarios a damping rate
        of twice the slowest frequency on the lightest rod (drag / (rho A) is the rate)."""
        if not scenario.quasi_static:
            return 0.0
        rate = 2.0 * scenario.slowest_frequency()
        return rate * min(r.material.density * r.area for r in scenario.rods)

    def _steps_per_frame(self, scenario: Scenario, n_frames: int) -> tuple[float, int]:
        """The simulator's dt and steps per frame: one frame, or a fraction of it under 0.5 s
        (explicit: the simulator substeps to its bound); implicit: a fraction of the frame
        under IMPLICIT_DT x time_step_scale, the implicit step's own default."""
        interval = scenario.duration / (n_frames - 1)
        longest = 0.5 if self.integrator == "explicit" else self.IMPLICIT_DT * self.time_step_scale
        steps = max(1, math.ceil(interval / longest - 1e-9))
        return interval / steps, steps

    def settings(self, scenario: Scenario, *, n_elements: int, n_frames: int) -> dict:
        precision = _ensure_taichi()
        dt, _ = self._steps_per_frame(scenario, n_frames)
        try:
            sim = self._build(scenario, n_elements, n_frames)[0]
            steps = {"time_step": sim.dt / sim.substeps, "substeps": sim.substeps}
        except NotImplementedError:  # run() raises it again, and the run is reported unsupported
            steps = {}
        return {
            "integrator": (f"symplectic Euler + {self.projection} projection"
                           f"{', compliant edges EA' if self.extensible else ''} (explicit)"
                           if self.integrator == "explicit" else
                           "linearised BDF2 with lengths in the solve + fast projection (implicit)"),
            **steps,
            "frame_step": dt,
            "stability_factor": self._stability_factor(scenario),
            "twist": "quasistatic",
            "precision": precision,
            "drag": self._drag(scenario),
            "damping_rate": 2.0 * scenario.slowest_frequency() if scenario.quasi_static else 0.0,
            "contact": "position-based, margin = rod radius" if scenario.obstacles else "none",
            "rod_contact": ("position-based segment-segment, radius = rod radius, "
                            f"self_contact={scenario.self_contact}"
                            if len(scenario.rods) > 1 or scenario.self_contact else "none"),
        }

    # ---- build and run -------------------------------------------------------------------
    def _build(self, scenario: Scenario, n_elements: int, n_frames: int):
        stability_factor = self._stability_factor(scenario)
        if stability_factor >= 2.0 and self.integrator == "explicit":
            raise NotImplementedError(
                f"a time step {self.time_step_scale:g}x the default: "
                f"at or past the explicit step's limit, which taichi_hair refuses to run")
        strands = [_Strand(rod, n_elements) for rod in scenario.rods]
        roots = {s.rod.condition(s.root_end) for s in strands}
        # a pinned root is a pin on node 0 of a free strand: held in place, free to turn and spin;
        # the implicit step needs a held root, and takes root="pinned" (which holds the spin), as
        # does SHAKE: with a pin on a free root node the undamped pendulum loses -8.1e-5 of its
        # swing in 5 s, with root="pinned" -1.3e-5 (a planar swing never spins the root)
        root = "clamped" if roots == {EndCondition.CLAMPED} else "free"
        if (self.integrator == "implicit" or self.projection == "shake") and roots == {EndCondition.PINNED}:
            root = "pinned"
        if root == "free" and EndCondition.CLAMPED in roots:
            raise NotImplementedError("rods clamped and rods pinned or free at their roots in one "
                                      "scenario: taichi_hair's root condition is per simulator")
        needs_pins = EndCondition.PINNED in roots or any(s.rod.condition(s.tip_end) is not EndCondition.FREE
                                                         for s in strands)
        if needs_pins and not hasattr(th.Simulator, "turn_pin"):
            raise NotImplementedError("a pinned root or a held tip needs Simulator.add_pin with "
                                      "twist-holding clips (not in this taichi_hair)")
        if self.integrator == "implicit" and (root == "free" or any(
                s.rod.condition(s.tip_end) is EndCondition.CLAMPED for s in strands)):
            raise NotImplementedError("a free rod or a clamped tip: the implicit step needs a held "
                                      "root and has no twist-holding clips")
        contact = self._contact(scenario)
        if contact and self.integrator == "implicit":
            raise NotImplementedError("rod-rod contact: the implicit step has none")
        motions = [s for s in strands if s.motion is not None]
        if motions and len(strands) > 1:
            raise NotImplementedError("a driven end with several rods: taichi_hair's head motion "
                                      "moves every root together")

        groom = th.Groom.from_polylines(np.stack([s.rest_nodes for s in strands]))
        groom = groom.with_rest_curvature(np.zeros(groom.positions.shape[:2] + (4,)))  # straight
        materials = [th.Material(youngs_modulus=s.rod.material.youngs_modulus,
                                 shear_modulus=s.rod.material.shear_modulus,
                                 radius=s.rod.radius, density=s.rod.material.density)
                     for s in strands]
        colliders = [self._collider(o, scenario) for o in scenario.obstacles]
        dt, steps = self._steps_per_frame(scenario, n_frames)
        options = dict(dt=dt, gravity=tuple(scenario.gravity), drag=self._drag(scenario),
                       twist="quasistatic", colliders=colliders,
                       stability_factor=stability_factor,
                       max_substeps=2**31 - 1,  # frames of up to 0.5 s, substepped to the bound by design
                       # a straight rope pressed end-on into a floor (pile) gives the projection no
                       # sideways way out but its small bow: Gauss-Seidel needs a few hundred passes
                       projection_iterations=PROJECTION_ITERATIONS,
                       integrator=self.integrator, root=root,
                       **({"projection": self.projection, "extensible": self.extensible}
                          if self.integrator == "explicit" else {}),
                       root_motion=_motion_callable(motions[0]) if motions else None)
        if contact:
            options["strand_contact"] = th.StrandContact(
                friction=max(r.friction for r in scenario.rods), self_contact=scenario.self_contact)
        sim = th.Simulator(groom, materials, **options)
        if self.extensible and any(s.rod.rest_arc_length is not None for s in strands):
            x = sim.positions()  # pre-stretched rods start where the scenario puts them
            for k, s in enumerate(strands):
                if s.rod.rest_arc_length is not None:
                    x[k, :len(s.scenario_nodes)] = s.scenario_nodes
            sim.set_positions(x)
        for k, s in enumerate(strands):
            condition = s.rod.condition(s.tip_end)
            last = len(s.rest_nodes) - 1
            if s.rod.condition(s.root_end) is EndCondition.PINNED and root == "free":
                sim.add_pin(k, 0, s.scenario_nodes[0])
            if condition is EndCondition.PINNED:
                sim.add_pin(k, last, s.scenario_nodes[-1])
            elif condition is EndCondition.CLAMPED:  # a clip holding the edge's frame, maybe sliding
                slides = s.tip_motion is not None and s.tip_motion.slides_along is not None
                s.clip = sim.add_pin(k, last - 1, clamp=True, hold_twist=True,
                                     slide=tuple(s.axis[s.tip_end]) if slides else False)
        loads = np.zeros((groom.n_strands, groom.max_nodes, 3))
        for k, s in enumerate(strands):
            for load in s.rod.loads:
                loads[k, s.node_of(load.at)] += load.force
        if np.any(loads):
            sim.set_user_forces(loads)
        return sim, strands, steps

    @staticmethod
    def _collider(obstacle, scenario: Scenario):
        friction = max([obstacle.friction] + [r.friction for r in scenario.rods])
        margin = max(r.radius for r in scenario.rods)
        if len({r.radius for r in scenario.rods}) > 1:
            raise NotImplementedError("rods of different radii against one obstacle: a "
                                      "taichi_hair collider has one margin")
        if isinstance(obstacle, Plane):
            return th.Plane(point=tuple(obstacle.point), normal=tuple(obstacle.unit_normal),
                            margin=margin, friction=friction, attached="world")
        if isinstance(obstacle, Cylinder):
            half = obstacle.unit_axis * obstacle.length / 2
            centre = np.asarray(obstacle.center, dtype=float)
            return th.Capsule(p0=tuple(centre - half), p1=tuple(centre + half),
                              radius=obstacle.radius, margin=margin, friction=friction,
                              attached="world")
        raise NotImplementedError(f"an obstacle of kind {type(obstacle).__name__}")

    def run(self, scenario: Scenario, *, n_elements: int, n_frames: int) -> Trajectory:
        _ensure_taichi()
        sim, strands, steps = self._build(scenario, n_elements, n_frames)
        frames = sim.frames()
        angles = []  # per strand: the fixed angle of d1 in (m1, m2), per element [n]
        for k, s in enumerate(strands):
            m1, m2 = frames["m1"][k, :n_elements], frames["m2"][k, :n_elements]
            angles.append(np.arctan2((s.d1_start * m2).sum(1), (s.d1_start * m1).sum(1)))
        positions = [[] for _ in strands]
        directors = [[] for _ in strands]

        def record():
            x, f = sim.positions(), sim.frames()
            if not np.all(np.isfinite(x)):
                raise Diverged("taichi_hair produced non-finite positions", time=sim.time)
            for k, a in enumerate(angles):
                positions[k].append(x[k, : n_elements + 1])
                m1, m2 = f["m1"][k, :n_elements], f["m2"][k, :n_elements]
                d1 = np.cos(a)[:, None] * m1 + np.sin(a)[:, None] * m2
                directors[k].append(d1 / np.linalg.norm(d1, axis=1, keepdims=True))

        record()  # t = 0: the strand as it starts (a pre-stretched rod unstretched, but with extensible)
        times = np.linspace(0.0, scenario.duration, n_frames)
        turned = [s for s in strands if s.tip_motion is not None]
        try:
            for frame in range(1, n_frames):
                for s in turned:  # a driven clip reaches the frame's angle over the frame
                    sim.turn_pin(s.clip, s.tip_angle(times[frame]))
                sim.step(steps)
                record()
        except th.SimulationDiverged as error:
            raise Diverged(f"taichi_hair: {error}", time=sim.time) from error
        return Trajectory(times,
                          tuple(s.to_scenario(np.stack(p)) for s, p in zip(strands, positions)),
                          tuple(s.to_scenario(np.stack(d)) for s, d in zip(strands, directors)))


class TaichiHairImplicitSolver(TaichiHairSolver):
    """The same mapping with Simulator(integrator="implicit") at its default dt (1 ms, or the
    frame interval if shorter; `time_step_scale` scales it)."""

    name = "taichi_hair_implicit"
    integrator = "implicit"


class TaichiHairShakeSolver(TaichiHairSolver):
    """The same mapping with the explicit step's SHAKE projection (Simulator(projection="shake"):
    constraint forces along the start-of-step edges, so an undamped swing keeps its energy)."""

    name = "taichi_hair_shake"
    projection = "shake"


class TaichiHairStretchSolver(TaichiHairSolver):
    """The same mapping with extensible edges (Simulator(extensible=True): each edge a compliant
    constraint of axial stiffness E A in the fast projection), as the scenarios' Cosserat rods;
    pre-stretched rods start stretched."""

    name = "taichi_hair_stretch"
    extensible = True
    capabilities = TaichiHairSolver.capabilities | {Capability.STRETCH}
