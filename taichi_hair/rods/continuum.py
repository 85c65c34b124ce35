"""Independent continuum reference: the static Kirchhoff rod with intrinsic curvature and twist.

numpy and the standard library only (no taichi, no other taichi_hair module), so it can check the
discrete simulator without sharing any of its code. SI units: metres, newtons, radians.

The rod is inextensible and unshearable, clamped at s = 0 (position and material frame fixed),
free at s = L, under a uniform distributed load f [N/m] (a world vector; gravity: rho A g):

    x' = d3,   d_i' = omega x d_i,   omega = k1 d1 + k2 d2 + k3 d3            (kinematics)
    m = B1 (k1 - k1bar) d1 + B2 (k2 - k2bar) d2 + C (k3 - k3bar) d3            (constitutive)
    n(s) = f (L - s),   m' + d3 x n = 0,   m(L) = 0                             (balance, free tip)

n and m are the force and moment that the piece (s, L] exerts on [0, s]. The boundary value
problem is solved by shooting on the root moment m(0) (world frame): classical RK4 from the root
on a uniform grid, Newton on m(L) = 0 with a forward-difference Jacobian (the three perturbed
trajectories are integrated together with the base one, as one batch), and load continuation
(f ramped from 0, each Newton solve warm-started by extrapolating the previous two) on a coarse
grid, then a last Newton polish on the full grid.
"""

import math

import numpy as np

from ..validation import integer, real, vector3

RESIDUAL_RTOL = 1e-10  # converged when |m(L)| <= this * |f| L^2 (the root moment's scale)
CONTINUATION_RTOL = 1e-6  # intermediate load steps only need to land in Newton's basin
FD_RELATIVE_STEP = 1e-7  # forward-difference step on m(0), relative to |f| L^2
COARSE_STEPS = 400  # grid for the continuation; RK4 there is accurate to ~1e-8 of the shape
MIN_LOAD_STEP = 1.0 / 4096  # give up when the continuation has to crawl finer than this
NEWTON_ITERATIONS = 12  # per load step; quadratic convergence needs far fewer when it works


def kirchhoff_static(length, intrinsic, stiffness, load, root_position, root_frame, n_steps=4000):
    """Static equilibrium of a clamped-free Kirchhoff rod under a uniform load.

    length: L [m] > 0.
    intrinsic: (k1bar, k2bar, k3bar) [1/m], the unloaded material curvatures (about d1, about d2)
        and twist, constants, or a callable s [m] -> array (3,).
    stiffness: (B1, B2, C) [N m^2] > 0: bending stiffness about d1 (E I1), about d2 (E I2), and
        torsional stiffness G J.
    load: f [N/m], world vector (3,), the distributed load per unit arc length.
    root_position: x(0) [m], (3,).
    root_frame: 3x3 rotation whose COLUMNS are d1, d2, d3 at s = 0 (d3 = the tangent).
    n_steps: RK4 steps on the uniform grid over [0, L].

    Returns a dict: s [n+1] m; x [n+1, 3] m; d1, d2, d3 [n+1, 3]; moment [n+1, 3] N m (world, the
    internal moment m(s)); root_moment [3] N m (world, m(0)); tip [3] m (x(L)); residual (|m(L)|
    N m); load_steps (continuation steps taken). Raises ValueError on bad input and RuntimeError
    when Newton does not converge.
    """
    rod = _Rod(length, intrinsic, stiffness, load, root_position, root_frame)
    n = integer("n_steps", n_steps, low=2)
    scale = np.linalg.norm(rod.load) * rod.length ** 2
    if scale == 0.0:  # no load: m' = 0 and m(L) = 0 force m = 0, the unloaded shape
        return _result(rod, n, np.zeros(3), 0)
    coarse = min(n, COARSE_STEPS)
    m0, load_steps = _continuation(rod, coarse, scale)
    m0 = _newton(rod, n, m0, 1.0, RESIDUAL_RTOL * scale, scale)
    if m0 is None:
        raise RuntimeError(f"Kirchhoff shooting: Newton did not reach |m(L)| <= "
                           f"{RESIDUAL_RTOL:g} |f| L^2 on the {n}-step grid (the {coarse}-step "
                           f"continuation had converged); try another n_steps")
    return _result(rod, n, m0, load_steps)


