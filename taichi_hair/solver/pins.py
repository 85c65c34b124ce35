"""Pins and clips: any node held at a point, any edge clamped, in the world or on the head.

A pin gives its node infinite mass (inv_mass 0): symplectic Euler leaves it alone, the fast
projection cannot move it, contacts and hair-hair interaction skip it, and after the Euler
update it is put at its target, exactly as the root node is put on the head. A clip
(clamp=True) pins the edge (node, node + 1): both nodes, the second at the first's target plus
the edge vector the edge had when it was clipped (position and direction held; the edge's
material angle is not, unless the clip holds twist too: hold_twist=True keeps the edge's
material frame at the clip's director, turned about the edge by an angle that `turn_pin` drives
in time, and the twist solve treats that edge as held; docs/model.md, "Clips that hold twist").
A slider (slide=True) is a clip on a strand's last edge that is free to move along the edge's
direction at clip time: its two nodes move together along that axis under the forces on them
and the pull of the strand (the projection gives the pair the anisotropic inverse mass
a a^T / (m_c + m_c+1)), and are held across it.

Decisions (see also `Simulator.add_pin`):
- Targets move linearly in time over the next `Simulator.step(n)` call: a target set by
  `move_pin` is reached at the end of that call, every substep of it placing the node at its
  share of the way (so move_pin once per frame gives the node the velocity (new - old) / frame
  time). Head-attached targets are interpolated in head coordinates and carried by the head
  pose of every substep, like the root nodes.
- Adding a pin at the node's current position does not move it; the next step gives the node
  the pin's velocity (zero for a still pin): a moving node is stopped, which can only take
  energy out. Releasing a pin restores the node's mass; it keeps the velocity of its last step.
- Total energy counts a pinned node as the free node it was (its kinetic and gravitational
  energy), so adding and releasing a still pin leaves the total unchanged.
- An edge whose two nodes are both held (a clip, two neighbouring pins, a pin on node 1 beside
  the root) is prescribed, not projected: the pins set its length (step.strand_project).
- Pins are not part of `save_state` checkpoints: scene scripts add them in `setup`.

Device data, [S, N] per node: pin_mode (0 free, 1 world target, 2 head target), pin_start and
pin_end [m] (the targets at the start and end of the current step call, world or head
coordinates by mode), clip [S, N, 3] vec3 on a clip's first node c: [0] the held director d1 at
angle 0 (world or head coordinates, perpendicular to the edge), [1] (angle at the start and end
of the step call [rad], 1 if the clip holds twist else 0), [2] on both nodes of a slider
a / sqrt(m_c + m_c+1) (a the unit slide axis; zero elsewhere). They are Taichi ndarrays: adding
or releasing pins never recompiles.
"""

import numpy as np
import taichi as ti

from ..rods import arrays
from .collisions import from_head, head_rotate
from ..rods.frames import parallel_transport
from ..rods.twist import edge_twist_held

FREE, WORLD, HEAD = 0, 1, 2
ATTACH = {"world": WORLD, "head": HEAD}

# With pins a stretch of strand can be held at both ends; taut and straight, its projection
# system is singular (more length constraints than the free nodes can move along the line).
# Levenberg-Marquardt damping of the diagonal, (1 + HELD_DAMPING), keeps every pivot positive;
# it slows the linear convergence only by a factor HELD_DAMPING per iteration. The implicit
# step damps its length rows by the same amount.
HELD_DAMPING = 1e-6


@ti.func
def strand_place_pins(s, fraction, clips: ti.template(), node_count: ti.template(), pin_mode: ti.template(),
                      pin_start: ti.template(), pin_end: ti.template(), clip: ti.template(),
                      head: ti.template(), now, x: ti.template()):
    """Put strand s's pinned nodes at their targets `fraction` of the way from start to end
    (head targets carried by head pose `now`); a slider's nodes keep their place along its axis."""
    for i in range(node_count[s]):
        mode = pin_mode[s, i]
        if mode != FREE:
            p = pin_start[s, i] + fraction * (pin_end[s, i] - pin_start[s, i])
            if mode == HEAD:
                p = from_head(head, now, p)
            if ti.static(clips):
                b = clip[s, i, 2]
                if b.dot(b) > 0.0:
                    p += b * (b.dot(arrays.point(x, s, i) - p) / b.dot(b))
            x[s, i] = p


