"""The Simulator: rods (system.RodSystem) stepped by Kmoch's loop (the step package) under a control
(head, air, colliders, touch, pins), with the stability bound and its substeps. Its records
(stats, checkpoints, rollback on blow-up: sim_records.py), its view of the rods (state in and
out, energies: sim_rods.py) and its start (groom placed, initial contacts, the bound of the start
shape: sim_start.py) are mixins. Units: SI throughout.
"""

import math

import numpy as np

from ..progress import ProgressBar
from ..rods import arrays
from ..rods.groom import Groom
from ..rods.state import COUNTERS
from ..runtime import ensure_init
from ..validation import is_integer, is_real
from ..world.forces import Grab, Wind
from ..world.options import DEFAULT_PROJECTION_TOL, Environment, SolverOptions, split_keywords
from ..world.scene import COLLIDERS as COLLIDER_TYPES
from ..world.scene import Head
from .checkpoint import pose_rows
from .control import build_control, load_poses, load_tools
from .drivers import StagedDriver, StrandContactDriver, choose_driver
from .interaction import InteractionGrid
from .pins import PinTable
from .sim_records import Records
from .sim_rods import RodAccess
from .sim_start import StartSetup
from .sim_steps import StepFitting
from .stability import default_stability_factor, scene_bound
from .step.contact import SMALL_CONTACT_SCENE
from .step.fused import place_roots
from .step.implicit_launches import seed_history
from .step.plan import StepPlan
from .strand_contact import contact_grid
from .system import RodSystem


def _positive(name, value, unit, upper=math.inf):
    if not (is_real(value) and 0 < value < upper and math.isfinite(value)):
        bound = f" and < {upper:g}" if upper < math.inf else ""
        raise ValueError(f"{name} must be > 0{bound} {unit}, got {value!r}")
    return float(value)


