"""Checkpointed reverse mode over the whole run (docs/differentiable.md, "Memory").

The run of T steps is cut into segments of K steps. The forward pass keeps each segment's
starting state (a checkpoint) and the positions the loss asks for. The backward pass goes
through the segments from the last: it loads the segment's checkpoint, runs its K steps again
into the slot arrays, seeds the loss gradient, and replays the kernels' gradients (`kernel.grad`)
in reverse. The gradient of the segment's starting state is carried to the end of the segment
before it. Memory: K slots plus T / K checkpoints; time: two forward runs plus one reverse."""

import numpy as np
import taichi as ti

from .fields import SLOT_FIELDS


@ti.data_oriented
class SegmentKernels:
    """Mixin: the segment bookkeeping kernels (not differentiated) and the tape."""

    @ti.kernel
    def save(self, c: ti.i32, k: ti.i32):
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            self.ck_x[c, s, i] = self.x[k, s, i]
            self.ck_v[c, s, i] = self.v[k, s, i]
            if i < self.n_nodes - 1:
                self.ck_ang[c, s, i] = self.ang[k, self.twist_iterations, s, i]

    @ti.kernel
    def load(self, c: ti.i32):
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            self.x[0, s, i] = self.ck_x[c, s, i]
            self.v[0, s, i] = self.ck_v[c, s, i]
            if i < self.n_nodes - 1:
                self.ang[0, self.twist_iterations, s, i] = self.ck_ang[c, s, i]

    @ti.kernel
    def carry_out(self):
        """The gradient of the segment's starting state, kept for the segment before."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            self.carry_x[s, i] = self.x.grad[0, s, i]
            self.carry_v[s, i] = self.v.grad[0, s, i]
            if i < self.n_nodes - 1:
                self.carry_ang[s, i] = self.ang.grad[0, self.twist_iterations, s, i]

    @ti.kernel
    def carry_in(self, k: ti.i32):
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            self.x.grad[k, s, i] += self.carry_x[s, i]
            self.v.grad[k, s, i] += self.carry_v[s, i]
            if i < self.n_nodes - 1:
                self.ang.grad[k, self.twist_iterations, s, i] += self.carry_ang[s, i]

    @ti.kernel
    def seed(self, k: ti.i32, g: ti.types.ndarray()):
        """Add the loss gradient g [S, N, 3] to slot k's positions."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            if i < self.node_count[s]:
                self.x.grad[k, s, i] += ti.Vector([ti.cast(g[s, i, d], float) for d in ti.static(range(3))])

    @ti.kernel
    def gather(self, k: ti.i32, out: ti.types.ndarray()):
        """Slot k's positions into out [S, N, 3] (float64)."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            if i < self.node_count[s]:
                for d in ti.static(range(3)):
                    out[s, i, d] = self.x[k, s, i][d]

    @ti.kernel
    def clear_forces(self):
        for k, s, i in self.f:
            self.f[k, s, i] = ti.Vector([0.0, 0.0, 0.0])

    # ---------------------------------------------------------------- the tape
    def segment_length(self, c: int) -> int:
        """Steps in segment c (the last may be shorter)."""
        return min(self.segment_steps, self.n_steps - c * self.segment_steps)

    def segment_ops(self, c: int) -> list:
        """The kernel launches of segment c, in order: (kernel, args)."""
        first = c * self.segment_steps
        count = self.segment_length(c)
        ops = [(self.pose, self.pose_key(first, 0))]
        if c == 0:
            ops.append((self.start, ()))
        ops += [(self.frames, (0,)), (self.binormals, (0,))]
        for k in range(count):
            ops.append((self.pose, self.pose_key(first + k + 1, k + 1)))
            ops += [(self.bend_gradients, (k,)), (self.holonomy, (k,)), (self.forces, (k,)),
                    (self.integrate, (k, self.dt))]
            for p in range(self.projection_iterations):
                ops += [(self.push, (k, p)), (self.length_system, (k, p)), (self.length_solve, (k, p)),
                        (self.length_move, (k, p))]
            ops += [(self.finish, (k, self.dt)), (self.frames, (k + 1,)), (self.binormals, (k + 1,))]
            for w in range(self.twist_iterations):
                src = (k, self.twist_iterations) if w == 0 else (k + 1, w)
                ops += [(self.twist_system, (k + 1, w) + src), (self.twist_solve, (k, w)),
                        (self.twist_update, (k + 1, w) + src)]
        return ops

    def pose_key(self, step: int, k: int) -> tuple:
        """(slot, key, weight) of the head pose at global step `step` (keys evenly over the run)."""
        position = step * (len(self.key_values) - 1) / self.n_steps
        key = min(int(np.floor(position)), len(self.key_values) - 2)
        return k, key, float(position - key)

    def run_segment(self, c: int) -> tuple[list, int]:
        """Run segment c forward from its checkpoint; returns its launches and step count."""
        if c > 0:
            self.load(c)
        self.clear_forces()
        ops = self.segment_ops(c)
        for kernel, args in ops:
            kernel(*args)
        return ops, self.segment_length(c)

    def forward_pass(self, steps_wanted) -> dict:
        """The whole run; returns {step: positions [S, N, 3] (NaN on padding)} for steps_wanted
        and records the checkpoints and the run's health (`self.health`)."""
        wanted = set(int(n) for n in steps_wanted)
        found = {}
        self.health = {}
        for kernel in self.rest_kernels():
            kernel()
        for c in range(self.n_segments):
            _, count = self.run_segment(c)
            first = c * self.segment_steps
            for k in range(count + 1):
                if first + k in wanted and first + k not in found:
                    found[first + k] = self.positions_of(k)
            self.check_health(first + count, count)
            if c + 1 < self.n_segments:
                self.save(c + 1, count)
        return found

    def positions_of(self, k: int) -> np.ndarray:
        out = np.full((self.n_strands, self.n_nodes, 3), np.nan)
        self.gather(k, out)
        return out

    def backward_pass(self, seeds: dict) -> None:
        """Gradients of the loss into the input fields' .grad, from seeds {step: dL/dx [S, N, 3]}.
        Follows forward_pass at once: the slot arrays still hold the last segment, which is
        therefore not run again."""
        for c in reversed(range(self.n_segments)):
            if c == self.n_segments - 1:
                ops, count = self.segment_ops(c), self.segment_length(c)
            else:
                ops, count = self.run_segment(c)
            for name in SLOT_FIELDS:
                getattr(self, name).grad.fill(0)
            if c + 1 < self.n_segments:
                self.carry_in(count)
            first = c * self.segment_steps
            for step, g in seeds.items():
                k = step - first
                if 0 < k <= count or (k == 0 and c == 0):
                    self.seed(k, np.ascontiguousarray(g, dtype=np.float64))
            for kernel, args in reversed(ops):
                kernel.grad(*args)
            self.carry_out()
        for kernel in reversed(self.rest_kernels()):
            kernel.grad()
