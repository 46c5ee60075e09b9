"""The robot's own pose filter (agent.localisation): the EKF's math keeps its covariance
symmetric positive semi-definite, the gate refuses forged and misread poses also after a long
blind stretch, late poses are fused at their capture stamp, and the handed pose never jumps."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.localisation import (
    Localiser,
    confidence_radius,
    predict,
    process_noise,
    update,
)

finite = st.floats(-5.0, 5.0, allow_nan=False)
small = st.floats(-0.05, 0.05, allow_nan=False)


def psd(p: np.ndarray) -> bool:
    return bool(np.allclose(p, p.T) and np.linalg.eigvalsh(p).min() >= -1e-12)


@st.composite
def covariances(draw):
    a = np.array(draw(st.lists(st.floats(-0.3, 0.3), min_size=9, max_size=9))).reshape(3, 3)
    return a @ a.T + 1e-6 * np.eye(3)


@settings(max_examples=200, deadline=None)
@given(p=covariances(), th=finite, inc=st.tuples(small, small, small))
def test_prediction_keeps_the_covariance_symmetric_psd_and_growing(p, th, inc):
    x = np.array([0.0, 0.0, th])
    _x, pn = predict(x, p, inc)
    assert psd(pn)
    # the process noise itself is PSD and never shrinks the uncertainty in a fixed direction
    assert psd(process_noise(th, inc))


@settings(max_examples=200, deadline=None)
@given(p=covariances(), z=st.tuples(finite, finite, finite))
def test_update_keeps_the_covariance_symmetric_psd_and_shrinks_it(p, z):
    r = np.diag([1e-4, 1e-4, 4e-4])
    _x, pn = update(np.zeros(3), p, z, r)
    assert psd(pn)
    assert np.trace(pn) <= np.trace(p) + 1e-12


def drive(loc: Localiser, steps: int, speed: float = 0.2, dt: float = 0.05, t0: float = 0.0):
    for k in range(steps):
        loc.odometry(t0 + (k + 1) * dt, (speed * dt, 0.0, 0.0), dt)
    return t0 + steps * dt


def test_a_robot_unseen_has_no_estimate_until_its_first_pose():
    loc = Localiser()
    drive(loc, 10)
    assert loc.estimate() is None
    assert loc.camera(0.5, (1.0, 2.0, 0.0))
    assert loc.estimate()[0] == (1.0, 2.0, 0.0)


def test_blind_driving_grows_the_radius_and_a_true_pose_is_fused_afterwards():
    loc = Localiser()
    loc.camera(0.0, (0.0, 0.0, 0.0))
    r0 = loc.estimate()[1]
    t = drive(loc, 400)  # 4 m blind
    pose, r = loc.estimate()
    assert r > r0 + 0.02 and math.isclose(pose[0], 4.0, abs_tol=1e-9)
    # the truth after 4 m with a 1 % short odometry: 4.04 m, 2 cm to the side
    assert loc.camera(t, (4.04, 0.02, 0.005))
    assert loc.rejected == 0


@settings(max_examples=50, deadline=None)
@given(angle=st.floats(0.0, 2 * math.pi), blind=st.integers(0, 400))
def test_a_pose_forged_half_a_metre_off_is_refused_even_after_a_long_blind_stretch(angle, blind):
    loc = Localiser()
    loc.camera(0.0, (0.0, 0.0, 0.0))
    t = drive(loc, blind)
    pose, _r = loc.estimate()
    forged = (pose[0] + 0.5 * math.cos(angle), pose[1] + 0.5 * math.sin(angle), pose[2])
    assert not loc.camera(t, forged)
    assert loc.rejected == 1
    assert loc.estimate()[0] == pose


def test_a_late_pose_is_fused_at_its_capture_stamp():
    """Moving at 0.2 m/s, a pose captured 0.5 s ago that says the robot was 3 cm to the left
    then moves the present estimate 3 cm to the left, not back to where it was."""
    loc = Localiser()
    loc.camera(0.0, (0.0, 0.0, 0.0))
    drive(loc, 40)  # 2 s, 0.4 m
    x_before = float(loc.x[0])
    assert loc.camera(1.5, (0.3, 0.03, 0.0))
    assert math.isclose(float(loc.x[0]), x_before, abs_tol=0.01)
    assert 0.015 < float(loc.x[1]) < 0.031


def test_the_handed_pose_moves_towards_a_correction_at_a_bounded_rate():
    loc = Localiser()
    loc.camera(0.0, (0.0, 0.0, 0.0))
    t = drive(loc, 400)
    assert loc.camera(t, (4.0, 0.08, 0.0))
    handed = [loc.estimate()[0][1]]
    for k in range(40):
        loc.odometry(t + (k + 1) * 0.05, (0.0, 0.0, 0.0), 0.05)
        handed.append(loc.estimate()[0][1])
    steps = np.diff(handed)
    assert steps.max() <= 0.05 * 0.05 + 1e-12  # max_correction per tick
    assert handed[-1] > 0.05  # and it gets there


def test_confidence_radius_of_an_isotropic_covariance():
    p = np.diag([0.01 ** 2, 0.01 ** 2, 1.0])
    assert math.isclose(confidence_radius(p), 0.01 * math.sqrt(5.991), rel_tol=1e-9)


def feed(loc: Localiser, t: float, offset: tuple[float, float], n: int) -> tuple[float, int]:
    """``n`` frames 0.05 s apart, each ``offset`` off the robot's estimate, the robot driving
    on at 0.2 m/s; the frames' stamp and how many were fused."""
    fused = 0
    for _ in range(n):
        t = drive(loc, 1, t0=t)
        x, y = float(loc.x[0]), float(loc.x[1])
        fused += loc.camera(t, (x + offset[0], y + offset[1], float(loc.x[2])))
    return t, fused


def test_a_disputed_filter_follows_a_consistent_camera_within_its_lost_bound():
    """Odometry three times worse than assumed after 4 m blind: the camera is 0.2 m off the
    estimate, beyond the physical bound (about 0.13 m) but within three times it. The filter
    refuses, counts itself disputed, then follows."""
    loc = Localiser()
    loc.camera(0.0, (0.0, 0.0, 0.0))
    t = drive(loc, 400)
    _t, fused = feed(loc, t, (0.2, 0.0), 20)
    assert loc.rejected >= loc.t.agree and fused > 0 and loc.relocalised == 1


@settings(max_examples=30, deadline=None)
@given(angle=st.floats(0.0, 2 * math.pi), blind=st.integers(0, 400))
def test_a_forger_holding_half_a_metre_is_never_followed(angle, blind):
    loc = Localiser()
    loc.camera(0.0, (0.0, 0.0, 0.0))
    t = drive(loc, blind)
    _t, fused = feed(loc, t, (0.5 * math.cos(angle), 0.5 * math.sin(angle)), 80)
    assert fused == 0 and loc.disputed and loc.relocalised == 0
