"""The differentiable step's rest-shape, head-pose and frame kernels (docs/differentiable.md).

The step is Kmoch's loop as stages, one kernel each (this module, dynamics.py, tridiagonal.py):
each reads one time slot's arrays and writes its own or the next slot's, so that Taichi's
reverse mode replays it (`kernel.grad`) in reverse order (tape.py). Every array a kernel
writes is written once per launch (or accumulated with +=) and read only after it is written,
the rule under which Taichi's reverse mode is exact. Serial sweeps along a strand (transport,
suffix sums) run one thread per strand whose loop body reads only arrays; the tridiagonal
solves carry an adjoint of their own (tridiagonal.py).

Slot arrays (fields.py; K = the segment's step count, P projection iterations, W twist
iterations; S strands, N nodes; `float` is the process precision):
- x, v [K+1, S, N] vec3 (m, m/s): state at the slot's start; ang [K+1, W+1, S, N-1] rad:
  the material angles, the slot's own in column W, the twist iterations of a new slot in
  columns 1..W-1; pose_r, pose_t [K+1]: the head's pose;
- u [K+1, S, N-1] vec3 (Bishop vectors), kb [K+1, S, N] vec3 (curvature binormals);
- f [K, S, N] vec3 (N): forces; bend [K, S, N-1] (J): dE_bend / dtheta; hol [K, S, N] (J): its
  suffix sums (the holonomy term's weights);
- xp [K, P+1, S, N] vec3: predicted positions and projection iterates; xc [K, P, S, N]: after
  the head's push; pdiag, pup, pres, pc, pd, lam [K, P, S, N-1]: the projection's tridiagonal
  system, elimination and multipliers;
- tdiag, tup, tres, tc, td, tstep [K, W, S, N-1]: the twist Newton step's, likewise."""

import taichi as ti

from ..rods.arrays import vec3
from ..rods.frames import curvature_binormal
from .geometry import clamp_view, rotated, rotation_from_vector, view_angle_terms, views

PI = 3.141592653589793


@ti.func
def transported(w, a, b):
    """w turned by the rotation taking unit tangent a to unit tangent b about a x b, then made
    orthonormal to b. Branch-free (reverse mode through a branch in a serial loop needs a
    stack of past values): a fold of an edge back onto the one before, which grooms refuse,
    would divide by ~0."""
    axis = a.cross(b)
    c = a.dot(b)
    turned = c * w + axis.cross(w) + axis.dot(w) * axis / ti.max(1.0 + c, 1e-12)
    return (turned - turned.dot(b) * b).normalized()


@ti.func
def orthonormal_to(u, t):
    """u with its component along unit t removed, normalised."""
    return (u - u.dot(t) * t).normalized()