@ti.func
def clip_fraction_angle(clip: ti.template(), s, c, fraction):
    """The angle [rad] of the clip whose first node is c, `fraction` of the way through the call."""
    a = clip[s, c, 1]
    return a.x + fraction * (a.y - a.x)


@ti.func
def strand_hold_clip_twist(s, fraction, node_count: ti.template(), pin_mode: ti.template(),
                           clip: ti.template(), head: ti.template(), now, bishop_u: ti.template(),
                           bishop_v: ti.template(), theta: ti.template()):
    """theta of every edge a twist-holding clip holds: the angle of the clip's director (turned
    by its drive angle about the edge) in the edge's Bishop frame, on the branch nearest the
    edge's previous angle (so a clip turned through 2 pi twists the strand through 2 pi)."""
    for c in range(node_count[s] - 1):
        if edge_twist_held(s, c, True, clip):
            d = clip[s, c, 0]
            if pin_mode[s, c] == HEAD:
                d = head_rotate(head, now, d)
            u = bishop_u[s, c]
            v = bishop_v[s, c]
            t = u.cross(v)  # the edge's tangent (v = t x u)
            d = (d - d.dot(t) * t).normalized()
            phi = clip_fraction_angle(clip, s, c, fraction)
            d = d * ti.cos(phi) + t.cross(d) * ti.sin(phi)
            angle = ti.atan2(d.dot(v), d.dot(u))
            theta[s, c] = angle + 2.0 * ti.math.pi * ti.round((theta[s, c] - angle) / (2.0 * ti.math.pi))


@ti.func
def strand_carry_root_frame(s, x: ti.template(), root_t: ti.template(), root_u: ti.template()):
    """Pinned root: the root edge's reference (t, u) becomes its current tangent and its Bishop
    vector u^0, parallel-transported in time from the edge's previous direction (DER's free
    first edge), with the same operations as frames.strand_frames, so u^0 is unchanged. (It is
    recomputed, not read back from bishop_u[s, 0]: inside the fused kernel's step loop Taichi
    1.7 served that read from a value cached before the frames stage wrote it.)"""
    t = arrays.edge(x, s, 0, 1).normalized()
    u = parallel_transport(root_u[s], root_t[s], t)
    root_u[s] = (u - u.dot(t) * t).normalized()
    root_t[s] = t


def _index(name, value, upper):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if not 0 <= value < upper:
        raise ValueError(f"{name} must be in [0, {upper - 1}], got {value}")
    return int(value)


