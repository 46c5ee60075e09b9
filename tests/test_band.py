"""Issue 13, the band: formation keeping first, the goal second
(agent.control.yield_push, band_nominal). Safety rows are untouched; only the nominal changes."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rules_off import params_with

from agent.barriers import Neighbour
from agent.control import (
    BAND_EASE,
    BAND_HOLD,
    YIELD_RANGE,
    ControlParams,
    FormationView,
    _half_width,
    band_nominal,
    control_step,
    yield_push,
)
from geometry.ellipse import Ellipse
from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate

ROOT = Path(__file__).resolve().parents[1]
P = ControlParams(tiebreak=False)
EPS = P.epsilon

angle = st.floats(-math.pi, math.pi)
df = st.floats(0.25, 1.0)
vel = st.tuples(st.floats(-0.22, 0.22), st.floats(-0.22, 0.22))


def _neighbour(bearing: float, dist: float, df: float, v=(0.0, 0.0)) -> Neighbour:
    return Neighbour(dist * math.cos(bearing), dist * math.sin(bearing), v[0], v[1], df)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(angle, df, st.floats(-0.99, 0.99), vel), min_size=1, max_size=3),
       vel)
def test_within_the_ease_band_the_nominal_is_the_goals_alone(edges, goal_u):
    nbrs = [_neighbour(b, d + f * BAND_EASE * EPS, d, v) for b, d, f, v in edges]
    assert band_nominal(P, 0.0, 0.0, goal_u, nbrs) == goal_u


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(angle, df, st.floats(BAND_HOLD, 4.0), st.booleans()),
                min_size=1, max_size=3), vel)
def test_beyond_the_hold_band_the_nominal_only_lowers_the_edge_error_of_still_neighbours(edges, goal_u):
    # Every own edge at least BAND_HOLD epsilon off (stretched or squeezed), neighbours still:
    # whatever the goal asks, the nominal does not raise sum (|p - p_j| - Df_j)^2 (first order).
    nbrs = [_neighbour(b, d + (f if out else -f) * EPS, d) for b, d, f, out in edges]
    ux, uy = band_nominal(P, 0.0, 0.0, goal_u, nbrs)
    assert math.hypot(ux, uy) <= P.max_speed + 1e-12
    rate = 0.0
    for n in nbrs:
        d = math.hypot(n.x, n.y)
        rate += 2.0 * (d - n.df) * (-(n.x * ux + n.y * uy) / d)
    assert rate <= 1e-12


@settings(max_examples=100, deadline=None)
@given(angle, df, df, st.floats(0.0, 0.22), angle, vel)
def test_a_member_squeezed_evenly_between_its_neighbours_moves_with_them(b, d1, d2, sp, a, goal_u):
    # Two neighbours on opposite sides, both edges squeezed by the same error: the band-keeping
    # parts cancel and the member moves with its neighbours, not at its goal.
    err = -1.2 * EPS
    v = (sp * math.cos(a), sp * math.sin(a))  # within the speed limit
    nbrs = [_neighbour(b, d1 + err, d1, v), _neighbour(b + math.pi, d2 + err, d2, v)]
    ux, uy = band_nominal(P, 0.0, 0.0, goal_u, nbrs)
    assert ux == pytest.approx(v[0], abs=1e-9) and uy == pytest.approx(v[1], abs=1e-9)


def test_control_step_keeps_the_goal_nominal_for_an_undisturbed_formation_and_bends_it_otherwise():
    goal = (3.0, 0.0)
    calm = [Neighbour(0.0, 0.5, 0.0, 0.0, 0.5)]
    r = control_step(P, (0.0, 0.0, 0.0), goal, neighbours=calm)
    assert (r.nominal_ux, r.nominal_uy) == pytest.approx((P.max_speed, 0.0))
    squeezed = [Neighbour(0.0, 0.5 - 1.5 * EPS, 0.0, 0.0, 0.5)]  # band broken: repair first
    r = control_step(P, (0.0, 0.0, 0.0), goal, neighbours=squeezed)
    assert r.nominal_ux == pytest.approx(0.0, abs=1e-12) and r.nominal_uy < 0.0
    off = replace(P, band_first=False)
    r = control_step(off, (0.0, 0.0, 0.0), goal, neighbours=squeezed)
    assert (r.nominal_ux, r.nominal_uy) == pytest.approx((P.max_speed, 0.0))
    uni = replace(P, unicycle=True)  # unicycles too: their control point repairs the band first
    r = control_step(uni, (0.0, -0.05, 0.0), goal, neighbours=squeezed)
    goal_first = control_step(replace(uni, band_first=False), (0.0, -0.05, 0.0), goal,
                              neighbours=squeezed)
    assert r.nominal_uy < 0.0 <= goal_first.nominal_uy and r.nominal_ux < goal_first.nominal_ux


@pytest.mark.integration
def test_a_four_way_aisle_crossing_keeps_the_band_only_with_formation_keeping_first(monkeypatch):
    # A montecarlo layout (seed 1100163): four formations cross in the aisles while a forklift
    # passes. Goal-first, the rectangle squeezed among the others shears its diagonal to 2.15
    # epsilon (formation keeping first: 0.75).
    path = ROOT / "tests/scenarios/four-way-aisle-crossing.yaml"
    scenario = load_scenario(path)
    eps = scenario.controller.epsilon
    first = simulate(scenario, SimOptions(record=False)).summary
    assert first["all_reached"] and first["collisions"] == 0 and first["qp"]["fallback"] == 0
    assert first["formation_error_max_m"] <= 1.5 * eps

    # goal first; shape_push alone holds this band too (tests/test_shape.py)
    params_with(monkeypatch, band_first=False, shape_clear=False)
    before = simulate(scenario, SimOptions(record=False)).summary
    assert before["collisions"] == 0
    assert before["formation_error_max_m"] > 1.5 * eps


# ------------------------------------------------------------- giving way as one body

pos = st.floats(-3.0, 3.0)
axis = st.floats(0.2, 0.8)


def _ellipse(cx, cy, alpha, a, b, v=(0.0, 0.0)) -> Ellipse:
    return Ellipse(cx, cy, alpha, max(a, b), min(a, b), v[0], v[1])


@settings(max_examples=200, deadline=None)
@given(pos, pos, angle, axis, axis, pos, pos, angle, axis, axis, vel)
def test_only_a_formation_coming_closer_than_the_yield_range_pushes(
    x, y, al, a, b, hx, hy, hal, ha, hb, v,
):
    own = _ellipse(x, y, al, a, b)
    other = _ellipse(hx, hy, hal, ha, hb, v)
    push = yield_push(FormationView(own, 0.0, 0.0), [other])
    d = math.hypot(x - hx, y - hy)
    if d < 1e-6:
        return
    n = ((x - hx) / d, (y - hy) / d)
    v_n = v[0] * n[0] + v[1] * n[1]
    gap = d - _half_width(own, *n) - _half_width(other, *n)
    if v_n <= 0.0 or gap >= YIELD_RANGE:
        assert push == (0.0, 0.0)
    else:
        # away from it, along the line of centres, never faster than it comes
        along = push[0] * n[0] + push[1] * n[1]
        assert along >= 0.0 and abs(push[0] * n[1] - push[1] * n[0]) < 1e-12
        assert along <= v_n + 1e-12
        if gap <= 0.0:
            assert along == pytest.approx(v_n)


def test_every_member_of_a_formation_another_comes_at_gets_the_same_yield():
    own = Ellipse(0.0, 0.0, 0.0, 0.4, 0.2)
    coming = Ellipse(0.9, 0.0, 0.0, 0.4, 0.2, -0.2, 0.0)  # 0.1 m away, 0.2 m/s towards us
    view = FormationView(own, 0.0, 0.0)
    noms = []
    for member in ((-0.3, 0.1), (0.3, -0.1), (0.0, 0.15)):
        r = control_step(P, (*member, 0.0), member, others=[coming], view=view)  # at its goal
        noms.append((r.nominal_ux, r.nominal_uy))
    assert noms[0] == pytest.approx(noms[1]) and noms[0] == pytest.approx(noms[2])
    assert noms[0][0] < -0.1 and noms[0][1] == pytest.approx(0.0)
    off = replace(P, band_first=False, shape_clear=False)  # shape_push would back it off too
    r = control_step(off, (0.3, -0.1, 0.0), (0.3, -0.1), others=[coming], view=view)
    assert (r.nominal_ux, r.nominal_uy) == (0.0, 0.0)
