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
