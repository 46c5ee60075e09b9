"""Walls and shelves: distance, gradient and barrier rows (eq. 4.5 generalised to a shape),
checked against finite differences, hand-placed points and the qpsolvers oracle."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from agent import barriers
from agent.control import Controller, ControlParams, StepInput, build_rows
from agent.qp import qpsolvers_solver, solve_exact
from geometry import shapes
from geometry.shapes import box, box_distance, path_clearance, segment, segment_distance, shape_h

coord = st.floats(-3, 3)
H = 1e-6


def brute_outline_distance(sh, px, py, n=4000):
    """Distance to the outline sampled densely (reference for the closed form)."""
    pts = sh.corners()
    loops = pts if sh.kind == shapes.SEGMENT else pts + [pts[0]]
    best = math.inf
    for (ax, ay), (bx, by) in zip(loops, loops[1:], strict=False):
        for k in range(n + 1):
            t = k / n
            best = min(best, math.hypot(px - (ax + t * (bx - ax)), py - (ay + t * (by - ay))))
    return best


@settings(max_examples=300, deadline=None)
@given(coord, coord, coord, coord, coord, coord)
def test_segment_gradient_matches_finite_differences(px, py, ax, ay, bx, by):
    d, gx, gy = segment_distance(px, py, ax, ay, bx, by)
    assume(d > 0.05)  # closer, the central difference's own error (about H / 4d) exceeds the tolerance

    def f(x, y):
        return segment_distance(x, y, ax, ay, bx, by)[0]

    assert gx == pytest.approx((f(px + H, py) - f(px - H, py)) / (2 * H), abs=1e-5)
    assert gy == pytest.approx((f(px, py + H) - f(px, py - H)) / (2 * H), abs=1e-5)
    assert math.hypot(gx, gy) == pytest.approx(1.0)


@settings(max_examples=300, deadline=None)
@given(coord, coord, coord, coord, st.floats(0.05, 2.0), st.floats(0.05, 2.0),
       st.floats(-math.pi, math.pi))
def test_box_gradient_matches_finite_differences_inside_and_out(px, py, cx, cy, hx, hy, yaw):
    c, s = math.cos(yaw), math.sin(yaw)
    d, gx, gy = box_distance(px, py, cx, cy, hx, hy, c, s)
    u = c * (px - cx) + s * (py - cy)
    v = -s * (px - cx) + c * (py - cy)
    # away from the kinks: the diagonals inside, the outline itself and the axes through the centre;
    # and off the lines extending the sides outside, where the distance is only C1 (a central
    # difference there is off by about H / d: the curvature of the corner's arc)
    assume(abs(d) > 1e-3 and abs(abs(u) - hx - (abs(v) - hy)) > 1e-3 and abs(u) > 1e-3 and abs(v) > 1e-3)
    assume(abs(abs(u) - hx) > 1e-3 and abs(abs(v) - hy) > 1e-3)

    def f(x, y):
        return box_distance(x, y, cx, cy, hx, hy, c, s)[0]

    assert gx == pytest.approx((f(px + H, py) - f(px - H, py)) / (2 * H), abs=1e-5)
    assert gy == pytest.approx((f(px, py + H) - f(px, py - H)) / (2 * H), abs=1e-5)
    assert math.hypot(gx, gy) == pytest.approx(1.0)


@settings(max_examples=60, deadline=None)
@given(coord, coord, st.floats(-1, 1), st.floats(-1, 1), st.floats(0.1, 1.0), st.floats(0.1, 1.0),
       st.floats(-math.pi, math.pi))
def test_box_distance_is_the_distance_to_the_outline_negative_inside(px, py, cx, cy, hx, hy, yaw):
    sh = box("b", (cx, cy), (2 * hx, 2 * hy), yaw, 0.1)
    d = shapes.shape_distance(px, py, sh)[0]
    assert abs(d) == pytest.approx(brute_outline_distance(sh, px, py), abs=2e-3)
    u = math.cos(yaw) * (px - cx) + math.sin(yaw) * (py - cy)
    v = -math.sin(yaw) * (px - cx) + math.cos(yaw) * (py - cy)
    inside = abs(u) < hx and abs(v) < hy
    assert (d < 0) == inside or abs(d) < 1e-9


def test_a_point_nearest_a_corner_gets_the_radial_gradient():
    sh = box("shelf", (0.0, 0.0), (2.0, 1.0), 0.0, 0.2)  # corners at (+-1, +-0.5)
    d, gx, gy = shapes.shape_distance(1.3, 0.9, sh)
    assert d == pytest.approx(0.5)
    assert (gx, gy) == pytest.approx((0.6, 0.8))
    # rotated by 90 degrees the same corner sits at (-0.5, 1)
    sh90 = box("shelf", (0.0, 0.0), (2.0, 1.0), math.pi / 2, 0.2)
    d, gx, gy = shapes.shape_distance(-0.5 - 0.4, 1.0 + 0.3, sh90)
    assert d == pytest.approx(0.5)
    assert (gx, gy) == pytest.approx((-0.8, 0.6))


def test_a_segment_end_gets_the_radial_gradient_and_a_side_the_normal():
    wall = segment("w", (0.0, 0.0), (4.0, 0.0), 0.15)
    d, gx, gy = shapes.shape_distance(5.0, 1.0, wall)
    assert d == pytest.approx(math.sqrt(2.0))
    assert (gx, gy) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    d, gx, gy = shapes.shape_distance(2.0, -0.4, wall)
    assert (d, gx, gy) == pytest.approx((0.4, 0.0, -1.0))
    assert shape_h(2.0, -0.4, wall) == pytest.approx(0.25)


def test_inside_a_box_the_distance_is_negative_and_the_gradient_leads_out_of_the_nearest_face():
    sh = box("shelf", (1.0, 1.0), (4.0, 1.0), 0.0, 0.1)  # x in [-1, 3], y in [0.5, 1.5]
    d, gx, gy = shapes.shape_distance(2.8, 1.1, sh)
    assert d == pytest.approx(-0.2)
    assert (gx, gy) == pytest.approx((1.0, 0.0))
    d2, _, _ = shapes.shape_distance(2.8 - 0.01 * gx, 1.1 - 0.01 * gy, sh)
    assert d2 < d  # deeper along -gradient: more negative
    d, gx, gy = shapes.shape_distance(1.0, 0.6, sh)
    assert (d, gx, gy) == pytest.approx((-0.1, 0.0, -1.0))


def test_path_clearance_sees_a_path_through_a_box_and_one_passing_beside_it():
    sh = box("shelf", (0.0, 0.0), (2.0, 1.0), 0.3, 0.1)
    assert path_clearance((-3.0, 0.0), (3.0, 0.0), sh) == 0.0
    assert path_clearance((-0.1, 0.0), (0.1, 0.0), sh) == 0.0  # wholly inside
    wall = segment("w", (0.0, -1.0), (0.0, 1.0), 0.1)
    assert path_clearance((-1.0, 2.0), (1.0, 2.0), wall) == pytest.approx(1.0)
    assert path_clearance((-1.0, 0.0), (1.0, 0.0), wall) == 0.0
    rng = random.Random(3)
    for _ in range(200):  # against dense sampling of the path
        p0 = (rng.uniform(-3, 3), rng.uniform(-3, 3))
        p1 = (rng.uniform(-3, 3), rng.uniform(-3, 3))
        ref = min(max(shapes.shape_distance(p0[0] + t / 400 * (p1[0] - p0[0]),
                                            p0[1] + t / 400 * (p1[1] - p0[1]), sh)[0], 0.0)
                  for t in range(401))
        assert path_clearance(p0, p1, sh) == pytest.approx(ref, abs=0.02)


@settings(max_examples=300, deadline=None)
@given(coord, coord, st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(0.1, 2.0),
       st.sampled_from(["segment", "box"]))
def test_shape_row_is_the_cbf_condition_on_the_distance(px, py, ux, uy, gamma, kind):
    sh = (segment("w", (-1.0, 0.5), (1.5, -0.2), 0.15) if kind == "segment"
          else box("b", (0.2, 0.1), (1.6, 0.7), 0.4, 0.15))
    h, (ax, ay, b) = barriers.shape_row(px, py, sh, gamma)
    assert h == pytest.approx(shape_h(px, py, sh))
    d0 = shapes.shape_distance(px, py, sh)[0]
    assume(abs(d0) > 1e-3)
    hdot = (shape_h(px + ux * H, py + uy * H, sh) - shape_h(px - ux * H, py - uy * H, sh)) / (2 * H)
    # the row holds exactly when hdot >= -gamma h (up to the kinks, excluded by assume above)
    assert (b - (ax * ux + ay * uy)) == pytest.approx(hdot + gamma * h, abs=1e-4)


def test_qp_with_shape_rows_agrees_with_the_qpsolvers_oracle():
    params = ControlParams(max_speed=0.22)
    oracle = qpsolvers_solver("daqp")
    rng = random.Random(5)
    walls = [segment("w1", (-2.0, 1.0), (2.0, 1.0), 0.15), segment("w2", (1.0, -2.0), (1.0, 0.6), 0.15),
             box("s1", (-1.0, -0.8), (1.5, 0.5), 0.5, 0.15), box("s2", (0.0, 0.0), (0.4, 0.4), -0.2, 0.15)]
    compared = active = 0
    for _ in range(600):
        px, py = rng.uniform(-2.5, 2.5), rng.uniform(-2.5, 2.5)
        if min(shapes.shape_distance(px, py, w)[0] - w.ds for w in walls) < 0.0:
            continue
        nux, nuy = rng.uniform(-0.22, 0.22), rng.uniform(-0.22, 0.22)
        rows = build_rows(params, (px, py), 0.0, (nux, nuy), StepInput(shapes=walls))
        all_rows = rows.limits + rows.hard + list(rows.contact)  # shapes are contact rows
        mine = solve_exact(nux, nuy, all_rows)
        ref = oracle(nux, nuy, all_rows)
        assert mine is not None and ref is not None  # the start is safe: u = 0 is feasible
        assert math.dist(mine, ref) <= 1e-6
        for sh in walls:  # every shape row holds at the solution
            _, (ax, ay, b) = barriers.shape_row(px, py, sh, params.gamma_obstacle)
            assert ax * mine[0] + ay * mine[1] <= b + 1e-9
        active += math.dist(mine, (nux, nuy)) > 1e-6
        compared += 1
    assert compared > 300 and active > 20


def test_driving_straight_at_a_wall_stops_short_of_ds():
    params = ControlParams(max_speed=0.22, gamma_obstacle=1.0)
    wall = segment("w", (-1.0, 1.0), (1.0, 1.0), 0.3)
    x, y = 0.05, 0.0
    for _ in range(400):
        res = Controller(params).step(StepInput((x, y, 0.0), (0.05, 3.0), shapes=[wall]))
        x, y = x + res.ux * 0.05, y + res.uy * 0.05
        assert 1.0 - y >= 0.3 - 1e-9
    assert 1.0 - y == pytest.approx(0.3, abs=0.01)
    assert res.h_obstacle == pytest.approx(0.0, abs=0.01)
