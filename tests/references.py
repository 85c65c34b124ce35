"""Independent reference solutions (numpy only) for the validation tests and reports."""

import numpy as np


def _rk4_elastica(kappa0, load, length, n=2000):
    """Integrate theta'' = -load (L - s) cos(theta), theta(0) = 0, theta'(0) = kappa0.
    Returns s, theta, theta' arrays (theta measured downward from the horizontal)."""
    s = np.linspace(0.0, length, n + 1)
    h = s[1] - s[0]
    y = np.array([0.0, kappa0])
    out = [y]

    def f(si, yi):
        return np.array([yi[1], -load * (length - si) * np.cos(yi[0])])
    for si in s[:-1]:
        k1 = f(si, y)
        k2 = f(si + h / 2, y + h / 2 * k1)
        k3 = f(si + h / 2, y + h / 2 * k2)
        k4 = f(si + h, y + h * k3)
        y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(y)
    out = np.array(out)
    return s, out[:, 0], out[:, 1]


def cantilever_elastica_tip(length, weight_per_length, ei, n=4000):
    """Tip (x, z) [m] of an inextensible cantilever clamped horizontally at the origin along +x,
    sagging under its own weight w [N/m] (z up): EI theta'' = -w (L - s) cos theta, theta(0) = 0,
    theta'(L) = 0, solved by shooting on theta'(0) with bisection."""
    load = weight_per_length / ei
    lo, hi = 0.0, load * length * 2.0  # theta'(L) > 0 at hi? bracket by expanding
    def end_slope(k):
        return _rk4_elastica(k, load, length, n)[2][-1]
    while end_slope(hi) < 0:
        hi *= 2.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if end_slope(mid) < 0:
            lo = mid
        else:
            hi = mid
    s, theta, _ = _rk4_elastica(0.5 * (lo + hi), load, length, n)
    ds = s[1] - s[0]
    # trapezoid rule on the tangent
    x = np.sum(0.5 * (np.cos(theta[1:]) + np.cos(theta[:-1]))) * ds
    z = -np.sum(0.5 * (np.sin(theta[1:]) + np.sin(theta[:-1]))) * ds
    return np.array([x, z])


def cantilever_first_frequency(length, ei, linear_density):
    """First natural frequency [Hz] of a clamped-free Euler-Bernoulli beam."""
    return 1.8751040687**2 / (2 * np.pi * length**2) * np.sqrt(ei / linear_density)


def first_mode_slope(s, length):
    """d/ds of the clamped-free beam's first mode shape, normalised to unit tip deflection."""
    b = 1.8751040687 / length
    sigma = (np.cosh(b * length) + np.cos(b * length)) / (np.sinh(b * length) + np.sin(b * length))

    def shape(t):
        return np.cosh(b * t) - np.cos(b * t) - sigma * (np.sinh(b * t) - np.sin(b * t))
    slope = b * (np.sinh(b * s) + np.sin(b * s) - sigma * (np.cosh(b * s) - np.cos(b * s)))
    return slope / shape(length)


# ---------------------------------------------------------------- strand contact's curves


def node_curvatures(x, counts, s, i):
    """Curvature vectors [k, 3] at nodes (s, i) [k]: the circle through nodes i - 1, i, i + 1,
    (t_i - t_{i-1}) / mean edge length, zero at a strand's end nodes."""
    interior = (i > 0) & (i + 1 < counts[s])
    lo, mid, hi = np.maximum(i - 1, 0), i, np.minimum(i + 1, x.shape[1] - 1)
    e0, e1 = x[s, mid] - x[s, lo], x[s, hi] - x[s, mid]
    l0 = np.linalg.norm(e0, axis=1, keepdims=True)
    l1 = np.linalg.norm(e1, axis=1, keepdims=True)
    ok = interior[:, None] & (l0 > 0) & (l1 > 0)
    k = (e1 / np.where(ok, l1, 1) - e0 / np.where(ok, l0, 1)) / np.where(ok, 0.5 * (l0 + l1), 1)
    return np.where(ok, k, 0.0)


def curve_points(x, counts, s, j, u, radius):
    """Points [k, 3] at parameter u [k] of segment (s, j) [k] on the curve through the nodes the
    contact uses: the chord point moved by -(l^2 / 2) u (1 - u) kappa(u), kappa interpolated
    between the two nodes' curvatures (the parabola through both nodes with that curvature),
    the move shortened to at most the strand's radius [S]."""
    a0, a1 = x[s, j], x[s, j + 1]
    u = u[:, None]
    kappa = (1 - u) * node_curvatures(x, counts, s, j) + u * node_curvatures(x, counts, s, j + 1)
    l2 = ((a1 - a0) ** 2).sum(1, keepdims=True)
    offset = -0.5 * l2 * u * (1 - u) * kappa
    size = np.linalg.norm(offset, axis=1, keepdims=True)
    cap = radius[s][:, None]
    return a0 + u * (a1 - a0) + np.where(size > cap, offset * cap / np.where(size > 0, size, 1), offset)


def greenhill_critical_moment(tension, span=40.0):
    """Smallest twisting moment m = M L / B at which a straight rod, clamped (position and
    direction) at both ends and pulled by the dimensionless tension tau = T L^2 / B > 0, can
    buckle: Greenhill's problem. The linearised Kirchhoff rod's sideways displacement
    w = x + i y obeys w'''' - i m w''' - tau w'' = 0 on z in [0, 1], so
    w = a + b z + c exp(p z) + d exp(q z), p and q the roots of p^2 - i m p - tau = 0. The clamps
    w = w' = 0 at both ends allow w != 0 where the 4 x 4 determinant vanishes; divided by
    (p - q) exp((p + q) / 2) it is real, and its first sign change above m = 2 sqrt(tau) (below
    which no rod buckles, however long) is bisected. As tau -> 0 it tends to Greenhill's 2.861 pi
    (at tau = 0 itself q = 0 repeats the constant solution, so tau must be positive)."""
    def clamped(m):
        root = np.sqrt(complex(4.0 * tension - m * m))
        p, q = (1j * m + root) / 2.0, (1j * m - root) / 2.0
        rows = np.array([[1, 0, 1, 1], [0, 1, p, q],
                         [1, 1, np.exp(p), np.exp(q)], [0, 1, p * np.exp(p), q * np.exp(q)]])
        value = np.linalg.det(rows) / ((p - q) * np.exp((p + q) / 2.0))
        return value.real

    low = 2.0 * np.sqrt(tension)
    grid = np.linspace(low + 1e-6 * (1.0 + low), low + span, 4000)
    signs = np.sign([clamped(m) for m in grid])
    first = int(np.flatnonzero(signs[:-1] != signs[1:])[0])
    low, high = grid[first], grid[first + 1]
    for _ in range(60):
        middle = 0.5 * (low + high)
        if np.sign(clamped(middle)) == signs[first]:
            low = middle
        else:
            high = middle
    return 0.5 * (low + high)
