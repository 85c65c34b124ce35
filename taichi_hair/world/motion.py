"""Head motion: callables t [s] -> (R [3, 3] float64 proper rotation, translation [3] m).

Every motion here maps a head-local point x to `R x + translation` at time t, so each one can be
passed straight to `Simulator(..., root_motion=motion)`. Rotations about a pivot p (the neck)
are returned as `R (x - p) + p`, i.e. translation = p - R p (+ any translation of its own).

Built-ins (frozen, keyword-only dataclasses, checked at construction):

    Still()                                       identity at all times
    Nod(amplitude_deg=15, frequency_hz=1)         pitch about +x through the pivot
    Shake(amplitude_deg=30, frequency_hz=1)       yaw about +z through the pivot
    Turntable(period_s=4)                         a full turn about +z every period_s
    Jerk(time_s=0.5, displacement=(0.1, 0, 0))    a smooth translation step
    Keyframes(times=..., rotations=..., translations=...)
    compose(a, b)                                 b first, then a

Nod and Shake oscillate as angle(t) = amplitude * ramp(t) * sin(2 pi f t); with ramp_s > 0 the
envelope `ramp` rises from 0 to 1 by a cubic smoothstep over ramp_s seconds, so the head starts
from rest (zero angle and zero angular velocity at t = 0).
"""

from dataclasses import dataclass, field
import math

import numpy as np

from ..validation import choice, real, vector3

INTERPOLATIONS = ("slerp", "linear", "step")
EXTRAPOLATIONS = ("hold", "cycle")
_ROTATION_TOL = 1e-6  # same tolerance as Simulator's check_rigid_transform