def helix_strains(curl_radius, curl_pitch):
    """(kappa, tau) [1/m]: curvature and torsion of a helix of radius R = curl_radius [m] and
    pitch p = curl_pitch [m per turn]: c = p / (2 pi), kappa = R / (R^2 + c^2),
    tau = c / (R^2 + c^2). tau > 0 is a right-handed helix (as Groom.curly draws it)."""
    radius = real("curl_radius", curl_radius, "m", low=0.0, low_open=True)
    pitch = real("curl_pitch", curl_pitch, "m", low=0.0)
    rise = pitch / (2.0 * math.pi)
    denominator = radius ** 2 + rise ** 2
    return radius / denominator, rise / denominator


def curly_root_frame(direction, curl_radius, curl_pitch, phase=0.0):
    """Root material frame [3, 3] (columns d1 = binormal, d2 = -normal, d3 = tangent) of the helix
    that `taichi_hair.Groom.curly(directions=[direction], curl_radius=R, curl_pitch=p,
    phase=phase)` draws, so that intrinsic strains (kappa, 0, tau) from `helix_strains` reproduce
    it from the root: axis along `direction`, curl_radius beside the root, turning from the
    angle `phase` [rad] in the plane of the two side axes Groom's `_frames` picks."""
    side, side2, up = _groom_axes(direction)
    radius = real("curl_radius", curl_radius, "m", low=0.0, low_open=True)
    rise = real("curl_pitch", curl_pitch, "m", low=0.0) / (2.0 * math.pi)
    turn = 1.0 / math.hypot(radius, rise)  # helix angle per unit arc length [rad/m]
    c, s = math.cos(phase), math.sin(phase)
    # Groom.curly's local curve is R (cos a, sin a) + rise a, a = turn s + phase; at s = 0:
    tangent = turn * np.array([-radius * s, radius * c, rise])
    normal = -np.array([c, s, 0.0])  # towards the helix axis
    binormal = np.cross(tangent, normal)
    to_world = np.column_stack([side, side2, up])  # right-handed: side x side2 = up
    return to_world @ np.column_stack([binormal, -normal, tangent])


def hanging_helix(length, curl_radius, curl_pitch, direction, stiffness, linear_density,
                  gravity=(0.0, 0.0, -9.81), root=(0.0, 0.0, 0.0), phase=0.0, n_steps=4000):
    """`kirchhoff_static` for a Groom.curly helix (see `curly_root_frame`) of `length` [m] loaded
    by its weight: f = linear_density [kg/m] * gravity [m/s^2]. stiffness = (B1, B2, C) [N m^2]
    with B1 about the binormal and B2 about the normal of the unloaded helix."""
    density = real("linear_density", linear_density, "kg/m", low=0.0)
    kappa, tau = helix_strains(curl_radius, curl_pitch)
    frame = curly_root_frame(direction, curl_radius, curl_pitch, phase)
    load = density * vector3("gravity", gravity)
    return kirchhoff_static(length, (kappa, 0.0, tau), stiffness, load, root, frame, n_steps)