class Simulator(Records, RodAccess, StartSetup, StepFitting):
    """Guide strands of `groom` made of `material` (one Material or one per strand).

    The options come as typed data (taichi_hair.world.options, docs/architecture.md "Options"):
    solver: a SolverOptions (integrator, projection, root, twist, strain, extensible, the
    tolerances and caps below, stability_factor, max_substeps, max_speed, strict,
    hair_interaction, strand_contact); environment: an Environment (gravity, drag, wind, motion,
    touch); head: a Head whose colliders the hair stays out of (or colliders=, a sequence).
    Every field of the two may also be given flat as a keyword (twist="kmoch", drag=5e-4;
    root_motion= is motion=), replacing that field of `solver` / `environment`. The fields:

    dt: time step [s] of `step`, at most; past the explicit stability bound each step runs as
        equal substeps within it, silently (the same work as that smaller dt; `sim.substeps`,
        `sim.stable_dt` and `sim.stats()` say how many and why), or is refused with strict=True. gravity [m/s^2]. drag: air-drag coefficient nu [N s/m per metre of
        strand]: each node feels -nu l_i (v - u_air), l_i its Voronoi length.
    wind: the air velocity u_air: a 3-vector [m/s] or a `Wind` (gusts, turbulence); needs drag > 0.
    twist: "quasistatic" (default: Newton on dE/dtheta = 0 per strand, the energy-consistent
        choice), "kmoch" (Kmoch et al.'s rule for elliptic hair: cheaper, but not an energy
        minimum, so it can feed energy in; see the accuracy and stability reports) or "none"
        (material angles stay as they are).
    projection_tol: max |C_j| / |ebar_j|^2 of the inextensibility projection (default 1e-6 in
        both precisions: positions are float64, see `DEFAULT_PROJECTION_TOL`);
        projection_iterations caps it.
    twist_tol: scaled residual max |dE/dtheta| l / max(EI1, GJ) ending the quasistatic solve
        (default 1e-10 float64, 1e-5 float32); twist_iterations caps it.
    root_motion: optional callable t [s] -> (R [3, 3], t [3]) moving the head; otherwise use
        `set_root_transform`.
    colliders: Sphere / Ellipsoid / Capsule / Plane / MeshCollider shapes hair stays out of.
    touch: Hand (moving sphere) and Grab tools. hair_interaction: a HairInteraction or None.
    strand_contact: a StrandContact or None: strands (and, with self_contact, a strand and
        itself) kept apart by the sum of their contact radii, resolved after the projection by
        contact passes alternating with it (solver/strand_contact.py; explicit integrator).
    max_speed [m/s]: a node faster than this counts as a blow-up.
    stability_factor: the explicit bound's factor c (h_bend = c ds^2 sqrt(rho A / EI), in (0, 2));
        default 0.5, or 0.4 with strand_contact (contact pushes pumped energy into the stiffest
        bending mode at 0.5: docs/model.md "Stability bound"). `sim.stability_factor` says which.
    max_substeps: the most automatic substeps per step (default 1000); a scene whose stability
        bound needs more (drag = 1e6, say) is refused with a ValueError naming what sets the bound.
    root: "clamped" (default: node 0 rides on the head and the strand bends and twists against
        the head-carried root frame from node 0 on, docs/model.md "The clamp at the root"),
        "pinned" (node 0 rides on the head, node 1 is free: the strand swings freely about its
        root node. The root edge's reference director is parallel-transported in time from its
        previous direction each step; its material angle theta^0 stays held in that frame (the
        twist solve keeps it fixed), so the joint is free in bending and holds spin about the
        edge: a universal joint, not a ball joint), or "edge" (the first edge rides rigidly on
        the head and bending starts at node 1: the strand bends like one half an edge shorter,
        a first-order error; the model before the clamp moved to the root node, kept to compare),
        or "free" (no node is held: a loose strand, or one held only by pins and clips; node 0
        has its mass, the root edge's reference is carried in time as a pinned root's, and every
        material angle is free in the twist solve, the gauge of a round strand fixed by a
        damped Newton diagonal rather than by holding an edge; under twist="kmoch" elliptic
        strands keep theta^0 as a pinned root does). The implicit integrator needs a held root.
    integrator: "explicit" (default: symplectic Euler, substepped past the stability bound) or
        "implicit" (linearised BDF2 with the bending stiffness solved per strand, docs/model.md
        "The implicit step": stable at any dt, no substeps; the stability bound, substeps,
        max_substeps and strict apply to the explicit integrator only).
    projection: the explicit step's inextensibility projection, "fast" (default: Goldenthal et
        al.'s fast projection, which damps like backward Euler on the constraint forces, a
        first-order loss of swing) or "shake" (constraint forces along the start-of-step edges,
        SHAKE: an undamped swing keeps its energy; docs/model.md "Time step" says where it is
        less robust and why "fast" stays the default). Explicit integrator only.
    extensible: False (default: inextensible edges, Kmoch's model and right for hair) or True:
        each edge stretches like a spring of axial stiffness EA (`Material.axial_stiffness`),
        a compliant constraint inside the same projection (docs/model.md "Extensible strands"):
        for ropes and soft rods whose stretch under load matters (cosseratbench's). Explicit
        integrator only.
    strain: the strain measure of bending and twist (docs/model.md "Strains from rotations"):
        "rotation" (the rotation vector of the turn from one edge's material frame to the next,
        as Cosserat codes measure strain: exact on discrete helices, so curled strands are
        accurate at coarse resolution: a curled rod's tip 4x closer to the continuum at 50
        segments than with "der"), "der" (Discrete Elastic Rods' curvature binormal
        2 tan(phi/2) seen from each edge's material frame and the twist as a difference of
        angles, kept to compare) or None (default: "rotation",
        but "der" for a groom that carries its own rest curvatures, which are DER's: sag_free
        makes them, and under twist="kmoch", whose rule was built on DER and gains energy on
        elliptic curls under the rotation measure: that pair is refused). `sim.strain` says
        which. Both integrators run both.
    Pins and clips on any other node: `add_pin`, `move_pin`, `release_pin`, `pins`.
    """

    def __init__(self, groom: Groom, material, *, dt: float = 1e-3, solver: SolverOptions | None = None,
                 environment: Environment | None = None, head: Head | None = None, colliders=None, **options):
        ensure_init()
        solver, environment = split_keywords(solver, environment, options, "Simulator",
                                             aliases={"root_motion": "motion"})
        if not isinstance(groom, Groom):
            raise ValueError(f"groom must be a taichi_hair.Groom, got {type(groom).__name__}")
        solver = solver.for_groom(groom, material)
        self.solver, self.environment = solver, environment
        self.head = head
        colliders = _colliders_of(head, colliders)
        self.groom = groom
        self.dt = _positive("dt", dt, "s", upper=1.0)
        self.twist = solver.twist
        self.twist_iterations = solver.twist_iterations
        self.rods = RodSystem(groom, material, solver)
        self.integrator = solver.integrator
        self.strain = self.rods.strain
        self._history_h = None  # the step the implicit history was last seeded or stepped with
        self.model, self.state = self.rods.model, self.rods.state
        self._pins = PinTable(self.model, solver.root)
        self.touch = environment.touch
        self.root_motion = environment.motion
        self.stability_factor = (default_stability_factor(solver.strand_contact is not None)
                                 if solver.stability_factor is None else solver.stability_factor)
        gravity, wind, drag = np.array(environment.gravity), environment.air_velocity, environment.drag
        self.control, facts = build_control(gravity, wind, drag, colliders, self.touch, solver.max_speed)
        self.max_substeps = solver.max_substeps
        lightest = float(self.model.mass.to_numpy()[self.model.inv_mass.to_numpy() > 0].min())
        self._measured_for = None  # (positions, _measured_stiffening's answer for them)
        # strands step at strides of their own (each within its own bound) in the fused explicit
        # step; touch tools are sampled at every substep, and pins force stride 1 per launch
        self._strides_possible = (solver.strand_steps and solver.integrator == "explicit"
                                  and solver.hair_interaction is None and solver.strand_contact is None
                                  and not self.touch)
        self.strand_substeps = None  # [S] each strand's substeps per step (None: all `substeps`)
        self._strides_loaded = False
        self.bound = scene_bound(groom, self.model.materials, drag=drag, air_speed=_max_air_speed(wind),
                                 grabs=[(f"touch[{k}]", g.stiffness, lightest) for k, g in enumerate(self.touch)
                                        if isinstance(g, Grab)],
                                 factor=self.stability_factor, kmoch=self.twist == "kmoch",
                                 measured=self._measured_stiffening())
        self.substeps = self._substeps(solver.strict)
        self.plan = StepPlan.of(solver, facts, external_forces=bool(np.any(gravity) or drag > 0),
                                projection_tol=DEFAULT_PROJECTION_TOL if solver.projection_tol is None
                                else solver.projection_tol, twist_tol=self.rods.twist_tol)
        self._bundles = self.rods.bundles
        self._bundles.bind(self.control)
        self._substep = 0  # (sub)steps of dt / substeps taken: the clock, see `time`
        self._clock_offset = 0.0  # the clock's start in substeps (0 unless dt changed off the grid)
        self.steps_taken = 0
        self._snapshot = None
        self._potential = arrays.scalars((groom.n_strands,))
        self._head = self._head_prev = (np.eye(3), np.zeros(3))
        if self.root_motion is not None:
            self._place_groom(*self._head_at(0.0))
        self.skipped_colliders = self._colliders_holding_roots(colliders)
        if self.plan.contacts:
            self._resolve_initial_contacts()
            self._tighten_bound_to_start(solver.strict)
        self.update_frames()
        self.interaction = None if solver.hair_interaction is None else InteractionGrid(
            solver.hair_interaction, groom, self.model, self.state, self._head[1])
        self.strand_contact = solver.strand_contact
        self._contact_grid = None if self.strand_contact is None else contact_grid(self.strand_contact, self.model)
        self.small_contact_nodes = SMALL_CONTACT_SCENE  # builds self.driver

    @property
    def small_contact_nodes(self) -> int:
        """Strand contact in scenes of at most this many nodes runs many steps per launch on one
        thread; larger, a launch per step in parallel (drivers.StrandContactDriver)."""
        return self._small_contact_nodes

    @small_contact_nodes.setter
    def small_contact_nodes(self, nodes: int) -> None:
        self._small_contact_nodes = nodes
        self.driver = choose_driver(self._bundles, self.plan, self.control, self.interaction,
                                    self._contact_grid, self.strand_contact, nodes)
        self._contact = self.driver if isinstance(self.driver, StrandContactDriver) else getattr(
            self.driver, "contact", None)

    @classmethod
    def from_scene(cls, scene, dt: float = 1e-3, **options) -> "Simulator":
        """The simulator of a `Scene`: its groom, material, head colliders and motion, wind,
        touch tools and hair interaction; `options` go to the constructor (twist, drag, ...)."""
        return cls(scene.groom, scene.material, dt=dt, **{**scene.simulator_options(), **options})

    @property
    def time(self) -> float:
        """Simulated time [s]: the substeps taken times the substep dt / substeps, a function of the
        step index (never a running sum), so any grouping of steps into calls ends at one time."""
        return self._step_index() * (self.dt / self.substeps)

    @time.setter
    def time(self, value: float) -> None:
        self._set_clock(float(value))

    def _step_index(self) -> float:
        """The time in substeps of the current dt / substeps: a whole number while dt has not
        changed off the grid of earlier steps (kernels take time as this index times h)."""
        return self._clock_offset + self._substep

    def _set_clock(self, t: float) -> None:
        """The clock at time t [s] in steps of the current dt / substeps: a whole count where t
        lies on their grid (so any grouping of later steps ends at one time, bit for bit), else
        an offset from t."""
        n = t / (self.dt / self.substeps)
        whole = round(n)
        if abs(n - whole) <= 1e-9 * max(1.0, abs(n)):
            self._clock_offset, self._substep = 0.0, int(whole)
        else:
            self._clock_offset, self._substep = n, 0

    def _set_dt(self, dt: float) -> None:
        """dt [s] (and its substeps) changed at the current time, the clock kept."""
        t = self.time
        self.dt = dt
        self.substeps = self._substeps(False)
        self._set_clock(t)

    @property
    def stable_dt(self) -> float:
        """The explicit step's stability bound [s] (self.bound: with what sets it)."""
        return self.bound.dt

    # ---- head transform -----------------------------------------------------------------
    def _head_at(self, t: float):
        return check_rigid_transform(*self.root_motion(t))

    def _orient_roots(self, reference=None):
        """Head poses loaded; root reference frames at the current head pose (root nodes
        untouched), unless the root is pinned: its reference is carried in time by the steps
        (reference=True forces it, for the initial pose)."""
        load_poses(self.control, np.stack([pose_rows(*self._head_prev), pose_rows(*self._head)]))
        st, md = self.state, self.model
        if reference or (reference is None and not self.plan.carried_root_frame):
            place_roots(self.control.head, md.root_frame, st.dx, st.root_t, st.root_u)  # x -> dx: scratch

    @property
    def head_transform(self):
        """(R [3, 3], t [3] m): the head's current pose."""
        return self._head

    def set_root_transform(self, rotation, translation) -> None:
        """Move the head: the roots follow the rigid transform x -> R x + t of the groom's
        rest pose. Their reference frames turn at once; the root nodes get there during the next
        step (with the velocity that implies). rotation: 3x3 proper rotation; translation [m]."""
        self._head = check_rigid_transform(rotation, translation)
        self._orient_roots()
        self.update_frames()

    # ---- pins and clips (taichi_hair/solver/pins.py) -----------------------------------------
    def add_pin(self, strand, node, target=None, *, clamp: bool = False, attach: str = "world",
                hold_twist: bool = False, slide=False):
        """Pin node `node` of strand `strand` to a point (position only; node -1 is the tip).
        target [3] m: default the node's current position (no jump); in world coordinates
        (attach="world") or head coordinates (attach="head": the pin rides on the head's rigid
        transform, like the roots). clamp=True clips the edge (node, node + 1): both nodes held,
        target the node's position, the edge keeping its current direction (in the world or on
        the head). Returns the pin's int id. Bulk: strand and node as 1-D sequences of K (node
        may be one int for all) and target None or [K, 3] add K pins at once and return an int64
        array of K ids. Held already (root nodes, other pins) or out of range: ValueError.
        hold_twist=True (with clamp): the clip holds the edge's material frame too, at its current
        m1, turned about the edge by `turn_pin` (twist="quasistatic" only; explicit integrator).
        slide=True or an axis [3] (with clamp, on the strand's last edge, attach="world"): the
        clip's two nodes move together along the edge's current direction (or the axis) under
        the forces on them and the strand's pull, held across it (explicit integrator)."""
        if (hold_twist or slide is not False) and self.integrator == "implicit":
            raise ValueError("hold_twist and slide clips run with integrator='explicit'")
        if hold_twist and self.twist != "quasistatic":
            raise ValueError(f"hold_twist needs twist='quasistatic' (the solve that holds an edge's "
                             f"angle), got twist={self.twist!r}")
        ids = self._pins.add(strand, node, target, clamp, attach, self.positions(), self._head_prev,
                             hold_twist=hold_twist, slide=slide,
                             directors=self.frames()["m1"] if hold_twist else None)
        if self.strand_substeps is not None:
            self._set_dt(self.dt)  # with pins every strand takes every substep (_substeps)
        return int(ids[0]) if np.ndim(strand) == 0 and np.ndim(node) == 0 else ids

    def move_pin(self, pin_id, target) -> None:
        """New target [3] m (a clip's node position; in the pin's attach coordinates): the node
        gets there at the end of the next `step` call, moving linearly in time over it. Bulk:
        pin_id a sequence of K ids and target [K, 3]."""
        self._pins.move(pin_id, target)

    def turn_pin(self, pin_id, angle) -> None:
        """Turn a twist-holding clip to `angle` [rad] about its edge (right-handed, from where it
        was clipped; cumulative, so 2 pi is a full turn): reached at the end of the next `step`
        call, turning linearly in time over it. Bulk: pin_id a sequence of K ids, angle [K]."""
        self._pins.turn(pin_id, angle)

    def release_pin(self, pin_id) -> None:
        """Free the pin's node(s) from the next step on; they keep their last step's velocity.
        pin_id: an id or a sequence of ids; an unknown id is a ValueError."""
        self._pins.release(pin_id)
        if not self._pins.active and self._strides_possible and self.integrator == "explicit":
            self._set_dt(self.dt)  # the last pin gone: strands take their own substeps again

    def pins(self) -> list[dict]:
        """The live pins: dicts of id, strand, node, target ([3] m, the latest target in attach
        coordinates), clamp, attach."""
        return self._pins.listing()

    # ---- stepping -----------------------------------------------------------------------
    def step(self, n: int = 1, timers=None) -> None:
        """Advance n steps of dt (each maybe substepped). On blow-up the state is rolled back to
        where this call began and SimulationDiverged is raised. With `timers` (a callable
        name -> context manager that synchronises), or with hair interaction, every stage runs
        as its own kernel; otherwise many substeps run in one fused launch."""
        if not (is_integer(n) and n >= 0):
            raise ValueError(f"n must be an integer >= 0, got {n!r}")
        n = int(n)
        driver = self.driver if timers is None else StagedDriver(
            self._bundles, self.plan, self.control, self.interaction, self._contact, timers)
        strides = self.strand_substeps is not None and driver.strides
        if strides and not self._strides_loaded:
            self._load_strides()
        self._take_snapshot()
        self._pins.upload()
        h = self.dt / self.substeps
        if self.integrator == "implicit" and self._history_h != h:
            st = self.state
            seed_history(h, self.model.node_count, st.v, st.history, st.tension)
            self._history_h = h
        remaining = total = n * self.substeps
        while remaining > 0:
            count = driver.launch_size(remaining, self.substeps if strides else 1)
            moving = self._load_launch(h, count)
            self.control.first_step = self._step_index()
            # pins move linearly over the whole call (pins.py)
            pins = ((*self._pins.device, (total - remaining) / total, 1.0 / total, self._pins.clips)
                    if self._pins.active else None)
            driver.launch(h, count, moving, pins, strides)
            bad = self.state.counters.to_numpy()[:, COUNTERS["bad_step"]]
            if np.any(bad >= 0):
                self._diverged(h, bad)
            self._substep += count
            self._head_prev = self._head
            remaining -= count
        self.steps_taken += n
        self._pins.settle()

    def strand_contact_depth(self) -> float:
        """The deepest strand-strand overlap [m] at the current positions (0 without
        strand_contact): r_a + r_b minus the distance of the closest segment pair that may touch."""
        if self._contact_grid is None:
            return 0.0
        return self._contact_grid.max_penetration(self.state.x, self.model.inv_mass)

    def _load_launch(self, h, count) -> bool:
        """Head poses and tool positions for a launch of `count` steps; True if the head moves."""
        times = (self._step_index() + np.arange(count + 1)) * h
        if self.root_motion is not None:
            poses = [self._head_prev] + [self._head_at(t) for t in times[1:]]
            self._head = poses[-1]
            load_poses(self.control, np.stack([pose_rows(*p) for p in poses]))
        else:
            load_poses(self.control, np.stack([pose_rows(*self._head_prev), pose_rows(*self._head)]))
        load_tools(self.control, self.touch, times)
        return self.root_motion is not None and count > 1

    def run(self, seconds: float, progress: bool = True, chunk: float = 1.0 / 60.0) -> None:
        """Simulate exactly `seconds` [s]: the fewest equal steps of at most dt that fill it
        (seconds / ceil(seconds / dt), as `taichi-hair run` fits its step to a frame; dt is
        restored after), in chunks of about `chunk` seconds, with a progress bar on stderr.
        A blow-up leaves the state at the end of the last healthy chunk."""
        if not (is_real(seconds) and seconds >= 0 and math.isfinite(seconds)):
            raise ValueError(f"seconds must be a finite number >= 0, got {seconds!r}")
        if seconds == 0:
            return
        total = max(1, math.ceil(seconds / self.dt - 1e-9))
        dt = self.dt
        self._set_dt(seconds / total)  # dt only shrank: never more substeps than before
        per_chunk = max(1, int(round(chunk / self.dt)))
        try:
            with ProgressBar(seconds, "simulating", enabled=progress) as bar:
                done = 0
                while done < total:
                    k = min(per_chunk, total - done)
                    self.step(k)
                    done += k
                    bar.update(k * self.dt)
        finally:
            self._set_dt(dt)

    def set_user_forces(self, force) -> None:
        """Extra forces [S, N, 3] in newtons applied every step until changed; None removes them."""
        if force is None:
            self.control.user_force = None
            return
        force = np.asarray(force, dtype=np.float64)
        shape = (self.groom.n_strands, self.groom.max_nodes, 3)
        if force.shape != shape:
            raise ValueError(f"user forces must have shape {list(shape)} (strands, nodes, xyz) N, "
                             f"got {list(force.shape)}")
        if not np.all(np.isfinite(force)):
            s, i = np.argwhere(~np.isfinite(force))[0][:2]
            raise ValueError(f"user forces must be finite; strand {s} node {i} is {force[s, i]} N")
        if self.control.user_force is None:
            self.control.user_force = arrays.vectors(3, shape[:2])
        self.control.user_force.from_numpy(force.astype(arrays.np_float()))

