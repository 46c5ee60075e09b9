"""The shared formulas of geometry.angles, geometry.speed_polygon and geometry.slack."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from geometry import speed_polygon
from geometry.angles import LEFT_BIAS, wrap_angle, wrap_half_turn, wrap_left
from geometry.slack import smallest_slack

angle = st.floats(-50.0, 50.0)


@given(angle)
def test_each_wrap_keeps_the_direction_and_lands_in_its_interval(a):
    w, left, half = wrap_angle(a), wrap_left(a), wrap_half_turn(a)
    assert -math.pi <= w < math.pi
    assert -math.pi + LEFT_BIAS <= left < math.pi + LEFT_BIAS + 1e-12
    assert -0.5 * math.pi <= half < 0.5 * math.pi
    for x, period in ((w, 2.0 * math.pi), (left, 2.0 * math.pi), (half, math.pi)):
        k = (a - x) / period
        assert k == pytest.approx(round(k), abs=1e-9)


def test_a_turn_near_half_a_turn_goes_left_and_a_plain_one_the_short_way():
    assert wrap_left(math.pi) == pytest.approx(math.pi)
    assert wrap_left(-math.pi + 0.5 * LEFT_BIAS) > 0.0  # just short of half a turn right: left
    assert wrap_left(-math.pi + 1.5 * LEFT_BIAS) < 0.0  # farther from it: the short way
    assert wrap_left(0.3) == pytest.approx(0.3) and wrap_left(-0.3) == pytest.approx(-0.3)


@given(st.floats(0.01, 1.0), st.floats(-math.pi, math.pi))
def test_the_speed_polygon_is_inscribed_with_a_vertex_along_the_heading(r, heading):
    rows = speed_polygon.rows(r, heading)
    assert len(rows) == speed_polygon.SIDES
    vertex = (r * math.cos(heading), r * math.sin(heading))
    assert max(nx * vertex[0] + ny * vertex[1] - b for nx, ny, b in rows) == pytest.approx(0.0, abs=1e-12)
    for nx, ny, b in rows:
        assert math.hypot(nx, ny) == pytest.approx(1.0)
        assert b == speed_polygon.face(r) < r


@given(st.floats(0.0, 10.0), st.integers(10, 60))
def test_the_slack_search_brackets_the_smallest_feasible_slack(c, steps):
    hi = smallest_slack(lambda s: s >= c, 10.0 + 1e-6, steps)
    assert c <= hi <= c + 10.0 / 2 ** steps + 1e-6
    early = smallest_slack(lambda s: s >= c, 10.0 + 1e-6, 60, (1e-3, 0.0))
    assert c <= early <= c + 1e-3
