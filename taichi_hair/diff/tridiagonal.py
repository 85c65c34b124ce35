"""Symmetric tridiagonal solves per strand (the projection's and the twist's Newton systems)
with a hand-written adjoint.

A serial elimination whose pivots and right-hand sides both carry along the strand is beyond
what Taichi 1.7's reverse mode replays exactly (measured: the right-hand side's gradient off by
20 % to 4x against central differences, the matrix's right). The adjoint of A sol = rhs is
one more solve with the same (symmetric) matrix: A mu = sol_bar, then rhs_bar += mu,
diag_bar -= mu * sol, up_bar_j -= mu_j sol_{j+1} + mu_{j+1} sol_j.

Arrays are indexed [a, b, s, j] (slot, iteration, strand, edge): diag, up (A_{j,j+1}), rhs,
the elimination's c and d, and sol; strand s has node_count[s] - 1 unknowns."""

import taichi as ti


@ti.data_oriented
class TridiagonalKernels:
    """Mixin: the solve and its adjoint; scratch arrays mu_c, mu_d, mu [S, N-1] are the problem's."""

    @ti.kernel
    def tridiagonal_solve(self, diag: ti.template(), up: ti.template(), rhs: ti.template(), c: ti.template(),
                          d: ti.template(), sol: ti.template(), a: ti.i32, b: ti.i32):
        for s in range(self.n_strands):
            n = self.node_count[s] - 1
            c[a, b, s, 0] = up[a, b, s, 0] / diag[a, b, s, 0]
            d[a, b, s, 0] = rhs[a, b, s, 0] / diag[a, b, s, 0]
            for j in range(1, n):
                den = diag[a, b, s, j] - up[a, b, s, j - 1] * c[a, b, s, j - 1]
                c[a, b, s, j] = up[a, b, s, j] / den
                d[a, b, s, j] = (rhs[a, b, s, j] - up[a, b, s, j - 1] * d[a, b, s, j - 1]) / den
            sol[a, b, s, n - 1] = d[a, b, s, n - 1]
            for r in range(1, n):
                j = n - 1 - r
                sol[a, b, s, j] = d[a, b, s, j] - c[a, b, s, j] * sol[a, b, s, j + 1]

    @ti.kernel
    def tridiagonal_adjoint(self, diag: ti.template(), up: ti.template(), rhs: ti.template(),
                            sol: ti.template(), a: ti.i32, b: ti.i32):
        for s in range(self.n_strands):
            n = self.node_count[s] - 1
            self.mu_c[s, 0] = up[a, b, s, 0] / diag[a, b, s, 0]
            self.mu_d[s, 0] = sol.grad[a, b, s, 0] / diag[a, b, s, 0]
            for j in range(1, n):
                den = diag[a, b, s, j] - up[a, b, s, j - 1] * self.mu_c[s, j - 1]
                self.mu_c[s, j] = up[a, b, s, j] / den
                self.mu_d[s, j] = (sol.grad[a, b, s, j] - up[a, b, s, j - 1] * self.mu_d[s, j - 1]) / den
            self.mu[s, n - 1] = self.mu_d[s, n - 1]
            for r in range(1, n):
                j = n - 1 - r
                self.mu[s, j] = self.mu_d[s, j] - self.mu_c[s, j] * self.mu[s, j + 1]
            for j in range(n):
                rhs.grad[a, b, s, j] += self.mu[s, j]
                diag.grad[a, b, s, j] -= self.mu[s, j] * sol[a, b, s, j]
                if j + 1 < n:
                    up.grad[a, b, s, j] -= self.mu[s, j] * sol[a, b, s, j + 1] + self.mu[s, j + 1] * sol[a, b, s, j]


class SolveOp:
    """A tape entry for one tridiagonal solve: calling it solves, `.grad` runs the adjoint."""

    def __init__(self, kernels, diag, up, rhs, c, d, sol):
        self.kernels, self.arrays = kernels, (diag, up, rhs, c, d, sol)

    def __call__(self, a: int, b: int):
        self.kernels.tridiagonal_solve(*self.arrays, a, b)

    def grad(self, a: int, b: int):
        diag, up, rhs, _, _, sol = self.arrays
        self.kernels.tridiagonal_adjoint(diag, up, rhs, sol, a, b)