# ---- small rotation helpers (pure numpy) -----------------------------------------------------
def axis_angle_matrix(axis, angle: float) -> np.ndarray:
    """Rotation [3, 3] about unit `axis` [3] by `angle` [rad] (right hand), Rodrigues' formula."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def quaternion_to_matrix(q) -> np.ndarray:
    """Rotation [3, 3] of a unit quaternion q = (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def matrix_to_quaternion(r) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a proper rotation r [3, 3] (Shepperd's method: divide by
    the largest of the four candidate components, so no branch loses precision)."""
    r = np.asarray(r, dtype=np.float64)
    trace = np.trace(r)
    candidates = np.array([trace, r[0, 0], r[1, 1], r[2, 2]])
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    else:
        i, j, m = k - 1, k % 3, (k + 1) % 3
        s = 2.0 * math.sqrt(max(1.0 + r[i, i] - r[j, j] - r[m, m], 0.0))
        q = [0.0] * 4
        q[0] = (r[m, j] - r[j, m]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (r[j, i] + r[i, j]) / s
        q[1 + m] = (r[m, i] + r[i, m]) / s
    q = np.array(q)
    return q / np.linalg.norm(q)


def slerp(q0, q1, u: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions at fraction u in [0, 1] along the
    shortest arc (q1 is negated when q0 . q1 < 0: q and -q are the same rotation)."""
    q0, q1 = np.asarray(q0, dtype=np.float64), np.asarray(q1, dtype=np.float64)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 1.0 - 1e-12:  # nearly equal: sin(theta) ~ 0, the chord is the arc
        q = (1.0 - u) * q0 + u * q1
        return q / np.linalg.norm(q)
    theta = math.acos(min(dot, 1.0))
    s = math.sin(theta)
    return (math.sin((1.0 - u) * theta) * q0 + math.sin(u * theta) * q1) / s


def smoothstep(u):
    """Cubic 3u^2 - 2u^3 of u clamped to [0, 1]: 0 -> 0, 1 -> 1, zero slope at both ends."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _is_numeric(value):
    try:
        np.asarray(value, dtype=np.float64)
        return True
    except (TypeError, ValueError):
        return False


def _pivoted(rotation, pivot):
    """(R, p - R p): rotation about the pivot point p [m], x -> R (x - p) + p."""
    p = np.asarray(pivot)
    return rotation, p - rotation @ p


# ---- built-in motions ------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Still:
    """The head never moves: (I, 0) at every t."""

    def __call__(self, t):
        return np.eye(3), np.zeros(3)


@dataclass(frozen=True, kw_only=True)
class _Oscillation:
    amplitude_deg: float = 15.0
    frequency_hz: float = 1.0
    axis: tuple = (1.0, 0.0, 0.0)
    pivot: tuple = (0.0, 0.0, 0.0)
    ramp_s: float = 0.0

    def __post_init__(self):
        real("amplitude_deg", self.amplitude_deg, "degrees", low=0.0, high=180.0)
        real("frequency_hz", self.frequency_hz, "Hz", low=0.0, low_open=True)
        real("ramp_s", self.ramp_s, "s", low=0.0)
        object.__setattr__(self, "axis", tuple(vector3("axis", self.axis, "1", normalise=True).tolist()))
        object.__setattr__(self, "pivot", tuple(vector3("pivot", self.pivot, "m").tolist()))

    def angle(self, t: float) -> float:
        """Signed rotation angle [rad] at time t [s]."""
        envelope = 1.0 if self.ramp_s == 0.0 else float(smoothstep(t / self.ramp_s))
        return math.radians(self.amplitude_deg) * envelope * math.sin(2.0 * math.pi * self.frequency_hz * t)

    def __call__(self, t):
        return _pivoted(axis_angle_matrix(self.axis, self.angle(float(t))), self.pivot)


@dataclass(frozen=True, kw_only=True)
class Nod(_Oscillation):
    """Pitch oscillation: angle(t) = amplitude_deg * ramp(t) * sin(2 pi frequency_hz t) about
    `axis` (unit-normalised; default +x, the ear-to-ear axis) through `pivot` [m] (the neck).
    ramp_s [s] >= 0: smoothstep ramp-in of the amplitude (0: none)."""

    axis: tuple = (1.0, 0.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class Shake(_Oscillation):
    """Yaw oscillation ("no"): as Nod, about `axis` (default +z, up) through `pivot` [m]."""

    amplitude_deg: float = 30.0
    axis: tuple = (0.0, 0.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class Turntable:
    """Uniform rotation by 2 pi t / period_s [rad] about `axis` (default +z) through `pivot` [m];
    a negative period_s turns the other way. ramp_s [s]: the angular speed ramps up from rest
    (the angle is the integral of the smoothstep-ramped speed), 0 for none."""

    period_s: float = 4.0
    axis: tuple = (0.0, 0.0, 1.0)
    pivot: tuple = (0.0, 0.0, 0.0)
    ramp_s: float = 0.0

    def __post_init__(self):
        real("period_s", self.period_s, "s (non-zero)")
        if self.period_s == 0:
            raise ValueError(f"period_s must be a finite non-zero number of seconds, got {self.period_s!r}")
        real("ramp_s", self.ramp_s, "s", low=0.0)
        object.__setattr__(self, "axis", tuple(vector3("axis", self.axis, "1", normalise=True).tolist()))
        object.__setattr__(self, "pivot", tuple(vector3("pivot", self.pivot, "m").tolist()))

    def angle(self, t: float) -> float:
        """Rotation angle [rad] at time t [s]."""
        omega = 2.0 * math.pi / self.period_s
        if self.ramp_s == 0.0:
            return omega * t
        u = min(max(t, 0.0) / self.ramp_s, 1.0)
        ramped = self.ramp_s * (u ** 3 - 0.5 * u ** 4)  # integral of the smoothstep speed to t
        return omega * (ramped + max(t - self.ramp_s, 0.0))

    def __call__(self, t):
        return _pivoted(axis_angle_matrix(self.axis, self.angle(float(t))), self.pivot)


@dataclass(frozen=True, kw_only=True)
class Jerk:
    """A sudden smooth translation: the head moves by `displacement` [m] between time_s and
    time_s + duration_s [s], following a cubic smoothstep (zero velocity at both ends); no
    rotation. Before time_s it is at rest at the origin, after it rests at `displacement`."""

    time_s: float = 0.5
    displacement: tuple = (0.1, 0.0, 0.0)
    duration_s: float = 0.05

    def __post_init__(self):
        real("time_s", self.time_s, "s")
        real("duration_s", self.duration_s, "s", low=0.0, low_open=True)
        object.__setattr__(self, "displacement", tuple(vector3("displacement", self.displacement, "m").tolist()))

    def __call__(self, t):
        u = (float(t) - self.time_s) / self.duration_s
        return np.eye(3), float(smoothstep(u)) * np.asarray(self.displacement)


@dataclass(frozen=True, kw_only=True)
class Composed:
    """x -> A(B(x)): `inner` applied first, then `outer` (R = R_a R_b, t = R_a t_b + t_a)."""

    outer: object
    inner: object

    def __post_init__(self):
        for name in ("outer", "inner"):
            if not callable(getattr(self, name)):
                raise ValueError(f"{name} must be a callable t -> (R [3, 3], t [3]), "
                                 f"got {type(getattr(self, name)).__name__}")

    def __call__(self, t):
        ra, ta = self.outer(t)
        rb, tb = self.inner(t)
        ra, ta, rb, tb = (np.asarray(a, dtype=np.float64) for a in (ra, ta, rb, tb))
        return ra @ rb, ra @ tb + ta


def compose(a, b) -> Composed:
    """Motion applying b first, then a: x -> R_a (R_b x + t_b) + t_a. E.g. a head that nods
    while the body carries it: compose(Jerk(...), Nod(...))."""
    return Composed(outer=a, inner=b)


# ---- keyframes -------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True, eq=False)
class Keyframes:
    """Piecewise motion through K poses.

    times: [K] s, strictly increasing (K >= 1).
    rotations: [K, 3, 3] proper rotations or [K, 4] quaternions (w, x, y, z; normalised here),
        or None (identity); stored as [K, 3, 3] matrices (given matrices are kept bit-exact and
        returned at the keyframe times), with unit quaternions in `quaternions` [K, 4]. translations: [K, 3] m, or None (zero).
    interpolation: "slerp" (rotations along the shortest arc at constant angular speed,
        translations linear: both piecewise constant speed), "linear" (normalised linear
        quaternion blend ("nlerp"): same path as slerp, not constant speed; translations
        linear) or "step" (hold each keyframe until the next).
    extrapolate: "hold" (first / last pose outside [times[0], times[-1]]) or "cycle" (repeat
        the span with period times[-1] - times[0]; make the last pose equal the first for a
        seamless loop).
    Note: translations are linear, not Catmull-Rom, so the velocity jumps at keyframes (no
    overshoot between poses); add keyframes or use a smooth motion if the jump matters.
    """

    times: np.ndarray
    rotations: np.ndarray | None = None
    translations: np.ndarray | None = None
    interpolation: str = "slerp"
    extrapolate: str = "hold"
    quaternions: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        times = _keyframe_times(self.times)
        quats = _keyframe_quaternions(self.rotations, len(times))
        trans = _keyframe_translations(self.translations, len(times))
        choice("interpolation", self.interpolation, INTERPOLATIONS)
        choice("extrapolate", self.extrapolate, EXTRAPOLATIONS)
        if self.extrapolate == "cycle" and len(times) < 2:
            raise ValueError(f"extrapolate='cycle' needs at least 2 keyframes, got {len(times)}")
        for a in (times, quats, trans):
            a.setflags(write=False)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "translations", trans)
        object.__setattr__(self, "quaternions", quats)
        given = None if self.rotations is None else np.array(self.rotations, dtype=np.float64)
        matrices = given if given is not None and given.ndim == 3 else \
            np.stack([quaternion_to_matrix(q) for q in quats])  # keyframe matrices stay bit-exact
        matrices.setflags(write=False)
        object.__setattr__(self, "rotations", matrices)

    def _locate(self, t):
        """(k, u): t lies at fraction u in [0, 1] of segment [times[k], times[k+1]]."""
        times = self.times
        if self.extrapolate == "cycle":
            span = times[-1] - times[0]
            t = times[0] + (t - times[0]) % span
        if t <= times[0] or len(times) == 1:
            return 0, 0.0
        if t >= times[-1]:
            return len(times) - 2, 1.0
        k = int(np.searchsorted(times, t, side="right")) - 1
        return k, (t - times[k]) / (times[k + 1] - times[k])

    def __call__(self, t):
        k, u = self._locate(float(t))
        if len(self.times) == 1 or u == 0.0:
            return self.rotations[k].copy(), self.translations[k].copy()
        if u == 1.0:
            return self.rotations[k + 1].copy(), self.translations[k + 1].copy()
        if self.interpolation == "step":
            return self.rotations[k].copy(), self.translations[k].copy()
        q0, q1 = self.quaternions[k], self.quaternions[k + 1]
        if self.interpolation == "slerp":
            q = slerp(q0, q1, u)
        else:
            q1 = q1 if np.dot(q0, q1) >= 0 else -q1
            q = (1.0 - u) * q0 + u * q1
            q = q / np.linalg.norm(q)
        trans = (1.0 - u) * self.translations[k] + u * self.translations[k + 1]
        return quaternion_to_matrix(q), trans


def _keyframe_times(times):
    t = np.array(times, dtype=np.float64) if _is_numeric(times) else None
    if t is None or t.ndim != 1 or len(t) < 1 or not np.all(np.isfinite(t)):
        raise ValueError(f"times must be a 1-D array of K >= 1 finite seconds, got {times!r}")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        raise ValueError(f"times must be strictly increasing (s); times[{bad[0] + 1}] = "
                         f"{t[bad[0] + 1]!r} follows times[{bad[0]}] = {t[bad[0]]!r}")
    return t


def _keyframe_quaternions(rotations, k):
    """Unit quaternions [K, 4] of validated rotations; no sign fix (slerp picks the short arc)."""
    if rotations is None:
        return np.tile([1.0, 0.0, 0.0, 0.0], (k, 1))
    r = np.array(rotations, dtype=np.float64) if _is_numeric(rotations) else None
    if r is None or r.shape not in ((k, 3, 3), (k, 4)) or not np.all(np.isfinite(r)):
        raise ValueError(f"rotations must be finite [K={k}, 3, 3] matrices or [K={k}, 4] "
                         f"quaternions (w, x, y, z), got shape {getattr(r, 'shape', None)}")
    if r.shape == (k, 4):
        norms = np.linalg.norm(r, axis=1)
        if np.any(norms < 1e-12):
            raise ValueError(f"rotations: quaternion {int(np.argmin(norms))} has zero length; "
                             "quaternions must be non-zero (they are normalised)")
        return r / norms[:, None]
    for i, m in enumerate(r):
        err = np.abs(m.T @ m - np.eye(3)).max()
        det = np.linalg.det(m)
        if err > _ROTATION_TOL or abs(det - 1.0) > _ROTATION_TOL:
            raise ValueError(f"rotations[{i}] must be a proper rotation (R^T R = I within "
                             f"{_ROTATION_TOL:g}, det = +1), got |R^T R - I| = {err:.3g}, det = {det:.6g}")
    return np.stack([matrix_to_quaternion(m) for m in r])


def _keyframe_translations(translations, k):
    if translations is None:
        return np.zeros((k, 3))
    p = np.array(translations, dtype=np.float64) if _is_numeric(translations) else None
    if p is None or p.shape != (k, 3) or not np.all(np.isfinite(p)):
        raise ValueError(f"translations must be a finite [K={k}, 3] array of metres, "
                         f"got shape {getattr(p, 'shape', None)}")
    return p
