"""Head motions against closed forms: rotations stay proper, slerp runs at constant angular
speed through the keyframes, periods and amplitudes are as asked, pivots stay put."""

import math

import numpy as np
import pytest

from taichi_hair.world.motion import (Jerk, Keyframes, Nod, Shake, Still, Turntable, compose,
                                matrix_to_quaternion, quaternion_to_matrix)
from taichi_hair.solver.simulator import check_rigid_transform

from helpers import rotation_matrix


def rotation_angle(r):
    """Angle [rad] of a rotation matrix, from its trace (independent of the quaternion code)."""
    return math.acos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))


def random_rotations(n, seed):
    rng = np.random.default_rng(seed)
    return [rotation_matrix(rng.standard_normal(3), rng.uniform(0.1, 3.0)) for _ in range(n)]


def keyframes(interpolation="slerp", extrapolate="hold"):
    return Keyframes(times=[0.0, 0.4, 1.0, 1.7], rotations=random_rotations(4, 1),
                     translations=[[0, 0, 0], [0.1, 0, 0], [0.1, 0.2, 0], [0, 0, -0.05]],
                     interpolation=interpolation, extrapolate=extrapolate)


MOTIONS = [Still(), Nod(amplitude_deg=20, frequency_hz=1.3, pivot=(0, -0.02, -0.1), ramp_s=0.3),
           Shake(amplitude_deg=40, frequency_hz=2.0), Turntable(period_s=3.0, axis=(1, 1, 1), ramp_s=0.5),
           Jerk(time_s=0.2, displacement=(0.1, 0, 0.05), duration_s=0.1), keyframes(),
           keyframes("linear", "cycle"), keyframes("step"), compose(Nod(), Turntable(period_s=2.0))]


@pytest.mark.parametrize("motion", MOTIONS, ids=lambda m: type(m).__name__)
def test_rotations_are_proper_at_random_times(motion):
    for t in np.random.default_rng(0).uniform(-1.0, 5.0, 50):
        r, trans = motion(t)
        assert np.abs(r.T @ r - np.eye(3)).max() < 1e-12
        assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)
        assert np.asarray(trans).shape == (3,)
        check_rigid_transform(r, trans)  # what Simulator(root_motion=...) accepts


def test_quaternion_round_trip_including_half_turns():
    for r in random_rotations(20, 3) + [rotation_matrix((0, 1, 1), math.pi), np.diag([1.0, -1, -1])]:
        q = matrix_to_quaternion(r)
        assert np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(quaternion_to_matrix(q), r, atol=1e-12)


def test_slerp_hits_keyframes_exactly_and_turns_at_constant_speed():
    motion = keyframes()
    for k, t in enumerate(motion.times):
        r, trans = motion(t)
        np.testing.assert_array_equal(r, motion.rotations[k])
        np.testing.assert_array_equal(trans, motion.translations[k])
    rots = random_rotations(4, 1)
    np.testing.assert_array_equal(motion.rotations, np.stack(rots))  # given matrices kept bit-exact
    for k in range(3):
        t0, t1 = motion.times[k], motion.times[k + 1]
        r0 = motion(t0)[0]
        total = rotation_angle(motion(t1)[0] @ r0.T)
        assert total > 0.05  # the test is not vacuous
        for u in np.linspace(0.05, 0.95, 7):
            relative = motion(t0 + u * (t1 - t0))[0] @ r0.T
            assert rotation_angle(relative) == pytest.approx(u * total, abs=1e-9)
        # linear translation: the midpoint pose is halfway
        np.testing.assert_allclose(motion(0.5 * (t0 + t1))[1],
                                   0.5 * (motion.translations[k] + motion.translations[k + 1]), atol=1e-15)


def test_slerp_takes_the_shortest_arc():
    # 300 degrees about z is -60 degrees: the path must pass through -30, not +150
    motion = Keyframes(times=[0.0, 1.0], rotations=[np.eye(3), rotation_matrix((0, 0, 1), math.radians(300))])
    np.testing.assert_allclose(motion(0.5)[0], rotation_matrix((0, 0, 1), math.radians(-30)), atol=1e-12)
    # quaternions with opposite signs describe the same keyframe: no detour either
    q = Keyframes(times=[0, 1], rotations=[[1, 0, 0, 0], [-math.cos(0.3), 0, 0, -math.sin(0.3)]])
    assert rotation_angle(q(0.5)[0]) == pytest.approx(0.3, abs=1e-12)


def test_step_and_hold_and_cycle():
    step = keyframes("step")
    np.testing.assert_array_equal(step(0.39)[0], step.rotations[0])
    np.testing.assert_array_equal(step(-3.0)[1], step.translations[0])
    np.testing.assert_array_equal(step(10.0)[1], step.translations[-1])
    cycle = keyframes("slerp", "cycle")
    np.testing.assert_allclose(cycle(0.3 + 1.7)[0], cycle(0.3)[0], atol=1e-12)
    linear = keyframes("linear")
    np.testing.assert_allclose(linear(0.4)[0], linear.rotations[1], atol=1e-15)