def _targets(name, value, count):
    """[count, 3] float64 targets from one 3-vector or [count, 3], or ValueError naming `name`."""
    t = np.asarray(value, dtype=np.float64)
    if t.shape == (3,):
        t = np.broadcast_to(t, (count, 3))
    if t.shape != (count, 3):
        shapes = "[3]" if count == 1 else f"[3] or [{count}, 3]"
        raise ValueError(f"{name} must be a 3-vector in metres, shape {shapes}, got shape {list(t.shape)}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return np.array(t)


class PinTable:
    """The pins of one simulator: a host-side table (records, per-node modes and targets) and
    its device copy, uploaded before a step when something changed.

    inv_mass: the model's [S, N] ndarray, changed in place (0 on held nodes); free_inv_mass:
    an ndarray copy of the unpinned masses (energies count pinned nodes as free ones)."""

    def __init__(self, model, root: str):
        self.model = model
        self.node_counts = np.asarray(model.groom.node_counts)
        self.first_free = {"edge": 2, "free": 0}.get(root, 1)  # the nodes riding on the head
        self.free_inv = model.inv_mass.to_numpy().astype(np.float64)
        self.free_inv_mass = arrays.scalars(self.free_inv.shape, self.free_inv)
        self.inv = self.free_inv.copy()  # host copy of model.inv_mass with the pins in
        shape = self.free_inv.shape
        self.owner = np.full(shape, -1, dtype=np.int64)
        self.mode = np.zeros(shape, dtype=np.int32)
        self.start = np.zeros(shape + (3,))
        self.end = np.zeros(shape + (3,))
        self.clip = np.zeros(shape + (3, 3))
        self.records = {}
        self.next_id = 0
        self.device = None  # (mode, start, end) ndarrays once a pin was added
        self.dirty = False

    @property
    def active(self) -> bool:
        return bool(self.records)

    @property
    def clips(self) -> bool:
        """Whether a clip holds twist or slides (the step compiles their stages only then)."""
        return any(r["hold_twist"] or r["slide"] for r in self.records.values())

    # ---- edits ----------------------------------------------------------------------
    def add(self, strands, nodes, targets, clamp, attach, positions, head, hold_twist=False,
            slide=False, directors=None):
        """Validate everything, then add the pins; returns their ids [K]. positions: world
        node positions [S, N, 3]; head: (R, t), the pose those positions belong to; directors:
        the material directors m1 [S, N-1, 3] (the director a twist-holding clip holds)."""
        if attach not in ATTACH:
            raise ValueError(f"attach must be 'world' or 'head', got {attach!r}")
        for name, value in (("clamp", clamp), ("hold_twist", hold_twist)):
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {value!r}")
        axis = None  # the slide axis: None (the clipped edge's direction) or a unit 3-vector
        if not isinstance(slide, (bool, np.bool_)):
            axis = np.asarray(slide, dtype=np.float64) if np.ndim(slide) == 1 else None
            if axis is None or axis.shape != (3,) or not np.all(np.isfinite(axis)) \
                    or np.linalg.norm(axis) == 0:
                raise ValueError(f"slide must be True, False or a nonzero 3-vector (the slide axis), "
                                 f"got {slide!r}")
            axis = axis / np.linalg.norm(axis)
            slide = True
        if (hold_twist or slide) and not clamp:
            raise ValueError("hold_twist and slide need clamp=True: they hold an edge, not a node")
        if slide and attach != "world":
            raise ValueError("a slider (slide=True) slides along a world axis: attach must be 'world'")
        held = self._checked_nodes(strands, nodes, bool(clamp))
        if slide:
            for s, i in held:
                if i != self.node_counts[s] - 2:
                    raise ValueError(f"a slider must clip strand {s}'s last edge: node must be "
                                     f"{self.node_counts[s] - 2} (or -2), got {i}")
        count = len(held)
        rotation, translation = head
        here = positions[[s for s, _ in held], [i for _, i in held]]
        target = here if targets is None else _targets("target", targets, count)
        ids = []
        for k, (s, i) in enumerate(held):
            offset = positions[s, i + 1] - positions[s, i] if clamp else None
            if attach == "head":
                if targets is None:
                    target[k] = rotation.T @ (target[k] - translation)
                if clamp:
                    offset = rotation.T @ offset
            pid = self.next_id
            self.next_id += 1
            self.records[pid] = {"strand": s, "node": i, "clamp": bool(clamp), "attach": attach,
                                 "target": target[k].copy(), "offset": offset,
                                 "hold_twist": bool(hold_twist), "slide": bool(slide), "angle": 0.0}
            for node in (i, i + 1) if clamp else (i,):
                self.owner[s, node] = pid
                self.mode[s, node] = ATTACH[attach]
                self.inv[s, node] = 0.0
            if hold_twist:
                d = np.asarray(directors[s, i], dtype=np.float64)
                self.clip[s, i, 0] = rotation.T @ d if attach == "head" else d
                self.clip[s, i, 1] = (0.0, 0.0, 1.0)
            if slide:
                a = offset / np.linalg.norm(offset) if axis is None else axis
                mass = 1.0 / self.free_inv[s, i] + 1.0 / self.free_inv[s, i + 1]
                self.clip[s, i, 2] = self.clip[s, i + 1, 2] = a / np.sqrt(mass)
            self._write(pid, target[k], both=True)
            ids.append(pid)
        self.dirty = True
        return np.array(ids, dtype=np.int64)

    def _checked_nodes(self, strands, nodes, clamp):
        strands = np.atleast_1d(np.asarray(strands, dtype=object))
        nodes = np.atleast_1d(np.asarray(nodes, dtype=object))
        if strands.ndim != 1 or nodes.ndim != 1:
            raise ValueError("strand and node must be integers or 1-D sequences of integers")
        if len(nodes) == 1 and len(strands) > 1:
            nodes = np.repeat(nodes, len(strands))
        if len(strands) != len(nodes):
            raise ValueError(f"strand and node must have the same length, got {len(strands)} and "
                             f"{len(nodes)}")
        held, seen = [], set()
        for s, i in zip(strands, nodes):
            s = _index("strand", s, len(self.node_counts))
            n = int(self.node_counts[s])
            if isinstance(i, (int, np.integer)) and not isinstance(i, (bool, np.bool_)) and -n <= i < 0:
                i = int(i) + n  # from the strand's end: -1 is the tip
            last = n - 2 if clamp else n - 1
            i = _index("node", i, last + 1)
            if i < self.first_free:
                raise ValueError(f"node {i} of strand {s} rides on the head already (the root); "
                                 f"node must be >= {self.first_free}")
            for node in (i, i + 1) if clamp else (i,):
                if self.owner[s, node] >= 0 or (s, node) in seen:
                    other = self.owner[s, node]
                    raise ValueError(f"node {node} of strand {s} is already held"
                                     f"{f' by pin {other}' if other >= 0 else ' (listed twice)'}")
                seen.add((s, node))
            held.append((s, i))
        return held

    def move(self, pin_ids, targets):
        ids = self._known(pin_ids)
        target = _targets("target", targets, len(ids))
        for k, pid in enumerate(ids):
            self.records[pid]["target"] = target[k].copy()
            self._write(pid, target[k], both=False)
        self.dirty = True

    def turn(self, pin_ids, angles):
        """New drive angles [rad] of twist-holding clips, reached at the end of the next step call."""
        ids = self._known(pin_ids)
        angles = np.broadcast_to(np.asarray(angles, dtype=np.float64), (len(ids),))
        if not np.all(np.isfinite(angles)):
            raise ValueError(f"angle must be finite radians, got {angles!r}")
        for pid, angle in zip(ids, angles):
            r = self.records[pid]
            if not r["hold_twist"]:
                raise ValueError(f"pin {pid} does not hold twist: add it with clamp=True, hold_twist=True")
            r["angle"] = float(angle)
            self.clip[r["strand"], r["node"], 1, 1] = float(angle)
        self.dirty = True

    def release(self, pin_ids):
        for pid in self._known(pin_ids):
            r = self.records.pop(pid)
            s, i = r["strand"], r["node"]
            self.clip[s, i] = 0.0
            if r["clamp"]:
                self.clip[s, i + 1, 2] = 0.0
            for node in (i, i + 1) if r["clamp"] else (i,):
                self.owner[s, node] = -1
                self.mode[s, node] = FREE
                self.inv[s, node] = self.free_inv[s, node]
        self.dirty = True

    def _known(self, pin_ids):
        ids = [pin_ids] if np.ndim(pin_ids) == 0 else list(np.asarray(pin_ids).ravel())
        out = []
        for pid in ids:
            if isinstance(pid, (bool, np.bool_)) or not isinstance(pid, (int, np.integer)) \
                    or int(pid) not in self.records:
                raise ValueError(f"pin_id {pid!r} is not a pin of this simulator "
                                 f"(live ids: {sorted(self.records)[:10]})")
            out.append(int(pid))
        if len(set(out)) != len(out):
            raise ValueError("pin_id lists a pin twice")
        return out

    def _write(self, pid, target, both):
        """Set the end target (and the start too when `both`: a new pin does not move)."""
        r = self.records[pid]
        s, i = r["strand"], r["node"]
        rows = [(i, target)] + ([(i + 1, target + r["offset"])] if r["clamp"] else [])
        for node, p in rows:
            self.end[s, node] = p
            if both:
                self.start[s, node] = p

    def listing(self) -> list[dict]:
        return [{"id": pid, "strand": r["strand"], "node": r["node"], "target": r["target"].copy(),
                 "clamp": r["clamp"], "attach": r["attach"], "hold_twist": r["hold_twist"],
                 "slide": r["slide"], "angle": r["angle"]} for pid, r in sorted(self.records.items())]

    # ---- device side ----------------------------------------------------------------
    def upload(self):
        """Device copies of what changed since the last step (called before each step)."""
        if not self.dirty:
            return
        f = arrays.np_float()
        if self.device is None:
            shape = self.mode.shape
            self.device = (arrays.ints(shape, 0), arrays.vectors(3, shape), arrays.vectors(3, shape),
                           arrays.vectors(3, shape + (3,)))
        self.device[0].from_numpy(self.mode)
        self.device[1].from_numpy(self.start.astype(f))
        self.device[2].from_numpy(self.end.astype(f))
        self.device[3].from_numpy(self.clip.astype(f))
        self.model.inv_mass.from_numpy(self.inv.astype(f))
        self.dirty = False

    def settle(self):
        """After a completed step call: the targets reached become the next call's start."""
        if self.active and not np.array_equal(self.start, self.end):
            self.start[...] = self.end
            self.dirty = True
        if self.active and not np.array_equal(self.clip[..., 1, 0], self.clip[..., 1, 1]):
            self.clip[..., 1, 0] = self.clip[..., 1, 1]
            self.dirty = True
