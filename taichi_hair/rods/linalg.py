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