def test_shake_period_and_amplitude():
    f, amp = 1.7, 25.0
    motion = Shake(amplitude_deg=amp, frequency_hz=f)
    times = np.linspace(0.0, 2.0, 4001)
    angles = np.array([rotation_angle(motion(t)[0]) for t in times])
    assert angles.max() == pytest.approx(math.radians(amp), rel=1e-5)
    for t in np.random.default_rng(1).uniform(0, 3, 20):
        np.testing.assert_allclose(motion(t + 1.0 / f)[0], motion(t)[0], atol=1e-12)
    # yaw: the rotation axis is +z, so z is untouched
    np.testing.assert_allclose(motion(0.1)[0] @ [0, 0, 1], [0, 0, 1], atol=1e-15)
    # a quarter period in, the angle is the full amplitude about +z
    np.testing.assert_allclose(motion(0.25 / f)[0], rotation_matrix((0, 0, 1), math.radians(amp)), atol=1e-12)


def test_ramp_starts_from_rest():
    motion = Nod(amplitude_deg=30, frequency_hz=2.0, ramp_s=0.5)
    h = 1e-5
    assert rotation_angle(motion(0.0)[0]) == 0.0
    assert rotation_angle(motion(h)[0]) / h < 1e-3  # angular speed ~ 0 at t = 0
    free = Nod(amplitude_deg=30, frequency_hz=2.0)
    np.testing.assert_allclose(motion(0.9)[0], free(0.9)[0], atol=1e-15)  # full amplitude after the ramp


def test_turntable_completes_a_turn_and_pivot_stays_fixed():
    pivot = np.array([0.01, -0.03, -0.12])
    motion = Turntable(period_s=2.5, axis=(0, 0, 2), pivot=pivot)
    np.testing.assert_allclose(motion(2.5)[0], np.eye(3), atol=1e-12)
    assert rotation_angle(motion(1.25)[0]) == pytest.approx(math.pi, abs=1e-9)
    np.testing.assert_allclose(motion(2.5 / 4)[0], rotation_matrix((0, 0, 1), math.pi / 2), atol=1e-12)
    for m in (motion, Nod(pivot=pivot, amplitude_deg=30), Shake(pivot=pivot)):
        for t in (0.1, 0.37, 1.9):
            r, trans = m(t)
            np.testing.assert_allclose(r @ pivot + trans, pivot, atol=1e-15)
            assert rotation_angle(r) > 1e-3


def test_jerk_moves_by_displacement():
    d = np.array([0.05, -0.1, 0.02])
    motion = Jerk(time_s=0.3, displacement=d, duration_s=0.04)
    np.testing.assert_array_equal(motion(0.0)[1], 0.0)
    np.testing.assert_array_equal(motion(0.3)[1], 0.0)
    np.testing.assert_allclose(motion(0.32)[1], 0.5 * d, atol=1e-15)
    np.testing.assert_allclose(motion(0.34)[1], d, atol=1e-15)
    np.testing.assert_allclose(motion(5.0)[1], d, atol=1e-15)
    h = 1e-7  # smooth: zero velocity at both ends of the step
    assert np.linalg.norm(motion(0.34 - h)[1] - motion(0.34)[1]) / h < 1e-3


def test_compose_applies_inner_first():
    a, b = Turntable(period_s=4.0), Jerk(time_s=0.0, displacement=(0.1, 0, 0), duration_s=0.5)
    r, t = compose(a, b)(1.0)  # b moves x by 0.1, then a turns 90 degrees about z
    x = np.array([0.0, 0.0, 0.0])
    np.testing.assert_allclose(r @ x + t, [0.0, 0.1, 0.0], atol=1e-12)
    r, t = compose(b, a)(1.0)  # turn first (origin stays), then translate
    np.testing.assert_allclose(r @ x + t, [0.1, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("make, name", [
    (lambda: Nod(amplitude_deg=-5), "amplitude_deg"),
    (lambda: Nod(frequency_hz=0.0), "frequency_hz"),
    (lambda: Shake(ramp_s=-1), "ramp_s"),
    (lambda: Shake(axis=(0, 0, 0)), "axis"),
    (lambda: Nod(pivot=(0, 1)), "pivot"),
    (lambda: Turntable(period_s=0.0), "period_s"),
    (lambda: Jerk(duration_s=0.0), "duration_s"),
    (lambda: Jerk(displacement=(0, float("nan"), 0)), "displacement"),
    (lambda: Keyframes(times=[0.0, 1.0, 1.0]), "times"),
    (lambda: Keyframes(times=[0.0, 1.0], rotations=[np.eye(3), np.diag([1.0, 1, -1])]), "rotations"),
    (lambda: Keyframes(times=[0.0, 1.0], rotations=[np.eye(3), 2 * np.eye(3)]), "rotations"),
    (lambda: Keyframes(times=[0.0, 1.0], rotations=[[1, 0, 0, 0], [0, 0, 0, 0]]), "rotations"),
    (lambda: Keyframes(times=[0.0, 1.0], translations=[[0, 0, 0]]), "translations"),
    (lambda: Keyframes(times=[0.0, 1.0], interpolation="cubic"), "interpolation"),
    (lambda: Keyframes(times=[0.0, 1.0], extrapolate="mirror"), "extrapolate"),
    (lambda: compose(Nod(), 3), "inner"),
])
def test_bad_inputs_name_the_parameter(make, name):
    with pytest.raises(ValueError, match=name):
        make()