class _Rod:
    """Validated problem data: length, 1 / stiffness (3,), load (3,), root, frame rows d_i."""

    def __init__(self, length, intrinsic, stiffness, load, root_position, root_frame):
        self.length = real("length", length, "m", low=0.0, low_open=True)
        stiffness = vector3("stiffness", stiffness)
        if not np.all(stiffness > 0):
            raise ValueError(f"stiffness (B1, B2, C) must all be > 0 N m^2, got {stiffness.tolist()}")
        self.compliance = 1.0 / stiffness
        self.load = vector3("load", load)
        self.root = vector3("root_position", root_position)
        self.frame_rows = _rotation(root_frame).T  # row i is d_i
        self.intrinsic = intrinsic if callable(intrinsic) else vector3("intrinsic", intrinsic)
        self._tables = {}  # grid size -> intrinsic_table, evaluated once per grid
        # n x d3 = (L - s) skew(f) d3; for a batch of row vectors d3 that is d3 @ skew(f).T
        fx, fy, fz = self.load
        self.cross_load = np.array([[0.0, -fz, fy], [fz, 0.0, -fx], [-fy, fx, 0.0]])

    def intrinsic_table(self, n):
        """k-bar [2n+1, 3] at the RK4 stage points s = j h / 2, j = 0 .. 2n."""
        if n in self._tables:
            return self._tables[n]
        if callable(self.intrinsic):
            s = np.linspace(0.0, self.length, 2 * n + 1)
            table = np.array([np.asarray(self.intrinsic(si), dtype=np.float64) for si in s])
            if table.shape != (2 * n + 1, 3) or not np.all(np.isfinite(table)):
                raise ValueError("intrinsic(s) must return 3 finite curvatures [1/m] for every s "
                                 "in [0, L]")
        else:
            table = np.broadcast_to(self.intrinsic, (2 * n + 1, 3))
        self._tables[n] = table
        return table


def _rates(state, kbar, remaining, rod, load_factor):
    """d/ds of a batch of states [K, 5, 3] (rows x, d1, d2, d3, m); `remaining` = L - s."""
    directors, moment = state[:, 1:4], state[:, 4]
    material_moment = np.einsum("kij,kj->ki", directors, moment)
    k = kbar + material_moment * rod.compliance  # constitutive law inverted
    k1, k2, k3 = k[:, 0:1], k[:, 1:2], k[:, 2:3]
    d1, d2, d3 = directors[:, 0], directors[:, 1], directors[:, 2]
    out = np.empty_like(state)
    out[:, 0] = d3
    out[:, 1] = k3 * d2 - k2 * d3  # omega x d1 with omega in the frame's own components
    out[:, 2] = k1 * d3 - k3 * d1
    out[:, 3] = k2 * d1 - k1 * d2
    out[:, 4] = (load_factor * remaining) * (d3 @ rod.cross_load.T)  # m' = n x d3
    return out


def _integrate(rod, n, root_moments, load_factor, keep_path=False):
    """RK4 from the root for a batch of root moments [K, 3]; returns the tip states [K, 5, 3], or
    with keep_path the whole path of trajectory 0 [n+1, 5, 3]."""
    h = rod.length / n
    kbar = rod.intrinsic_table(n)
    state = np.empty((len(root_moments), 5, 3))
    state[:, 0] = rod.root
    state[:, 1:4] = rod.frame_rows
    state[:, 4] = root_moments
    path = np.empty((n + 1, 5, 3)) if keep_path else None
    if keep_path:
        path[0] = state[0]
    for j in range(n):
        rest = rod.length - j * h
        a = _rates(state, kbar[2 * j], rest, rod, load_factor)
        b = _rates(state + 0.5 * h * a, kbar[2 * j + 1], rest - 0.5 * h, rod, load_factor)
        c = _rates(state + 0.5 * h * b, kbar[2 * j + 1], rest - 0.5 * h, rod, load_factor)
        d = _rates(state + h * c, kbar[2 * j + 2], rest - h, rod, load_factor)
        state = state + (h / 6.0) * (a + 2.0 * (b + c) + d)
        # RK4 leaves the frame orthonormal only to O(h^5) a step; one Newton step of the polar
        # decomposition, Q <- (3 Q - Q Q^T Q) / 2, pulls it back to a rotation (symmetrically)
        q = state[:, 1:4]
        state[:, 1:4] = 1.5 * q - 0.5 * (q @ np.swapaxes(q, 1, 2) @ q)
        if keep_path:
            path[j + 1] = state[0]
    return path if keep_path else state


def _residual_and_jacobian(rod, n, m0, load_factor, scale):
    """m(L) [3] and its forward-difference Jacobian d m(L) / d m(0) [3, 3], one batched RK4."""
    step = FD_RELATIVE_STEP * max(scale, np.linalg.norm(m0))
    batch = np.vstack([m0, m0 + step * np.eye(3)])
    tips = _integrate(rod, n, batch, load_factor)[:, 4]
    return tips[0], (tips[1:] - tips[0]).T / step


