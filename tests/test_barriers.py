"""Barrier values, gradients and rows against finite differences (thesis 4.3-4.6, appendix A)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent import barriers
from agent.barriers import Neighbour, Obstacle
from leader.ellipse import Ellipse

coord = st.floats(-3, 3)
vel = st.floats(-0.3, 0.3)
H = 1e-6


@settings(max_examples=300, deadline=None)
@given(coord, coord, coord, coord, st.floats(-math.pi, math.pi), st.floats(0.3, 1.5),
       st.floats(0.1, 1.0))
def test_ellipse_gradients_match_finite_differences(px, py, cx, cy, alpha, a, ratio):
    b = a * ratio
    h, gx, gy, ga = barriers.ellipse_terms(px, py, cx, cy, alpha, a, b)

    def f(px=px, py=py, alpha=alpha):
        return barriers.ellipse_terms(px, py, cx, cy, alpha, a, b)[0]

    scale = 1.0 + abs(h)
    assert gx == pytest.approx((f(px=px + H) - f(px=px - H)) / (2 * H), abs=1e-4 * scale)
    assert gy == pytest.approx((f(py=py + H) - f(py=py - H)) / (2 * H), abs=1e-4 * scale)
    assert ga == pytest.approx((f(alpha=alpha + H) - f(alpha=alpha - H)) / (2 * H), abs=1e-4 * scale)


def test_ellipse_value_matches_eq_4_6_written_out():
    px, py, cx, cy, al, a, b = 1.3, -0.4, 0.2, 0.1, 0.7, 0.6, 0.3
    c, s = math.cos(al), math.sin(al)
    dx, dy = px - cx, py - cy
    eq46 = ((c * c / a**2 + s * s / b**2) * dx * dx + (s * s / a**2 + c * c / b**2) * dy * dy
            + 2 * dx * dy * c * s * (1 / a**2 - 1 / b**2) - 1)
    assert barriers.ellipse_terms(px, py, cx, cy, al, a, b)[0] == pytest.approx(eq46, rel=1e-12)


def slack_of(row, ux, uy):
    ax, ay, b = row
    return b - (ax * ux + ay * uy)


@settings(max_examples=300, deadline=None)
@given(coord, coord, coord, coord, vel, vel, vel, vel, st.floats(0.1, 2.0))
def test_formation_rows_are_the_cbf_condition_with_the_neighbour_velocity(px, py, qx, qy, ux, uy,
                                                                          vx, vy, gamma):
    d = math.hypot(px - qx, py - qy)
    if d < 0.05:
        return
    df, eps = 0.5, 0.05
    hg, hl, rg, rl = barriers.formation_rows(px, py, Neighbour(qx, qy, vx, vy, df), eps, gamma)

    def hdot(k):  # d/dt of h along p' = u, q' = v
        def h(t):
            return barriers.formation_h(px + ux * t, py + uy * t, qx + vx * t, qy + vy * t, df, eps)[k]
        return (h(H) - h(-H)) / (2 * H)

    # Normalised rows: b - a.u = (h' + gamma h) / (2 |p - q|)
    assert slack_of(rg, ux, uy) == pytest.approx((hdot(0) + gamma * hg) / (2 * d), abs=1e-5)
    assert slack_of(rl, ux, uy) == pytest.approx((hdot(1) + gamma * hl) / (2 * d), abs=1e-5)


@settings(max_examples=300, deadline=None)
@given(coord, coord, coord, coord, vel, vel, vel, vel, st.floats(0.1, 2.0))
def test_obstacle_row_is_the_cbf_condition_with_the_obstacle_velocity(px, py, ox, oy, ux, uy, vx, vy,
                                                                      gamma):
    d = math.hypot(px - ox, py - oy)
    if d < 0.05:
        return
    o = Obstacle(ox, oy, vx, vy, 0.3)
    h, row = barriers.obstacle_row(px, py, o, gamma)

    def hh(t):
        return barriers.obstacle_h(px + ux * t, py + uy * t, Obstacle(ox + vx * t, oy + vy * t, 0, 0, 0.3))

    hdot = (hh(H) - hh(-H)) / (2 * H)
    assert slack_of(row, ux, uy) == pytest.approx((hdot + gamma * h) / (2 * d), abs=1e-5)


@settings(max_examples=300, deadline=None)
@given(st.tuples(coord, coord), coord, coord, vel, vel, vel, vel, st.floats(-0.5, 0.5),
       st.floats(-math.pi, math.pi), st.floats(0.1, 2.0))
def test_ellipse_row_includes_centroid_velocity_and_alpha_rate(point, cx, cy, ux, uy, vx, vy, w,
                                                               alpha, gamma):
    px, py = point
    e = Ellipse(cx, cy, alpha, 0.6, 0.3, vx, vy, w)
    h, gx, gy, _ = barriers.ellipse_terms(px, py, cx, cy, alpha, 0.6, 0.3)
    g = math.hypot(gx, gy)
    if g < 1e-3:
        return
    _, row = barriers.ellipse_row(px, py, e, gamma)

    def hh(t):
        return barriers.ellipse_terms(px + ux * t, py + uy * t, cx + vx * t, cy + vy * t,
                                      alpha + w * t, 0.6, 0.3)[0]

    hdot = (hh(H) - hh(-H)) / (2 * H)
    expected = (hdot + barriers.ellipse_class_k(h, gamma)) / g
    assert slack_of(row, ux, uy) == pytest.approx(expected, abs=1e-4 * (1 + abs(expected)))


def test_ellipse_class_k_is_the_thesis_gamma_h_near_the_boundary_and_increasing():
    g = 0.7
    assert barriers.ellipse_class_k(0.0, g) == 0.0
    assert barriers.ellipse_class_k(-0.2, g) == pytest.approx(-0.14)
    assert barriers.ellipse_class_k(1e-4, g) == pytest.approx(g * 1e-4, rel=1e-3)
    vals = [barriers.ellipse_class_k(h, g) for h in [-1, -0.5, 0, 0.5, 1, 5, 50]]
    assert vals == sorted(vals)


@pytest.mark.parametrize("heading", [0.0, 0.3, 2.0, -2.9])
def test_speed_polygon_is_inscribed_and_keeps_the_nominal_direction_at_full_speed(heading):
    rows = barriers.speed_rows(0.22, heading)
    vertex = (0.22 * math.cos(heading), 0.22 * math.sin(heading))
    assert max(ax * vertex[0] + ay * vertex[1] - b for ax, ay, b in rows) <= 1e-12
    for k in range(360):
        phi = 2 * math.pi * k / 360
        u = (0.2201 * math.cos(phi), 0.2201 * math.sin(phi))
        assert max(ax * u[0] + ay * u[1] - b for ax, ay, b in rows) > 0  # outside the disk: cut