@ti.data_oriented
class FrameKernels:
    """Mixin: the rest shape, head poses and frames kernels; the arrays are the problem's (problem.py)."""

    # ---------------------------------------------------------------- rest shape and material
    @ti.kernel
    def rest_lengths(self):
        """Stiffnesses (docs/model.md, "Cross-section and stiffness"), the root tangent (head
        coordinates) and rest edge lengths."""
        for s, j in ti.ndrange(self.n_strands, self.n_nodes - 1):
            if j == 0:
                root_e = ti.sqrt(self.ellipticity[s])
                a = self.radius[s] * root_e
                b = self.radius[s] / root_e
                self.stiffness[s] = vec3(self.youngs_modulus[s] * PI * a * a * a * b / 4.0,
                                         self.youngs_modulus[s] * PI * a * b * b * b / 4.0,
                                         self.shear_modulus[s] * PI * a * a * a * b * b * b / (a * a + b * b))
                self.root_t_head[s] = (self.rest_x[s, 1] - self.rest_x[s, 0]).normalized()
            if j < self.node_count[s] - 1:
                self.rest_length[s, j] = (self.rest_x[s, j + 1] - self.rest_x[s, j]).norm()

    @ti.kernel
    def rest_masses(self):
        """Voronoi lengths (half an edge at either end) and node masses rho A l_i."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            n = self.node_count[s]
            if i < n:
                length = 0.0
                if i > 0:
                    length += 0.5 * self.rest_length[s, i - 1]
                if i < n - 1:
                    length += 0.5 * self.rest_length[s, i]
                self.voronoi[s, i] = length
                self.mass[s, i] = self.density[s] * PI * self.radius[s] * self.radius[s] * length

    @ti.kernel
    def rest_frames(self):
        """The rest shape's Bishop vectors (head coordinates), transported from the root frame.
        A serial sweep per strand whose loop body reads only arrays, so reverse mode replays it
        exactly (Taichi 1.7 differentiates a value computed before an inner loop and used in it
        wrongly)."""
        for s in range(self.n_strands):
            for j in range(self.node_count[s] - 1):
                rt = self.root_t_head[s]
                back = ti.max(j - 1, 0)
                t_prev = (self.rest_x[s, back + 1] - self.rest_x[s, back]).normalized()
                t = (self.rest_x[s, j + 1] - self.rest_x[s, j]).normalized()
                first = j == 0
                self.rest_u[s, j] = transported(ti.select(first, self.root_u_head[s], self.rest_u[s, back]),
                                                ti.select(first, rt, t_prev), t)

    @ti.kernel
    def rest_binormals(self):
        for s, i in ti.ndrange(self.n_strands, self.n_nodes - 1):
            if i < self.node_count[s] - 1:
                a = self.root_t_head[s]
                if i > 0:
                    a = self.rest_x[s, i] - self.rest_x[s, i - 1]
                self.rest_kb[s, i] = curvature_binormal(a, self.rest_x[s, i + 1] - self.rest_x[s, i])

    @ti.kernel
    def rest_curvatures(self):
        """rest_kappa: each node's binormal seen from the edge before (the clamp's frame at node
        0) and after, at the rest angles."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes - 1):
            if i < self.node_count[s] - 1:
                kbi = self.rest_kb[s, i]
                rt = self.root_t_head[s]
                d1 = orthonormal_to(self.root_u_head[s], rt)
                before = clamp_view(kbi, d1, rt.cross(d1))
                if i > 0:
                    t0 = (self.rest_x[s, i] - self.rest_x[s, i - 1]).normalized()
                    before, _, _ = views(kbi, self.rest_u[s, i - 1], t0, self.rest_theta[s, i - 1])
                t1 = (self.rest_x[s, i + 1] - self.rest_x[s, i]).normalized()
                after, _, _ = views(kbi, self.rest_u[s, i], t1, self.rest_theta[s, i])
                self.rest_kappa[s, i] = ti.Vector([before[0], before[1], after[0], after[1]])

    def rest_kernels(self) -> list:
        """The rest shape's kernels in order (run forward once per run, their gradients last)."""
        return [self.rest_lengths, self.rest_masses, self.rest_frames, self.rest_binormals, self.rest_curvatures]

    # ---------------------------------------------------------------- head pose and start
    @ti.kernel
    def pose(self, k: ti.i32, key: ti.i32, weight: float):
        """Slot k's head pose: the pose parameters interpolated between keys `key` and key + 1."""
        for _ in range(1):  # a loop, so that reverse mode takes the kernel as one loop body
            p = (1.0 - weight) * self.keys[key] + weight * self.keys[key + 1]
            self.pose_r[k] = rotation_from_vector(ti.Vector([p[0], p[1], p[2]]))
            self.pose_t[k] = ti.Vector([p[3], p[4], p[5]])

    @ti.func
    def placed(self, k, y):
        """Rest-pose point y [m] carried by slot k's head pose (about the pivot)."""
        return rotated(self.pose_r[k], y - self.pivot[None]) + self.pivot[None] + self.pose_t[k]

    @ti.kernel
    def start(self):
        """Slot 0 from the rest shape (or the given start) at the first pose, the initial
        velocities, the rest angles."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            if i < self.node_count[s]:
                if ti.static(self.own_start):
                    self.x[0, s, i] = self.placed(0, self.start_x[s, i])
                else:
                    self.x[0, s, i] = self.placed(0, self.rest_x[s, i])
                self.v[0, s, i] = self.initial_v[s, i]
            if i < self.node_count[s] - 1:
                self.ang[0, self.twist_iterations, s, i] = self.rest_theta[s, i]

    # ---------------------------------------------------------------- frames
    @ti.func
    def root_frame(self, k, s):
        """Slot k's clamp frame of strand s: (root_t, d1, d2), carried by the head."""
        rt = rotated(self.pose_r[k], self.root_t_head[s])
        d1 = orthonormal_to(rotated(self.pose_r[k], self.root_u_head[s]), rt)
        return rt, d1, rt.cross(d1)

    @ti.kernel
    def frames(self, k: ti.i32):
        """Slot k's Bishop vectors u: transported from the clamp frame along the strand (a
        serial sweep whose loop body reads only arrays, as rest_frames)."""
        for s in range(self.n_strands):
            for j in range(self.node_count[s] - 1):
                rt, d1, _ = self.root_frame(k, s)
                back = ti.max(j - 1, 0)
                t_prev = (self.x[k, s, back + 1] - self.x[k, s, back]).normalized()
                t = (self.x[k, s, j + 1] - self.x[k, s, j]).normalized()
                first = j == 0
                self.u[k, s, j] = transported(ti.select(first, d1, self.u[k, s, back]),
                                              ti.select(first, rt, t_prev), t)

    @ti.kernel
    def binormals(self, k: ti.i32):
        """Slot k's curvature binormals kb (node 0's against the clamp's tangent)."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes - 1):
            if i < self.node_count[s] - 1:
                a = rotated(self.pose_r[k], self.root_t_head[s])
                if i > 0:
                    a = self.x[k, s, i] - self.x[k, s, i - 1]
                self.kb[k, s, i] = curvature_binormal(a, self.x[k, s, i + 1] - self.x[k, s, i])

    @ti.func
    def edge_view(self, k, s, i, j, angle):
        """Node i's binormal seen from edge j of slot k at material angle `angle`: (w, m1, m2)."""
        t = (self.x[k, s, j + 1] - self.x[k, s, j]).normalized()
        return views(self.kb[k, s, i], self.u[k, s, j], t, angle)

    @ti.func
    def edge_bend_terms(self, k, s, j, n, angle):
        """Bending energy terms of edge j's two views (nodes j and j + 1) at angle `angle`:
        (energy, d/dangle, d2/dangle2)."""
        ei = self.stiffness[s]
        energy, grad, hess = 0.0, 0.0, 0.0
        w, _, _ = self.edge_view(k, s, j, j, angle)
        rk = self.rest_kappa[s, j]
        e, g, h = view_angle_terms(w, ti.Vector([rk[2], rk[3]]), ei[0], ei[1], 0.5 / self.voronoi[s, j])
        energy += e
        grad += g
        hess += h
        if j + 1 <= n - 2:
            w1, _, _ = self.edge_view(k, s, j + 1, j, angle)
            rk1 = self.rest_kappa[s, j + 1]
            e1, g1, h1 = view_angle_terms(w1, ti.Vector([rk1[0], rk1[1]]), ei[0], ei[1],
                                          0.5 / self.voronoi[s, j + 1])
            energy += e1
            grad += g1
            hess += h1
        return energy, grad, hess
