"""The Simulator: rods (system.RodSystem) stepped by Kmoch's loop (step.py) under a control
(head, air, colliders, touch, pins), with the stability bound and its substeps, rollback on
blow-up, and checkpoints. Units: SI throughout.
"""

import math
import warnings

import numpy as np

from ..rods import arrays
from ..rods.groom import Groom
from ..progress import ProgressBar
from ..runtime import ensure_init
from .stability import (MEASURE_ABOVE, curvature_stiffening, default_stability_factor, rest_turns,
                        SimulationDiverged, likely_cause, scene_bound, stable_time_step, stiffest_mode_ratio,
                        substeps_for)
from ..world.scene import COLLIDERS as COLLIDER_TYPES
from .collisions import root_keeps_collider
from ..world.colliders import host_distance
from ..world.scene import check_common_inputs
from .control import MAX_STEPS_PER_LAUNCH, build_control, load_poses, load_tools
from ..world.forces import Grab, Wind
from .interaction import InteractionGrid
from .strand_contact import contact_grid, resolve_strand_contacts
from .pins import PinTable
from ..rods.state import COUNTERS
from .checkpoint import load_state, pose_rows, save_state
from .system import DEFAULT_TWIST_ITERATIONS, RodSystem
from ..validation import is_integer, is_real
from .step import (FAILED_ABOVE, STALL_BELOW, TWIST_FAILED_ABOVE, StepPlan, advance, kmoch_step,
                   SMALL_CONTACT_SCENE, place_roots, project_once, seed_history, step_with_strand_contact,
                   steps_with_strand_contact, strand_mechanical_energy)

DEFAULT_MAX_SUBSTEPS = 1000  # automatic substeps per step at most: past it a scene is refused
# 1e-6 in both precisions: positions are stored in float64 and edges formed there, so even in
# float32 |e|^2 - |ebar|^2 resolves to a few eps of the edge itself (~2.4e-7), whatever the
# coordinates' magnitude. (With float32 positions the floor was ~2 eps X / ds, and a residual
# left at such a tol was an edge stretched by tol ds / 2 that the next step removed as a
# velocity kick: docs/model.md, "Positions and velocities in float32".)
DEFAULT_PROJECTION_TOL = 1e-6
INITIAL_PROJECTION_ROUNDS = 50  # projection calls at most to move a groom out of the colliders


def _vector3(name, value):
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be a finite 3-vector, got {value!r}")
    return v


def _positive(name, value, unit, upper=math.inf):
    if not (is_real(value) and 0 < value < upper and math.isfinite(value)):
        bound = f" and < {upper:g}" if upper < math.inf else ""
        raise ValueError(f"{name} must be > 0{bound} {unit}, got {value!r}")
    return float(value)


