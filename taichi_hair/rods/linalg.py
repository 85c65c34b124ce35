"""Small linear-algebra helpers used inside kernels."""

import taichi as ti


@ti.func
def thomas_solve(s, first, last, diag: ti.template(), upper: ti.template(), rhs: ti.template()):
    """Solve strand s's symmetric tridiagonal system on rows first..last in place: diag[s, j]
    the diagonal, upper[s, j] the entry coupling rows j and j+1, rhs[s, j] the right-hand side,
    overwritten by the solution (diag is overwritten too). O(rows), no pivoting: the callers'
    matrices are symmetric positive definite."""
    for j in range(first + 1, last + 1):
        w = upper[s, j - 1] / diag[s, j - 1]
        diag[s, j] -= w * upper[s, j - 1]
        rhs[s, j] -= w * rhs[s, j - 1]
    back_substitute(s, first, last, diag, upper, rhs)


@ti.func
def back_substitute(s, first, last, diag: ti.template(), upper: ti.template(), rhs: ti.template()):
    """The backward sweep of a tridiagonal solve whose forward elimination left the pivots in
    diag and the eliminated right-hand side in rhs (overwritten by the solution)."""
    for r in range(last - first + 1):
        j = last - r
        nxt = 0.0
        if j < last:
            nxt = upper[s, j] * rhs[s, j + 1]
        rhs[s, j] = (rhs[s, j] - nxt) / diag[s, j]


@ti.func
def rotate_rows(r0, r1, r2, p):
    """R p for the rotation R given by its rows r0, r1, r2 (how head poses are stored)."""
    return ti.Vector([r0.dot(p), r1.dot(p), r2.dot(p)])


@ti.func
def unrotate_rows(r0, r1, r2, p):
    """R^T p for the rotation R given by its rows."""
    return p[0] * r0 + p[1] * r1 + p[2] * r2


@ti.func
def grid_cell(g):
    """(lower corner index, fraction within the cell) of grid coordinates g [3]: the cell of a
    trilinear interpolation."""
    base = ti.floor(g, ti.i32)
    return base, g - base


@ti.func
def corner_factors(c, f):
    """The per-axis trilinear factors [3] of cell corner c (0 or 1 per axis) at fraction f: the
    corner's weight is their product."""
    return ti.Vector([ti.select(c[0] == 1, f[0], 1.0 - f[0]), ti.select(c[1] == 1, f[1], 1.0 - f[1]),
                      ti.select(c[2] == 1, f[2], 1.0 - f[2])])


@ti.func
def corner_signs(c):
    """d(factor)/d(fraction) per axis for corner c: +1 where c is 1, -1 where it is 0."""
    return ti.Vector([ti.select(c[0] == 1, 1.0, -1.0), ti.select(c[1] == 1, 1.0, -1.0),
                      ti.select(c[2] == 1, 1.0, -1.0)])


@ti.func
def block_inverse(d):
    """(d^-1, ok) for a 5x5 float64 block d, by partitioning off its last row and column:
    d = [[a, b], [b^T, c]], d^-1 from a^-1 and the Schur complement c - b^T a^-1 b (Taichi
    inverts matrices up to 4x4). ok is 0 when a or the complement is singular (or NaN)."""
    a = ti.types.matrix(4, 4, ti.f64)(0.0)
    b = ti.types.vector(4, ti.f64)(0.0)
    for r in ti.static(range(4)):
        b[r] = d[r, 4]
        for c in ti.static(range(4)):
            a[r, c] = d[r, c]
    ok = 1
    if not (ti.abs(a.determinant()) > 0.0):
        ok = 0
        a = ti.Matrix.identity(ti.f64, 4)
    a_inv = a.inverse()
    y = a_inv @ b
    complement = d[4, 4] - b.dot(y)
    if not (ti.abs(complement) > 0.0):
        ok = 0
        complement = 1.0
    inv = ti.types.matrix(5, 5, ti.f64)(0.0)
    for r in ti.static(range(4)):
        inv[r, 4] = -y[r] / complement
        inv[4, r] = -y[r] / complement
        for c in ti.static(range(4)):
            inv[r, c] = a_inv[r, c] + y[r] * y[c] / complement
    inv[4, 4] = 1.0 / complement
    return inv, ok