def _newton(rod, n, m0, load_factor, tolerance, scale):
    """Damped Newton on m(L) = 0 from m0; the root moment [3], or None when it fails."""
    residual, jacobian = _residual_and_jacobian(rod, n, m0, load_factor, scale)
    for _ in range(NEWTON_ITERATIONS):
        size = np.linalg.norm(residual)
        if not np.isfinite(size):
            return None
        if size <= tolerance:
            return m0
        try:
            step = -np.linalg.solve(jacobian, residual)
        except np.linalg.LinAlgError:
            return None
        fraction = 1.0
        while True:  # backtrack until |m(L)| decreases (large steps can overshoot a fold)
            trial = m0 + fraction * step
            trial_residual, trial_jacobian = _residual_and_jacobian(rod, n, trial, load_factor, scale)
            if np.linalg.norm(trial_residual) < (1.0 - 1e-4 * fraction) * size:
                break
            fraction *= 0.5
            if fraction < 1.0 / 64:
                return None
        m0, residual, jacobian = trial, trial_residual, trial_jacobian
    return m0 if np.linalg.norm(residual) <= tolerance else None


def _continuation(rod, n, scale):
    """Ramp the load factor from 0 to 1 on an n-step grid; returns (m(0) at full load, steps).
    Each solve starts from the straight-line extrapolation of the last two solutions (m(0) is
    0 at no load); a failed solve halves the load step, a success lets it grow again."""
    done, m_done = 0.0, np.zeros(3)
    before, m_before = 0.0, np.zeros(3)
    increment, steps = 0.25, 0
    while done < 1.0:
        target = min(1.0, done + increment)
        slope = (m_done - m_before) / (done - before) if done > before else np.zeros(3)
        guess = m_done + (target - done) * slope
        tolerance = CONTINUATION_RTOL * scale * target  # the full-grid polish tightens it
        solution = _newton(rod, n, guess, target, tolerance, scale)
        if solution is None:
            increment *= 0.5
            if increment < MIN_LOAD_STEP:
                raise RuntimeError(f"Kirchhoff shooting: Newton failed at load factor {target:.6g} "
                                   f"even with load steps of {increment * 2:.3g}; the root moment "
                                   f"reached {m_done.tolist()} N m at load factor {done:.6g}")
            continue
        before, m_before, done, m_done = done, m_done, target, solution
        increment, steps = min(2.0 * increment, 1.0), steps + 1
    return m_done, steps


def _result(rod, n, m0, load_steps):
    """Integrate the converged root moment once more, keeping the path, and unpack it."""
    path = _integrate(rod, n, m0[None], 1.0, keep_path=True)
    return {"s": np.linspace(0.0, rod.length, n + 1), "x": path[:, 0].copy(),
            "d1": path[:, 1].copy(), "d2": path[:, 2].copy(), "d3": path[:, 3].copy(),
            "moment": path[:, 4].copy(), "root_moment": m0.copy(), "tip": path[-1, 0].copy(),
            "residual": float(np.linalg.norm(path[-1, 4])), "load_steps": load_steps}


def _groom_axes(direction):
    """Groom._frames for one strand: side, side2, up (unit, right-handed: side x side2 = up)."""
    up = vector3("direction", direction)
    norm = np.linalg.norm(up)
    if norm < 1e-12:
        raise ValueError(f"direction must be a non-zero vector, got {up.tolist()}")
    up = up / norm
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    side = np.cross(up, helper)
    side /= np.linalg.norm(side)
    return side, np.cross(up, side), up


def _rotation(frame):
    array = np.asarray(frame, dtype=np.float64)
    if array.shape != (3, 3) or not np.all(np.isfinite(array)):
        raise ValueError(f"root_frame must be a finite 3x3 matrix (columns d1, d2, d3), got shape "
                         f"{array.shape}")
    if not np.allclose(array.T @ array, np.eye(3), atol=1e-9) or np.linalg.det(array) < 0:
        raise ValueError("root_frame must be a rotation: orthonormal columns d1, d2, d3 with "
                         "d1 x d2 = d3 (det = +1)")
    return array