class Simulator:
    """Guide strands of `groom` made of `material` (one Material or one per strand).

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

    def __init__(self, groom: Groom, material, *, dt: float = 1e-3, gravity=(0.0, 0.0, -9.81),
                 drag: float = 0.0, wind=(0.0, 0.0, 0.0), twist: str = "quasistatic",
                 projection_tol: float | None = None, projection_iterations: int = 100,
                 twist_tol: float | None = None, twist_iterations: int = DEFAULT_TWIST_ITERATIONS,
                 root_motion=None,
                 colliders=(), touch=(), hair_interaction=None, strict: bool = False,
                 max_speed: float = 100.0, stability_factor: float | None = None,
                 root: str = "clamped", max_substeps: int = DEFAULT_MAX_SUBSTEPS,
                 integrator: str = "explicit", strand_contact=None, projection: str = "fast",
                 extensible: bool = False, strain: str | None = None):
        ensure_init()
        _check_arguments(groom, twist, projection_iterations, twist_iterations, drag, root_motion,
                         wind, colliders, touch, hair_interaction, gravity, integrator, strand_contact,
                         projection, extensible)
        self.groom = groom
        self.dt = _positive("dt", dt, "s", upper=1.0)
        self.twist = twist
        self.twist_iterations = twist_iterations
        twist_tol = None if twist_tol is None else _positive("twist_tol", twist_tol, "")
        if root == "free" and integrator == "implicit":
            raise ValueError("integrator='implicit' needs a held root (root='clamped', 'pinned' or "
                             "'edge'); a free root (root='free') runs with integrator='explicit'")
        self.rods = RodSystem(groom, material, twist=twist, root=root, twist_tol=twist_tol,
                              twist_iterations=twist_iterations, integrator=integrator, extensible=extensible,
                              strain=strain)
        self.integrator = integrator
        self.strain = self.rods.strain
        self._history_h = None  # the step the implicit history was last seeded or stepped with
        self.model, self.state = self.rods.model, self.rods.state
        self._pins = PinTable(self.model, root)
        self.touch = tuple(touch)
        self.root_motion = root_motion
        self.stability_factor = (default_stability_factor(strand_contact is not None) if stability_factor is None
                                 else _positive("stability_factor", stability_factor, "", upper=2.0))
        self.control, facts = build_control(_vector3("gravity", gravity),
                                            wind if isinstance(wind, Wind) else _vector3("wind", wind),
                                            drag, tuple(colliders), self.touch,
                                            _positive("max_speed", max_speed, "m/s"))
        if facts["wind"] and drag == 0:
            raise ValueError("wind acts through air drag: give drag > 0 N s/m per metre of strand "
                             "(human hair in air: about 1e-4 to 1e-3)")
        self.max_substeps = _check_max_substeps(max_substeps)
        lightest = float(self.model.mass.to_numpy()[self.model.inv_mass.to_numpy() > 0].min())
        self._measured_for = None  # (positions, _measured_stiffening's answer for them)
        self.bound = scene_bound(groom, self.model.materials, drag=drag, air_speed=_max_air_speed(wind),
                                 grabs=[(f"touch[{k}]", g.stiffness, lightest) for k, g in enumerate(self.touch)
                                        if isinstance(g, Grab)],
                                 factor=self.stability_factor, kmoch=twist == "kmoch",
                                 measured=self._measured_stiffening())
        self.substeps = self._substeps(strict)
        self.plan = StepPlan(
            external_forces=bool(np.any(_vector3("gravity", gravity)) or drag > 0),
            wind_field=facts["wind_field"], twist=twist, n_analytic=facts["n_analytic"],
            mesh=facts["mesh"], touch=facts["touch"],
            projection_tol=_positive("projection_tol", DEFAULT_PROJECTION_TOL if projection_tol is None else projection_tol,
                                     "", upper=1.0),
            projection_iterations=projection_iterations,
            twist_tol=self.rods.twist_tol,
            twist_iterations=twist_iterations, root=root, integrator=integrator, projection=projection,
            extensible=bool(extensible), strain=self.rods.strain)
        self._bundles = self.rods.bundles
        self._bundles.bind(self.control)
        self._substep = 0  # (sub)steps of dt / substeps taken: the clock, see `time`
        self._clock_offset = 0.0  # the clock's start in substeps (0 unless dt changed off the grid)
        self.steps_taken = 0
        self._snapshot = None
        self._potential = arrays.scalars((groom.n_strands,))
        self._head = self._head_prev = (np.eye(3), np.zeros(3))
        if root_motion is not None:
            self._place_groom(*self._head_at(0.0))
        self.skipped_colliders = self._colliders_holding_roots(tuple(colliders))
        if self.plan.contacts:
            self._resolve_initial_contacts()
            self._tighten_bound_to_start(strict)
        self.update_frames()
        self.interaction = None if hair_interaction is None else InteractionGrid(
            hair_interaction, groom, self.model, self.state, self._head[1])
        self.strand_contact = strand_contact
        self._contact_grid = None if strand_contact is None else contact_grid(strand_contact, self.model)
        self._contact_depth = 0.0  # the largest depth a last contact pass found, since the stats reset
        # strand contact in scenes of at most this many nodes: many steps per launch, one thread
        # (step.advance_small_with_strand_contact); larger: a launch per step, parallel
        self.small_contact_nodes = SMALL_CONTACT_SCENE

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

    def fit_step(self, interval: float) -> int:
        """Take the fewest equal steps within both dt and the explicit bound that fill `interval`
        [s] (a video frame, say): sets dt to interval / count, one substep each (the implicit
        step: within dt alone), and returns the count. Substeps of a fixed dt would waste up to
        half the bound: 0.992 ms steps over a 0.96 ms bound run as two of 0.496 ms."""
        interval = _positive("interval", interval, "s")
        largest = self.dt if self.integrator == "implicit" else min(self.dt, self.stable_dt)
        count = max(1, math.ceil(interval / largest - 1e-9))
        self._set_dt(interval / count)
        self._history_h = None
        return count

    # ---- head transform -----------------------------------------------------------------
    def _head_at(self, t: float):
        return check_rigid_transform(*self.root_motion(t))

    def _place_groom(self, rotation, translation):
        """Put the whole groom rigidly at the head's pose (used for the initial pose only)."""
        self._head = self._head_prev = (rotation, translation)
        x = self.groom.positions @ rotation.T + translation
        self.state.x.from_numpy(x.astype(np.float64))
        self._orient_roots(reference=True)

    def _orient_roots(self, reference=None):
        """Head poses loaded; root reference frames at the current head pose (root nodes
        untouched), unless the root is pinned: its reference is carried in time by the steps
        (reference=True forces it, for the initial pose)."""
        load_poses(self.control, np.stack([pose_rows(*self._head_prev), pose_rows(*self._head)]))
        st, md = self.state, self.model
        if reference or (reference is None and not self.plan.carried_root_frame):
            place_roots(self.control.head, md.root_frame, st.dx, st.root_t, st.root_u)  # x -> dx: scratch

    def _colliders_holding_roots(self, colliders) -> list[tuple[int, int]]:
        """(strand, collider index) pairs whose root starts inside the collider by more than its
        margin: the contact stage skips them (collisions.root_keeps_collider), so say so once.
        Head-attached colliders see the roots in head coordinates, world ones at the start pose."""
        head_roots = self.groom.positions[:, 0]
        world_roots = self.positions()[:, 0]
        skipped = []
        for k, c in enumerate(colliders):
            roots = head_roots if c.attached == "head" else world_roots
            depth = host_distance(c, roots)
            skipped += [(int(s), k) for s in np.flatnonzero(~root_keeps_collider(depth, c.margin))]
        if skipped:
            kinds = sorted({type(colliders[k]).__name__ + f" (colliders[{k}])" for _, k in skipped})
            warnings.warn(f"{len(skipped)} strand root(s) (first: strand {skipped[0][0]}) lie inside "
                          f"{', '.join(kinds)} by more than its margin: those strands do not collide with "
                          f"it (sim.skipped_colliders lists the pairs); move the roots onto the surface "
                          f"to keep the hair out", RuntimeWarning, stacklevel=3)
        return skipped

    def _resolve_initial_contacts(self):
        """Move groomed nodes that start inside a collider's margin out of it before the first
        step, so the correction does not turn into a velocity kick (the push over one substep
        would read as metres per second)."""
        st, c = self.state, self.control
        load_poses(c, np.stack([pose_rows(*self._head), pose_rows(*self._head)]))
        load_tools(c, self.touch, np.full(2, self.time))
        st.x_prev.copy_from(st.x)
        # A strand groomed into the head may need many more iterations than one step allows;
        # this runs once, so keep going (up to INITIAL_PROJECTION_ROUNDS calls) until it holds.
        for _ in range(INITIAL_PROJECTION_ROUNDS):
            st.residuals.fill(0.0)
            project_once(self._bundles, self.plan, c)
            residual = st.residuals.to_numpy()[:, 0]
            if residual.max() <= self.plan.projection_tol:
                break
        stuck = np.flatnonzero(~(residual <= FAILED_ABOVE))
        if len(stuck):
            warnings.warn(f"{len(stuck)} strand(s) (first: {stuck[0]}) start inside a collider and "
                          f"could not be moved out with their edge lengths kept (relative residual "
                          f"{residual[stuck].max():.3g}); check the groom against the head",
                          RuntimeWarning, stacklevel=3)
        st.x_prev.copy_from(st.x)
        self._reset_counters()

    def _tighten_bound_to_start(self, strict):
        """Contacts may have bent the groom at the start: the bound must hold for that shape too."""
        x = self.positions()
        start = Groom.from_polylines([x[s, : n] for s, n in enumerate(self.groom.node_counts)])
        self.bound = self.bound.tightened(
            stable_time_step(start, self.model.materials, self.control.drag, self.stability_factor,
                             kmoch=self.twist == "kmoch", measured=self._measured_stiffening()),
            "the shape the colliders left the groom in at the start (sharp bends)")
        self.substeps = self._substeps(strict)

    def _measured_stiffening(self) -> dict:
        """{strand: EI_eff / EI} of the strands whose current shape the curvature rule charges
        more than MEASURE_ABOVE: their stiffest bending mode (stiffest_mode_ratio) from central
        differences of the elastic forces. Under the rotation measure only (the rule holds for
        DER's rest shapes but not once they bend away), explicit step, twist not Kmoch's.
        Positions and frames are as they were afterwards."""
        if self.strain != "rotation" or self.twist == "kmoch" or self.integrator != "explicit":
            return {}
        counts = self.groom.node_counts
        x0 = self.state.x.to_numpy()
        if self._measured_for is not None and np.array_equal(self._measured_for[0], x0):
            return self._measured_for[1]  # the start shape is the groom's: no collider moved a node
        measured = self._stiffening_of(x0, counts)
        self._measured_for = (x0, measured)
        return measured

    def _stiffening_of(self, x0, counts) -> dict:
        """_measured_stiffening's answer at positions x0 [S, N, 3] m."""
        strands = [s for s in range(len(counts))
                   if curvature_stiffening(rest_turns(x0[s, : counts[s]])) > MEASURE_ABOVE]
        if not strands:
            return {}
        h = 1e-4 * min(np.linalg.norm(np.diff(x0[s, : counts[s]], axis=0), axis=1).min() for s in strands)
        hessian = self.rods.elastic_hessian(x0, strands, h)
        mass = self.model.mass.to_numpy()
        measured = {}
        for k, s in enumerate(strands):
            n, m = counts[s], self.model.materials[s]
            measured[s] = stiffest_mode_ratio(x0[s, :n], mass[s, :n], hessian[k, : 3 * n, : 3 * n],
                                              max(m.bending_stiffness), m.linear_density)
        return measured

    def _substeps(self, strict) -> int:
        """Substeps per step: the explicit step's bound sets them; the implicit step needs none."""
        if self.integrator == "implicit":
            return 1
        return substeps_for(self.dt, self.bound, strict, self.max_substeps)

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
        self._take_snapshot()
        self._pins.upload()
        h = self.dt / self.substeps
        if self.integrator == "implicit" and self._history_h != h:
            st = self.state
            seed_history(h, self.model.node_count, st.v, st.history, st.tension)
            self._history_h = h
        remaining = total = n * self.substeps
        staged = timers is not None or self.interaction is not None or self.strand_contact is not None
        # strand contact without timers or the hair grid runs fused: a launch per step, or in a small
        # scene many steps per launch on one thread
        fused_contact = self.strand_contact is not None and timers is None and self.interaction is None
        small_contact = fused_contact and (self.model.groom.n_strands * self.model.groom.max_nodes
                                           <= self.small_contact_nodes)
        while remaining > 0:
            count = 1 if staged and not small_contact else min(remaining, MAX_STEPS_PER_LAUNCH)
            moving = self._load_launch(h, count)
            self.control.first_step = self._step_index()
            # pins move linearly over the whole call (pins.py)
            pins = ((*self._pins.device, (total - remaining) / total, 1.0 / total, self._pins.clips)
                    if self._pins.active else None)
            if small_contact:
                steps_with_strand_contact(self._bundles, self.plan, self.control, h, count, self._contact_grid,
                                          self.strand_contact, moving, pins)
            elif fused_contact:
                depth = step_with_strand_contact(self._bundles, self.plan, self.control, h, self._contact_grid,
                                                 self.strand_contact, pins)
                self._contact_depth = max(self._contact_depth, depth)
            elif staged:
                kmoch_step(self._bundles, self.plan, self.model, self.state, self.control, h, timers,
                           self.interaction.stage if self.interaction is not None else None, pins,
                           self._strand_contact_stage if self.strand_contact is not None else None)
            else:
                advance(self._bundles, self.plan, self.control, h, count, moving, pins)
            bad = self.state.counters.to_numpy()[:, COUNTERS["bad_step"]]
            if np.any(bad >= 0):
                self._diverged(h, bad)
            self._substep += count
            self._head_prev = self._head
            remaining -= count
        self.steps_taken += n
        self._pins.settle()

    def _strand_contact_stage(self, project):
        depth = resolve_strand_contacts(self._contact_grid, self.strand_contact, self.model, self.state,
                                        project)
        self._contact_depth = max(self._contact_depth, depth)

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

    def _take_snapshot(self):
        st = self.state
        if self._snapshot is None:
            self._snapshot = {name: arrays.like(getattr(st, name))
                              for name in ("x", "v", "theta", "root_t", "root_u")}
        for name, copy in self._snapshot.items():
            copy.copy_from(getattr(st, name))
        self._snapshot_clock = (self._substep, self.steps_taken, self._head, self._clock_offset)

    def _diverged(self, h, bad_step):
        bad = np.flatnonzero(bad_step >= 0)
        first = bad[np.argmin(bad_step[bad])]
        counters = self.state.counters.to_numpy()
        cap_hits = int(counters[:, COUNTERS["projection_cap_hits"]].sum())
        t = (self._step_index() + bad_step[first] + 1) * h
        start = (self._snapshot_clock[3] + self._snapshot_clock[0]) * h
        step = self._snapshot_clock[1] + int(math.ceil((t - start) / self.dt - 1e-9))
        for name, copy in self._snapshot.items():
            getattr(self.state, name).copy_from(copy)
        self._history_h = None
        self._substep, self.steps_taken, self._head, self._clock_offset = self._snapshot_clock
        self._head_prev = self._head
        self._orient_roots()
        self.update_frames()
        residual = float(self.state.residuals.to_numpy()[first, 0])
        cause = likely_cause(h, self.stable_dt, cap_hits, self.control.max_speed, residual,
                             implicit=self.integrator == "implicit")
        twist_residual = float(self.state.residuals.to_numpy()[first, 1])
        # the kernel's rule (step.strand_twist): a cap, or a stall above TWIST_FAILED_ABOVE
        if counters[first, COUNTERS["twist_cap_hits"]] or (
                counters[first, COUNTERS["twist_stalls"]] and twist_residual > TWIST_FAILED_ABOVE):
            cause = (f"the twist solve of strand {first} did not converge (scaled residual "
                     f"{twist_residual:.3g} after up to {self.twist_iterations} "
                     f"iterations): its forces would not be the energy's gradient; raise "
                     f"twist_iterations or twist_tol")
        raise SimulationDiverged(
            f"simulation diverged at step {step} (t = {t:.4g} s): strand {first} "
            f"({len(bad)} strand(s) in all) went non-finite, faster than {self.control.max_speed:g} m/s, "
            f"out of its inextensibility constraints or out of twist equilibrium; "
            f"likely cause: {cause}. State rolled back to t = {self.time:.4g} s.",
            step=step, strand=int(first))

    # ---- checkpoints (checkpoint.py) ------------------------------------------------------
    def save_state(self, path, extra=None) -> None:
        """Write the dynamic state to `path` (.npz) atomically; see checkpoint.save_state."""
        save_state(self, path, extra)

    def load_state(self, path) -> None:
        """Restore a state written by `save_state` for this same groom; see checkpoint.load_state."""
        load_state(self, path)

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

    def stats(self, reset: bool = False) -> dict:
        """Solver report since the last reset: time, steps, dt and substeps, the stability bound,
        projection iterations (max, and mean over strand-steps), its final residual (max), how many strand-steps ended above
        projection_tol at the iteration cap (projection_cap_hits) or stalled (projection_stalls:
        an iteration removed under 10 % of a residual already below projection_stall_below,
        1e-3: the rounding floor in float32, or contacts pushing nodes back against the edge
        lengths in any precision), the twist solve's iterations and residual, and with
        strand_contact the deepest overlap [m] a step's last contact pass found
        (strand_contact_depth_max)."""
        counters = self.state.counters.to_numpy()
        residuals = self.state.residuals.to_numpy()
        report = {
            "time": self.time, "steps": self.steps_taken, "dt": self.dt, "integrator": self.integrator,
            "projection": self.plan.projection, "extensible": self.plan.extensible, "strain": self.plan.strain,
            "substeps": self.substeps,
            "substep_dt": self.dt / self.substeps, "stable_dt": float(self.stable_dt),
            "projection_tol": self.plan.projection_tol,
            "projection_iterations_max": int(counters[:, COUNTERS["projection_iterations"]].max()),
            "projection_iterations_mean": (float(counters[:, COUNTERS["projection_iterations_sum"]].sum())
                                           / max(1, int(counters[:, COUNTERS["projections"]].sum()))),
            "projection_residual_max": float(residuals[:, 0].max()),
            "projection_cap_hits": int(counters[:, COUNTERS["projection_cap_hits"]].sum()),
            "projection_stalls": int(counters[:, COUNTERS["projection_stalls"]].sum()),
            "projection_stall_below": STALL_BELOW,
            "twist": self.twist,
        }
        if self.twist != "none":  # kmoch solves round strands exactly too
            report["twist_iterations_max"] = int(counters[:, COUNTERS["twist_iterations"]].max())
            report["twist_residual_max"] = float(residuals[:, 1].max())
            report["twist_cap_hits"] = int(counters[:, COUNTERS["twist_cap_hits"]].sum())
            report["twist_stalls"] = int(counters[:, COUNTERS["twist_stalls"]].sum())
        if self.twist == "kmoch":
            report["twist_branch_switches"] = int(counters[:, COUNTERS["twist_branch_switches"]].sum())
        if self.strand_contact is not None:
            fused = self._contact_grid.deepest_since_reset(reset)
            report["strand_contact_depth_max"] = max(self._contact_depth, fused)
        if reset:
            self._reset_counters()
            self._contact_depth = 0.0
        return report

    def _reset_counters(self):
        self.rods.reset_counters()

    # ---- the rods (system.RodSystem): state in and out, frames, twist, elastic energy --------
    @property
    def n_strands(self) -> int:
        return self.groom.n_strands

    def positions(self) -> np.ndarray:
        """Node positions [S, N, 3] in metres (padding nodes repeat each strand's last node)."""
        return self.rods.positions()

    def velocities(self) -> np.ndarray:
        """Node velocities [S, N, 3] in m/s."""
        return self.rods.velocities()

    def set_positions(self, x) -> None:
        """Set node positions [S, N, 3] (metres) and recompute the frames (RodSystem.set_positions)."""
        self.rods.set_positions(x)
        self._history_h = None

    def set_velocities(self, v) -> None:
        """Set node velocities [S, N, 3] in m/s."""
        self.rods.set_velocities(v)
        self._history_h = None

    def material_angles(self) -> np.ndarray:
        """Material angles theta [S, N-1] in radians, measured from the Bishop frame."""
        return self.rods.material_angles()

    def set_material_angles(self, theta) -> None:
        self.rods.set_material_angles(theta)

    def frames(self) -> dict:
        """Bishop and material frames, tangents and curvature binormals (RodSystem.frames)."""
        return self.rods.frames()

    def update_frames(self) -> None:
        """Bishop and material frames and curvature binormals from the current positions."""
        self.rods.update_frames()

    def update_twist(self) -> dict:
        """Solve the free edges' material angles with the chosen twist mode (RodSystem.update_twist);
        edges held by twist-holding clips take the clips' latest angles."""
        return self.rods.update_twist(self._clip_arrays())

    def _clip_arrays(self):
        """The pin table's device arrays when clips hold twist, else None."""
        if not self._pins.clips:
            return None
        self._pins.upload()
        return self._pins.device

    def strand_elastic_energy(self) -> np.ndarray:
        """Elastic energy of each strand [S] in joules, material angles as they are."""
        return self.rods.strand_elastic_energy()

    def elastic_energy(self) -> float:
        """Bending + twist energy of all strands in joules, material angles held as they are."""
        return self.rods.elastic_energy()

    def elastic_forces(self) -> np.ndarray:
        """Elastic forces [S, N, 3] in newtons (RodSystem.elastic_forces), with the term of edges
        whose material frame a clip holds in space."""
        arrays_ = self._clip_arrays()
        return self.rods.elastic_forces(clip=None if arrays_ is None else arrays_[3])

    def bending_stiffness(self) -> np.ndarray:
        """The implicit step's stiffness matrix [S, 3N, 3N] in N/m (RodSystem.bending_stiffness)."""
        return self.rods.bending_stiffness()

    def theta_gradient(self) -> np.ndarray:
        """dE/dtheta^j [S, N-1] in joules per radian (the twist solve drives the free ones to 0)."""
        return self.rods.theta_gradient()

    # ---- energies of the motion ---------------------------------------------------------
    def _mechanical(self):
        """Per-strand kinetic and gravitational energy [S], [S] in joules."""
        st, md = self.state, self.model
        strand_mechanical_energy(md.node_count, md.mass, self._pins.free_inv_mass, st.x, st.v,
                                 self.control.loads, st.strand_scalar, self._potential)
        return st.strand_scalar.to_numpy().astype(np.float64), self._potential.to_numpy().astype(np.float64)

    def kinetic_energy(self) -> float:
        """Sum of 1/2 m |v|^2 over free nodes [J] (the head-driven root node excluded)."""
        return float(self._mechanical()[0].sum())

    def gravity_energy(self) -> float:
        """Gravitational potential -sum m g . x over free nodes [J] (zero at the origin)."""
        return float(self._mechanical()[1].sum())

    def stretch_energy(self) -> float:
        """Stretch energy sum_j EA (|e_j| - |ebar_j|)^2 / (2 |ebar_j|) [J] of extensible strands
        (Simulator(extensible=True)); 0 for inextensible ones."""
        if not self.plan.extensible:
            return 0.0
        lengths = np.linalg.norm(np.diff(self.positions(), axis=1), axis=2)
        rest = self.model.rest_length.to_numpy().astype(np.float64)
        ea = self.model.stiffness.to_numpy()[:, 3].astype(np.float64)
        used = np.arange(rest.shape[1])[None, :] < (self.model.node_count.to_numpy() - 1)[:, None]
        return float(np.sum(np.where(used, ea[:, None] * (lengths - rest) ** 2 / (2 * np.where(used, rest, 1.0)),
                                     0.0)))

    def total_energy(self) -> float:
        """kinetic + gravity + elastic (+ stretch, extensible strands) [J]."""
        k, p = self._mechanical()
        return float(k.sum() + p.sum()) + self.elastic_energy() + self.stretch_energy()


