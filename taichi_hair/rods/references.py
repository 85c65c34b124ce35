"""Reference solutions independent of the simulator (numpy only, besides the continuum rod of
rods/continuum.py): the reports' accuracy rows and the test suite measure against these.

  cantilever_elastica_tip     a heavy cantilever's static tip (the elastica, by shooting)
  cantilever_first_frequency  a clamped-free Euler-Bernoulli beam's first frequency
  first_mode_slope            the slope of that beam's first mode shape
  hanging_curl                a curled rod hanging under gravity (the continuum Kirchhoff rod)
  curve_points                points on the curve the strand contact uses between nodes
  greenhill_critical_moment   the twist at which a clamped, pulled rod buckles (Greenhill)
"""

import functools
import math

import numpy as np

from .continuum import hanging_helix


# ---- beams ------------------------------------------------------------------------------------------
def elastica_end_slope(kappa0: float, load: float, length: float, n: int):
    """theta'(L) of theta'' = -load (L - s) cos(theta), theta(0) = 0, theta'(0) = kappa0 [1/m]
    (RK4 on n steps; load = w / EI [1/m^3]); also the tip (x, z) [m] by the trapezoid rule on
    the tangent (theta measured downward from +x)."""
    h = length / n
    th, dth, x, z = 0.0, kappa0, 0.0, 0.0

    def f(s, t):
        return -load * (length - s) * math.cos(t)
    for k in range(n):
        s = k * h
        k1t, k1d = dth, f(s, th)
        k2t, k2d = dth + h / 2 * k1d, f(s + h / 2, th + h / 2 * k1t)
        k3t, k3d = dth + h / 2 * k2d, f(s + h / 2, th + h / 2 * k2t)
        k4t, k4d = dth + h * k3d, f(s + h, th + h * k3t)
        new = th + h / 6 * (k1t + 2 * k2t + 2 * k3t + k4t)
        dth += h / 6 * (k1d + 2 * k2d + 2 * k3d + k4d)
        x += 0.5 * h * (math.cos(th) + math.cos(new))
        z -= 0.5 * h * (math.sin(th) + math.sin(new))
        th = new
    return dth, np.array([x, z])


@functools.lru_cache(maxsize=8)
def _cached_elastica_tip(length: float, weight: float, ei: float, n: int) -> tuple:
    load = weight / ei
    lo, hi = 0.0, load * length**2
    while elastica_end_slope(hi, load, length, n)[0] < 0:
        hi *= 2.0
    while hi - lo > 1e-13 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if elastica_end_slope(mid, load, length, n)[0] < 0 else (lo, mid)
    return tuple(elastica_end_slope(0.5 * (lo + hi), load, length, n)[1])


def cantilever_elastica_tip(length: float, weight_per_length: float, ei: float, n: int = 4000) -> np.ndarray:
    """Tip (x, z) [m] of an inextensible cantilever of `length` [m] clamped horizontally at the
    origin along +x, sagging under its weight w [N/m] (z up): EI theta'' = -w (L - s) cos theta,
    theta(0) = 0, theta'(L) = 0, by shooting on theta'(0) with bisection (RK4 on n steps, the
    trapezoid rule for the tip). ei: bending stiffness [N m^2]."""
    return np.array(_cached_elastica_tip(float(length), float(weight_per_length), float(ei), int(n)))


def cantilever_first_frequency(length: float, ei: float, linear_density: float) -> float:
    """First natural frequency [Hz] of a clamped-free Euler-Bernoulli beam of `length` [m],
    bending stiffness ei [N m^2] and linear_density [kg/m]."""
    return 1.8751040687**2 / (2 * math.pi * length**2) * math.sqrt(ei / linear_density)


def first_mode_slope(s, length: float):
    """d/ds of the clamped-free beam's first mode shape at arc lengths s [m] (array), normalised
    to a unit tip deflection [1/m]."""
    b = 1.8751040687 / length
    sigma = (np.cosh(b * length) + np.cos(b * length)) / (np.sinh(b * length) + np.sin(b * length))
    tip = np.cosh(b * length) - np.cos(b * length) - sigma * (np.sinh(b * length) - np.sin(b * length))
    s = np.asarray(s, dtype=np.float64)
    return b * (np.sinh(b * s) + np.sin(b * s) - sigma * (np.cosh(b * s) - np.cos(b * s))) / tip


# ---- curls ------------------------------------------------------------------------------------------
def hanging_curl(length: float, curl_radius: float, curl_pitch: float, direction, stiffness,
                 linear_density: float) -> dict:
    """A curled rod (a Groom.curly helix of `length` [m], curl_radius [m], curl_pitch [m per
    turn], its axis along `direction`, root clamped at the origin) hanging under gravity, by the
    continuum Kirchhoff rod with intrinsic curvature and twist (rods/continuum.py): {"tip": its
    tip [m] (list of 3), "drop": the tip's displacement from the unloaded tip [m]}.
    stiffness = (B1, B2, C) [N m^2]; linear_density [kg/m]."""
    loaded = hanging_helix(length, curl_radius, curl_pitch, direction, stiffness, linear_density)
    unloaded = hanging_helix(length, curl_radius, curl_pitch, direction, stiffness, 0.0)
    return {"tip": loaded["tip"].tolist(), "drop": float(np.linalg.norm(loaded["tip"] - unloaded["tip"]))}


# ---- strand contact's curves and Greenhill's buckling -------------------------------------------
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