def _max_air_speed(wind) -> float:
    """Fastest air [m/s] a wind can blow: mean * (1 + gust) + three turbulence rms."""
    if isinstance(wind, Wind):
        return (float(np.linalg.norm(wind.velocity)) * (1.0 + wind.gust_amplitude) + 3.0 * wind.turbulence)
    return float(np.linalg.norm(wind))


def _colliders_of(head, colliders) -> tuple:
    """The colliders of `head` (a Head or None) or the `colliders` sequence; both: ValueError."""
    if head is not None and not isinstance(head, Head):
        raise ValueError(f"head must be a taichi_hair.Head or None, got {type(head).__name__}")
    if head is not None and colliders is not None:
        raise ValueError("give head= or colliders=, not both (a Head carries its colliders)")
    colliders = head.colliders if head is not None else tuple(colliders or ())
    for k, c in enumerate(colliders):
        if not isinstance(c, COLLIDER_TYPES):
            raise ValueError(f"colliders[{k}] must be one of Sphere, Ellipsoid, Capsule, Plane, "
                             f"MeshCollider; got {type(c).__name__}")
    return colliders


def check_rigid_transform(rotation, translation):
    """Validated (R [3, 3], t [3]) float64 arrays, or ValueError naming the bad one."""
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64)
    if rotation.shape != (3, 3) or not np.all(np.isfinite(rotation)):
        raise ValueError(f"rotation must be a finite 3x3 matrix, got shape {rotation.shape}")
    if (np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-6
            or abs(np.linalg.det(rotation) - 1.0) > 1e-6):
        raise ValueError("rotation must be a proper rotation matrix (R^T R = I within 1e-6, det R = +1)")
    if translation.shape != (3,) or not np.all(np.isfinite(translation)):
        raise ValueError(f"translation must be a finite vector of 3 metres, got {translation!r}")
    return rotation, translation