def _max_air_speed(wind) -> float:
    """Fastest air [m/s] a wind can blow: mean * (1 + gust) + three turbulence rms."""
    if isinstance(wind, Wind):
        return (float(np.linalg.norm(wind.velocity)) * (1.0 + wind.gust_amplitude) + 3.0 * wind.turbulence)
    return float(np.linalg.norm(wind))


def _check_max_substeps(value) -> int:
    if not (is_integer(value) and value >= 1):
        raise ValueError(f"max_substeps must be an integer >= 1, got {value!r}")
    return int(value)


def _check_arguments(groom, twist, projection_iterations, twist_iterations, drag, root_motion,
                     wind, colliders, touch, hair_interaction, gravity, integrator, strand_contact,
                     projection, extensible):
    check_common_inputs(groom=groom, twist=twist, motion=root_motion, motion_name="root_motion", wind=wind,
                        touch=touch, hair_interaction=hair_interaction, gravity=gravity, drag=drag,
                        integrator=integrator, strand_contact=strand_contact, projection=projection,
                        extensible=extensible)
    for name, value in (("projection_iterations", projection_iterations),
                        ("twist_iterations", twist_iterations)):
        if not (is_integer(value) and value >= 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    for k, c in enumerate(colliders):
        if not isinstance(c, COLLIDER_TYPES):
            raise ValueError(f"colliders[{k}] must be one of Sphere, Ellipsoid, Capsule, Plane, "
                             f"MeshCollider; got {type(c).__name__}")


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
