"""Issue 13, the shape: static obstacles stay out of a formation's ellipse, and a formation does
not press into another faster than that one moves away (agent.control.shape_push, the
formation-level barrier on the motion all members share). Only the nominal changes: every
obstacle, separation, formation and inter-formation row is the same."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from rules_off import params_with

from agent.barriers import Obstacle
from agent.control import (
    SHAPE_RANGE,
    ControlParams,
    FormationView,
    _gap,
    control_step,
    shape_push,
)
from geometry.ellipse import Ellipse, ellipse_terms, ellipse_value
from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate

ROOT = Path(__file__).resolve().parents[1]
P = ControlParams(tiebreak=False, gamma_obstacle=0.8, gamma_formations=0.5)
DT = 0.05

pos = st.floats(-2.0, 2.0)
angle = st.floats(-math.pi, math.pi)
axis = st.floats(0.2, 0.9)
speed = st.floats(-0.22, 0.22)
vel = st.tuples(speed, speed)


def _ellipse(cx, cy, alpha, a, b, v=(0.0, 0.0)) -> Ellipse:
    return Ellipse(cx, cy, alpha, max(a, b), min(a, b), v[0], v[1])


def _far_goal(own: Ellipse, bearing: float) -> FormationView:
    """A view whose goal lies 20 m off (nothing here is inside the goal shape)."""
    return FormationView(own, own.cx + 20.0 * math.cos(bearing), own.cy + 20.0 * math.sin(bearing))


# ------------------------------------------------------------- static obstacles


@settings(max_examples=300, deadline=None)
@given(pos, pos, angle, axis, axis, st.lists(st.tuples(pos, pos), min_size=1, max_size=3),
       vel, angle)
def test_the_shared_motion_never_brings_a_static_obstacle_into_the_shape_faster_than_the_barrier_allows(
    x, y, alpha, a, b, centres, w, bearing,
):
    own = _ellipse(x, y, alpha, a, b)
    obstacles = [Obstacle(ox, oy, 0.0, 0.0, 0.35) for ox, oy in centres]
    assume(all(ellipse_value(own, o.x, o.y) >= 0.0 for o in obstacles))  # outside now
    dx, dy = shape_push(P, _far_goal(own, bearing), obstacles, [], w)
    ux, uy = w[0] + dx, w[1] + dy
    for o in obstacles:
        h = ellipse_value(own, o.x, o.y)
        # h of eq. 4.6 is convex in the centre, so one step at (ux, uy) keeps at least the
        # first-order value: h_next >= (1 - gamma dt) h >= 0, the obstacle stays outside.
        moved = own._replace(cx=own.cx + ux * DT, cy=own.cy + uy * DT)
        if math.hypot(o.x - own.cx, o.y - own.cy) <= own.a + SHAPE_RANGE:
            assert ellipse_value(moved, o.x, o.y) >= (1.0 - P.gamma_obstacle * DT) * h - 1e-9
        assert ellipse_value(moved, o.x, o.y) >= -1e-9


@settings(max_examples=300, deadline=None)
@given(pos, pos, angle, axis, axis, pos, pos, vel, angle)
def test_the_correction_is_zero_when_the_shared_motion_already_keeps_the_obstacle_out(
    x, y, alpha, a, b, ox, oy, w, bearing,
):
    own = _ellipse(x, y, alpha, a, b)
    h, gx, gy, _ = ellipse_terms(ox, oy, own.cx, own.cy, own.alpha, own.a, own.b)
    obstacle = Obstacle(ox, oy, 0.0, 0.0, 0.35)
    push = shape_push(P, _far_goal(own, bearing), [obstacle], [], w)
    if gx * w[0] + gy * w[1] <= P.gamma_obstacle * h:
        assert push == pytest.approx((0.0, 0.0), abs=1e-12)
    else:  # the smallest change: along the barrier's gradient only
        assert abs(push[0] * gy - push[1] * gx) <= 1e-9 * math.hypot(gx, gy)


@settings(max_examples=200, deadline=None)
@given(pos, pos, angle, axis, axis, pos, pos, vel, st.floats(0.02, 0.3), angle)
def test_moving_obstacles_and_obstacles_the_goal_shape_holds_are_left_to_the_other_rules(
    x, y, alpha, a, b, ox, oy, w, v, heading,
):
    own = _ellipse(x, y, alpha, a, b)
    moving = Obstacle(ox, oy, v * math.cos(heading), v * math.sin(heading), 0.35)
    assert shape_push(P, _far_goal(own, 0.0), [moving], [], w) == (0.0, 0.0)
    held = Obstacle(ox, oy, 0.0, 0.0, 0.35)
    at_goal = FormationView(own, ox, oy)  # the goal shape is centred on the obstacle
    assert shape_push(P, at_goal, [held], [], w) == (0.0, 0.0)


# ------------------------------------------------------------- other formations


@settings(max_examples=300, deadline=None)
@given(pos, pos, angle, axis, axis, pos, pos, angle, axis, axis, vel, vel, angle)
def test_a_formation_never_closes_on_another_faster_than_it_moves_away_and_the_barrier_allows(
    x, y, al, a, b, hx, hy, hal, ha, hb, v, w, bearing,
):
    own = _ellipse(x, y, al, a, b)
    other = _ellipse(hx, hy, hal, ha, hb, v)
    view = _far_goal(own, bearing)
    d = math.hypot(hx - x, hy - y)
    assume(d > 1e-6)
    n = ((hx - x) / d, (hy - y) / d)
    gap = _gap(own, other)
    assert gap == pytest.approx(_gap(other, own))  # both sides see the same gap
    dx, dy = shape_push(P, view, [], [other], w)
    ux, uy = w[0] + dx, w[1] + dy
    closing = ux * n[0] + uy * n[1] - (v[0] * n[0] + v[1] * n[1])
    if gap <= SHAPE_RANGE:
        assert closing <= P.gamma_formations * gap + 1e-9
    else:
        assert (dx, dy) == (0.0, 0.0)


def test_a_formation_does_not_press_into_one_that_cannot_give_way_but_slides_past_it():
    own = Ellipse(0.0, 0.0, 0.0, 0.6, 0.45)
    stuck = Ellipse(1.3, 0.0, 0.0, 0.6, 0.45)  # 0.1 m ahead, still
    w = (0.22, 0.05)
    dx, dy = shape_push(P, FormationView(own, 10.0, 0.0), [], [stuck], w)
    assert w[0] + dx == pytest.approx(P.gamma_formations * 0.1)  # approach slows to gamma gap
    assert w[1] + dy == pytest.approx(0.05)  # the sideways part is kept
    leaving = stuck._replace(vx=0.2)  # it moves away: we may follow as fast
    assert shape_push(P, FormationView(own, 10.0, 0.0), [], [leaving], w) == (0.0, 0.0)
    parked_by_goal = FormationView(own, 0.9, 0.0)  # our goal shape reaches into it
    assert shape_push(P, parked_by_goal, [], [stuck], w) == (0.0, 0.0)
    coming = stuck._replace(vx=-0.05)  # a formation coming at us is not left out by our goal
    dx, _ = shape_push(P, parked_by_goal, [], [coming], w)
    assert w[0] + dx == pytest.approx(-0.05 + P.gamma_formations * 0.1)


# ------------------------------------------------------------- one vector for all members


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.02, 0.02),
                          st.floats(-0.02, 0.02)), min_size=2, max_size=4),
       st.floats(-1.2, 1.2), st.floats(-1.2, 1.2), angle, vel)
def test_every_member_gets_the_same_correction(members, ox, oy, al, v):
    own = Ellipse(0.0, 0.0, al, 0.6, 0.45, v[0], v[1])
    obstacle = Obstacle(ox, oy, 0.0, 0.0, 0.35)
    other = Ellipse(1.4 * math.cos(al + 1.0), 1.4 * math.sin(al + 1.0), 0.0, 0.5, 0.4, -v[0], -v[1])
    view = FormationView(own, 0.01, -0.02)
    off = replace(P, shape_clear=False)
    changes = []
    for x, y, gx, gy in members:
        goal = (x + gx, y + gy)  # close to its goal: eq. 4.2 stays inside the speed limit
        on = control_step(P, (x, y, 0.0), goal, obstacles=[obstacle], view=view, hazards=[other])
        bare = control_step(off, (x, y, 0.0), goal, obstacles=[obstacle], view=view, hazards=[other])
        assume(math.hypot(on.nominal_ux, on.nominal_uy) < P.max_speed - 1e-9)
        changes.append((on.nominal_ux - bare.nominal_ux, on.nominal_uy - bare.nominal_uy))
    for c in changes[1:]:
        assert c == pytest.approx(changes[0], abs=1e-12)


# ------------------------------------------------------------- scenarios, with and without


def _without_shape_push(monkeypatch):
    params_with(monkeypatch, shape_clear=False)


def _run(name: str, record: bool = False):
    scenario = load_scenario(ROOT / "tests/scenarios" / f"{name}.yaml")
    return scenario, simulate(scenario, SimOptions(record=record))


def _deepest_static_obstacle(result) -> float:
    """The smallest h of eq. 4.6 of any static obstacle's centre against any formation's ellipse."""
    static = [o.center for o in result.scenario.obstacles if o.velocity == (0.0, 0.0)]
    return min(ellipse_value(Ellipse(*e[2:]), *c) for e in result.series.ellipses for c in static)


def _good(summary: dict, eps: float) -> None:
    assert summary["all_reached"] and summary["collisions"] == 0, summary
    assert summary["qp"]["fallback"] == 0 and summary["hard_row_unmet_ticks"] == 0
    assert summary["formation_error_max_m"] <= 1.5 * eps


@pytest.mark.integration
def test_a_unicycle_rectangle_pushed_onto_a_round_shelf_keeps_it_out_of_its_shape_only_with_shape_push(
    monkeypatch,
):
    """Without shape_push the rectangle closes round shelf-s5 (the shelf's centre inside its
    ellipse) and its band breaks (before the unicycle edges were measured on the bodies it also
    stood there for good: deadlock, 4.15 epsilon); with it no shelf ever enters the shape."""
    scenario, with_rule = _run("shelf-pushed-unicycle", record=True)
    _good(with_rule.summary, scenario.controller.epsilon)
    assert _deepest_static_obstacle(with_rule) >= 0.0  # no shelf ever inside a formation's ellipse
    _without_shape_push(monkeypatch)
    _, bare = _run("shelf-pushed-unicycle", record=True)
    assert _deepest_static_obstacle(bare) < 0.0  # closed round shelf-s5
    assert bare.summary["formation_error_max_m"] > 1.5 * scenario.controller.epsilon


@pytest.mark.integration
def test_a_rectangle_pushed_onto_a_round_shelf_keeps_its_band_only_with_shape_push(monkeypatch):
    scenario, with_rule = _run("shelf-pushed")
    _good(with_rule.summary, scenario.controller.epsilon)
    _without_shape_push(monkeypatch)
    _, bare = _run("shelf-pushed")
    assert bare.summary["formation_error_max_m"] > 1.5 * scenario.controller.epsilon


@pytest.mark.integration
def test_a_rectangle_squeezed_from_two_sides_keeps_its_band_only_with_shape_push(monkeypatch):
    scenario, with_rule = _run("squeeze-crossing")
    _good(with_rule.summary, scenario.controller.epsilon)
    _without_shape_push(monkeypatch)
    _, bare = _run("squeeze-crossing")
    assert bare.summary["formation_error_max_m"] > 1.5 * scenario.controller.epsilon
    assert bare.summary["qp"]["fallback"] > 0