@ti.func
def block_pentadiagonal_solve(s, n, blocks: ti.template(), rhs: ti.template()):
    """Solve strand s's symmetric block-pentadiagonal system A y = b in place, O(n): for node
    rows i < n, blocks[s, i, 0] = A_ii, blocks[s, i, 1] = A_{i,i-1}, blocks[s, i, 2] =
    A_{i,i-2} (5x5 float64 each), rhs[s, i] = b_i (float64). A = L D L^T with unit block lower L and block
    diagonal D, no pivoting (A may be indefinite, as a saddle-point system is, if every pivot
    block is invertible): blocks become (D_i^-1, L_{i,i-1}, L_{i,i-2}) and rhs the solution y.
    Returns 1 if a pivot block was singular (or NaN), else 0."""
    failed = 0
    for i in range(n):
        a1 = blocks[s, i, 1]
        a2 = blocks[s, i, 2]
        d = blocks[s, i, 0]
        l1 = ti.types.matrix(5, 5, ti.f64)(0.0)
        l2 = ti.types.matrix(5, 5, ti.f64)(0.0)
        if i >= 2:
            l2 = product(a2, blocks[s, i - 2, 0], False, False)
            a1 -= product(a2, blocks[s, i - 1, 1], False, True)  # L_{i,i-2} D_{i-2} = A_{i,i-2}
            d -= product(l2, a2, False, True)
        if i >= 1:
            l1 = product(a1, blocks[s, i - 1, 0], False, False)
            d -= product(l1, a1, False, True)
        # symmetric by construction, but rounding leaves d and its inverse slightly
        # asymmetric, and that asymmetry grows along a long stiff chain in this one-sided
        # recurrence (L D L^T formed from the lower blocks only): 201 nodes at 1 mm, bent by
        # microns, went from |L| 1.7 to 6e9 by node 120. Symmetrising both keeps it at 1.7.
        d_inv, ok = block_inverse(0.5 * (d + d.transpose()))
        if not ok:
            failed = 1
        blocks[s, i, 0] = 0.5 * (d_inv + d_inv.transpose())
        blocks[s, i, 1] = l1
        blocks[s, i, 2] = l2
    for i in range(n):  # L z = b
        z = rhs[s, i]
        if i >= 1:
            z -= blocks[s, i, 1] @ rhs[s, i - 1]
        if i >= 2:
            z -= blocks[s, i, 2] @ rhs[s, i - 2]
        rhs[s, i] = z
    for q in range(n):  # D L^T y = z, from the last node up
        i = n - 1 - q
        y = blocks[s, i, 0] @ rhs[s, i]
        if i + 1 < n:
            y -= blocks[s, i + 1, 1].transpose() @ rhs[s, i + 1]
        if i + 2 < n:
            y -= blocks[s, i + 2, 2].transpose() @ rhs[s, i + 2]
        rhs[s, i] = y
    return failed


@ti.func
def product(a, b, ta: ti.template(), tb: ti.template()):
    """a @ b, with a (ta) or b (tb) transposed, float64, summed in run-time loops. Taichi's `@`
    unrolls a product into scalar statements, and its compiler's passes grow faster than the
    statements: the implicit step's 5x5 block products, unrolled, made its kernel compile for
    minutes. Loops of 5 cost no more to run (LLVM unrolls what pays)."""
    rows = ti.static(a.m if ta else a.n)
    inner = ti.static(a.n if ta else a.m)
    cols = ti.static(b.n if tb else b.m)
    out = ti.Matrix.zero(ti.f64, rows, cols)
    for r in range(rows):
        for c in range(cols):
            acc = ti.f64(0.0)
            for k in range(inner):
                x = a[k, r] if ti.static(ta) else a[r, k]
                y = b[c, k] if ti.static(tb) else b[k, c]
                acc += x * y
            out[r, c] = acc
    return out
