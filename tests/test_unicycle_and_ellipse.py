"""The near-identity diffeomorphism (eq. 6.2) and the leader's ellipse estimate (eq. 4.7)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent import unicycle
from leader.ellipse import derive_axes, ellipse_value, estimate, reference_shape

angle = st.floats(-math.pi, math.pi)
speed = st.floats(-0.5, 0.5)


@settings(max_examples=200, deadline=None)
@given(speed, speed, angle)
def test_eq_6_2_and_its_inverse_round_trip(ux, uy, theta):
    v, w = unicycle.to_unicycle(ux, uy, theta, 0.05)
    assert unicycle.from_unicycle(v, w, theta, 0.05) == pytest.approx((ux, uy), abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(speed, speed, angle)
def test_limit_rows_are_exactly_the_speed_and_turn_rate_limits(ux, uy, theta):
    rows = unicycle.drive_limit_rows(theta, 0.05, 0.22, 2.84)
    v, w = unicycle.to_unicycle(ux, uy, theta, 0.05)
    inside = all(ax * ux + ay * uy <= b + 1e-12 for ax, ay, b in rows)
    assert inside == (abs(v) <= 0.22 + 1e-12 and abs(w) <= 2.84 + 1e-10)


@settings(max_examples=100, deadline=None)
@given(st.floats(-0.22, 0.22), st.floats(-2.84, 2.84), angle)
def test_exact_unicycle_integration_matches_fine_euler_steps(v, w, theta):
    x, y, th = 0.3, -0.2, theta
    for _ in range(10000):
        x += v * math.cos(th) * 1e-5
        y += v * math.sin(th) * 1e-5
        th += w * 1e-5
    assert unicycle.integrate(0.3, -0.2, theta, v, w, 0.1) == pytest.approx((x, y, th), abs=1e-6)


def test_control_point_velocity_follows_the_certified_command():
    # Moving the body by eq. 6.1 with (v, w) from eq. 6.2 moves s at u (to first order).
    x, y, th, look, dt = 0.0, 0.0, 0.4, 0.05, 1e-5
    ux, uy = 0.1, -0.15
    v, w = unicycle.to_unicycle(ux, uy, th, look)
    s0 = unicycle.control_point(x, y, th, look)
    s1 = unicycle.control_point(*unicycle.integrate(x, y, th, v, w, dt), look)
    assert ((s1[0] - s0[0]) / dt, (s1[1] - s0[1]) / dt) == pytest.approx((ux, uy), abs=1e-4)


RECT = [(-0.25, 0.125), (0.25, 0.125), (0.25, -0.125), (-0.25, -0.125)]


@settings(max_examples=100, deadline=None)
@given(st.floats(-5, 5), st.floats(-5, 5), angle, st.floats(-1, 1), st.floats(-0.2, 0.2),
       st.floats(-0.2, 0.2))
def test_estimate_recovers_a_rigid_motion_of_the_reference(tx, ty, theta, omega, vx, vy):
    shape = reference_shape(RECT)
    c, s = math.cos(theta), math.sin(theta)
    pos = [(tx + c * x - s * y, ty + s * x + c * y) for x, y in shape.offsets]
    # rigid-body velocities: v_c + omega x r
    vel = [(vx - omega * (p[1] - ty), vy + omega * (p[0] - tx)) for p in pos]
    e = estimate(shape, (0.6, 0.3), pos, vel)
    assert (e.cx, e.cy) == pytest.approx((tx, ty), abs=1e-9)
    assert math.remainder(e.alpha - (shape.alpha0 + theta), 2 * math.pi) == pytest.approx(0, abs=1e-9)
    assert (e.vx, e.vy, e.alpha_rate) == pytest.approx((vx, vy, omega), abs=1e-9)


def test_reference_orientation_is_the_long_side():
    assert reference_shape(RECT).alpha0 == pytest.approx(0.0, abs=1e-12)
    tall = [(y, x) for x, y in RECT]
    assert abs(math.remainder(reference_shape(tall).alpha0 - math.pi / 2, math.pi)) < 1e-12


@pytest.mark.parametrize("points", [RECT, [(-0.25, 0.0), (0.25, 0.0)],
                                    [(0.0, 0.35), (-0.303, -0.175), (0.303, -0.175)]])
def test_derived_axes_enclose_a_disk_of_the_clearance_around_every_member(points):
    shape = reference_shape(points)
    clearance = 0.3
    a, b = derive_axes(shape, clearance)
    assert a >= b > 0
    e = estimate(shape, (a, b), points, [(0.0, 0.0)] * len(points))
    for px, py in points:
        for phi in np.linspace(0, 2 * math.pi, 720):
            assert ellipse_value(e, px + clearance * math.cos(phi), py + clearance * math.sin(phi)) <= 1e-9


def test_derive_axes_rejects_a_non_positive_clearance():
    with pytest.raises(ValueError, match="clearance"):
        derive_axes(reference_shape(RECT), 0.0)

