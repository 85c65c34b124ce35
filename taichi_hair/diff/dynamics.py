"""The differentiable step's dynamics kernels (docs/differentiable.md): forces, the symplectic
Euler update, the projection of edge lengths with the head's push, velocities and the twist
update, each reading slot k's arrays (frames.py lists them) and writing its own.

Work per node or per edge runs one thread each; only the sweeps that must be serial (suffix
sums, tridiagonal solves) run one thread per strand, with no local variable changed from one
iteration to the next, so their reverse mode needs no stack of past values."""

import taichi as ti

from ..rods.arrays import vec3
from ..rods.rod import kb_gradient_to_nodes
from .geometry import clamp_view, view_kb_gradient


@ti.data_oriented
class DynamicsKernels:
    """Mixin: a step's kernels after the frames; the arrays are the problem's (problem.py)."""

    # ---------------------------------------------------------------- forces
    @ti.kernel
    def bend_gradients(self, k: ti.i32):
        """bend[k]: dE_bend / dtheta^j of every edge at the slot's angles."""
        for s, j in ti.ndrange(self.n_strands, self.n_nodes - 1):
            n = self.node_count[s]
            if j < n - 1:
                _, g, _ = self.edge_bend_terms(k, s, j, n, self.ang[k, ti.static(self.twist_iterations), s, j])
                self.bend[k, s, j] = g

    @ti.kernel
    def holonomy(self, k: ti.i32):
        """hol[k, s, i] = sum_{j >= i} bend[k, s, j]: the holonomy term's weights C_i (hol at the
        tip node n - 1 stays 0)."""
        for s in range(self.n_strands):
            for r in range(self.node_count[s] - 1):
                i = self.node_count[s] - 2 - r
                after = ti.select(r == 0, 0.0, self.hol[k, s, i + 1])
                self.hol[k, s, i] = after + self.bend[k, s, i]

    @ti.kernel
    def forces(self, k: ti.i32):
        """f[k] += elastic force at fixed angles (holonomy term included; docs/model.md,
        "Forces"), gravity and drag, node i's bending acting on nodes i - 1, i, i + 1."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            n = self.node_count[s]
            if i < n - 1:
                w_col = ti.static(self.twist_iterations)
                ei = self.stiffness[s]
                rt, d1, d2 = self.root_frame(k, s)
                kbi = self.kb[k, s, i]
                inv_2l = 0.5 / self.voronoi[s, i]
                rk = self.rest_kappa[s, i]
                w1, n1, n2 = self.edge_view(k, s, i, i, self.ang[k, w_col, s, i])
                g = view_kb_gradient(w1, ti.Vector([rk[2], rk[3]]), n1, n2, ei[0], ei[1], inv_2l)
                a = rt
                if i == 0:
                    g += view_kb_gradient(clamp_view(kbi, d1, d2), ti.Vector([rk[0], rk[1]]),
                                          d1, d2, ei[0], ei[1], inv_2l)
                else:
                    a = self.x[k, s, i] - self.x[k, s, i - 1]
                    w0, m1, m2 = self.edge_view(k, s, i, i - 1, self.ang[k, w_col, s, i - 1])
                    g += view_kb_gradient(w0, ti.Vector([rk[0], rk[1]]), m1, m2, ei[0], ei[1], inv_2l)
                b = self.x[k, s, i + 1] - self.x[k, s, i]
                before, after = kb_gradient_to_nodes(g, kbi, a, b)
                c = self.hol[k, s, i]
                before += c * kbi / (2.0 * a.norm())
                after -= c * kbi / (2.0 * b.norm())
                if i > 0:
                    self.f[k, s, i - 1] -= before
                self.f[k, s, i] += before + after
                self.f[k, s, i + 1] -= after
            if i < n:
                self.f[k, s, i] += self.mass[s, i] * self.gravity[None] \
                    - self.drag[None] * self.voronoi[s, i] * self.v[k, s, i]

    @ti.kernel
    def integrate(self, k: ti.i32, h: float):
        """Symplectic Euler into xp[k, 0]; the root node at the next slot's head pose."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            if i == 0:
                self.xp[k, 0, s, i] = self.placed(k + 1, self.rest_x[s, 0])
            elif i < self.node_count[s]:
                self.xp[k, 0, s, i] = self.x[k, s, i] + h * (self.v[k, s, i] + h * self.f[k, s, i] / self.mass[s, i])

    # ---------------------------------------------------------------- projection
    @ti.func
    def inv_mass(self, s, i):
        w = 0.0
        if i > 0:
            w = 1.0 / self.mass[s, i]
        return w

    @ti.kernel
    def push(self, k: ti.i32, p: ti.i32):
        """xc[k, p]: the iterate with its free nodes pushed out of the head's sphere."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            if i < self.node_count[s]:
                y = self.xp[k, p, s, i]
                if ti.static(self.collide):
                    if i > 0:
                        centre = self.placed(k + 1, self.sphere_centre[None])
                        d = y - centre
                        r = d.norm()
                        if r < self.sphere_radius[None]:
                            y = centre + self.sphere_radius[None] * d / r
                self.xc[k, p, s, i] = y

    @ti.kernel
    def length_system(self, k: ti.i32, p: ti.i32):
        """The Gauss-Newton system (G M^-1 G^T) lam = C of C_j = |e^j|^2 - |ebar^j|^2: diagonal,
        upper diagonal and residual of each edge."""
        for s, j in ti.ndrange(self.n_strands, self.n_nodes - 1):
            n = self.node_count[s]
            if j < n - 1:
                e = self.xc[k, p, s, j + 1] - self.xc[k, p, s, j]
                wb = self.inv_mass(s, j + 1)
                self.pdiag[k, p, s, j] = 4.0 * e.dot(e) * (self.inv_mass(s, j) + wb)
                self.pres[k, p, s, j] = e.dot(e) - self.rest_length[s, j] * self.rest_length[s, j]
                if j + 1 < n - 1:
                    self.pup[k, p, s, j] = -4.0 * e.dot(self.xc[k, p, s, j + 2] - self.xc[k, p, s, j + 1]) * wb

    @ti.kernel
    def length_move(self, k: ti.i32, p: ti.i32):
        """xp[k, p + 1] = xc - M^-1 G^T lam."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            n = self.node_count[s]
            if i < n:
                move = vec3(0.0)
                if i > 0:
                    move -= 2.0 * (self.xc[k, p, s, i] - self.xc[k, p, s, i - 1]) * self.lam[k, p, s, i - 1]
                if i < n - 1:
                    move += 2.0 * (self.xc[k, p, s, i + 1] - self.xc[k, p, s, i]) * self.lam[k, p, s, i]
                self.xp[k, p + 1, s, i] = self.xc[k, p, s, i] + self.inv_mass(s, i) * move

    @ti.kernel
    def finish(self, k: ti.i32, h: float):
        """Slot k + 1's positions (the last projection iterate) and velocities (x - x_prev) / h."""
        for s, i in ti.ndrange(self.n_strands, self.n_nodes):
            if i < self.node_count[s]:
                self.x[k + 1, s, i] = self.xp[k, ti.static(self.projection_iterations), s, i]
                self.v[k + 1, s, i] = (self.xp[k, ti.static(self.projection_iterations), s, i] - self.x[k, s, i]) / h

    # ---------------------------------------------------------------- twist
    @ti.kernel
    def twist_system(self, k: ti.i32, w: ti.i32, src_k: ti.i32, src_w: ti.i32):
        """The Newton system of the quasistatic twist at slot k from angles ang[src_k, src_w]:
        dE/dtheta (tres), its tridiagonal Hessian (tdiag, tup; docs/model.md, "Twist"), into
        column k - 1 of the twist arrays; the step tstep = Hessian^-1 dE/dtheta is a
        tridiagonal solve (tridiagonal.py)."""
        for s, j in ti.ndrange(self.n_strands, self.n_nodes - 1):
            n = self.node_count[s]
            if j < n - 1:
                gj = self.stiffness[s][2]
                angle = self.ang[src_k, src_w, s, j]
                _, g, hess = self.edge_bend_terms(k, s, j, n, angle)
                before = 0.0
                if j > 0:
                    before = self.ang[src_k, src_w, s, j - 1]
                g += gj * (angle - before - self.rest_twist[s, j]) / self.voronoi[s, j]
                hess += gj / self.voronoi[s, j]
                if j + 1 <= n - 2:
                    after = self.ang[src_k, src_w, s, j + 1]
                    g -= gj * (after - angle - self.rest_twist[s, j + 1]) / self.voronoi[s, j + 1]
                    hess += gj / self.voronoi[s, j + 1]
                    self.tup[k - 1, w, s, j] = -gj / self.voronoi[s, j + 1]
                self.tres[k - 1, w, s, j] = g
                self.tdiag[k - 1, w, s, j] = hess

    @ti.kernel
    def twist_update(self, k: ti.i32, w: ti.i32, src_k: ti.i32, src_w: ti.i32):
        """The Newton step: ang[k, w + 1] = ang[src_k, src_w] - tstep[k - 1, w]."""
        for s, j in ti.ndrange(self.n_strands, self.n_nodes - 1):
            if j < self.node_count[s] - 1:
                self.ang[k, w + 1, s, j] = self.ang[src_k, src_w, s, j] - self.tstep[k - 1, w, s, j]

    @ti.kernel
    def energy(self, k: ti.i32) -> float:
        """Slot k's elastic energy [J] (bending and twist; for checks against the forces)."""
        total = ti.cast(0.0, float)
        for s, j in ti.ndrange(self.n_strands, self.n_nodes - 1):
            n = self.node_count[s]
            if j < n - 1:
                w_col = ti.static(self.twist_iterations)
                gj = self.stiffness[s][2]
                if j == 0:
                    ei = self.stiffness[s]
                    rt, d1, d2 = self.root_frame(k, s)
                    kb0 = self.kb[k, s, 0]
                    rk = self.rest_kappa[s, 0]
                    d = clamp_view(kb0, d1, d2) - ti.Vector([rk[0], rk[1]])
                    total += 0.25 / self.voronoi[s, 0] * (ei[0] * d[0] * d[0] + ei[1] * d[1] * d[1])
                e, _, _ = self.edge_bend_terms(k, s, j, n, self.ang[k, w_col, s, j])
                before = 0.0
                if j > 0:
                    before = self.ang[k, w_col, s, j - 1]
                m = self.ang[k, w_col, s, j] - before - self.rest_twist[s, j]
                total += e + 0.5 * gj * m * m / self.voronoi[s, j]
        return total
