"""The control step: commands satisfy the rows they were built from; the tie-break rule."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent import barriers
from agent.barriers import Neighbour, Obstacle
from agent.control import (
    Controller,
    ControlParams,
    FormationView,
    StepInput,
    build_rows,
    nominal,
    shape_rows,
    tiebreak_push,
)
from agent.qp import STATUS_OK, STATUS_RELAXED
from geometry import shapes
from leader.ellipse import Ellipse

coord = st.floats(-2, 2)


@settings(max_examples=300, deadline=None)
@given(coord, coord, st.floats(-math.pi, math.pi), coord, coord,
       st.lists(st.tuples(coord, coord, st.floats(-0.2, 0.2), st.floats(-0.2, 0.2)), max_size=3),
       st.lists(st.tuples(coord, coord, st.floats(0.1, 0.5)), max_size=3),
       st.booleans())
def test_every_command_satisfies_every_row_it_was_given(x, y, th, gx, gy, nbrs, obs, uni):
    p = ControlParams(unicycle=uni)
    neighbours = [Neighbour(nx, ny, vx, vy, 0.5) for nx, ny, vx, vy in nbrs
                  if math.hypot(nx - x, ny - y) > 0.1]
    obstacles = [Obstacle(ox, oy, 0.0, 0.0, ds) for ox, oy, ds in obs]
    others = [Ellipse(1.5, -1.0, 0.3, 0.6, 0.3, 0.05, 0.0, 0.1)]
    inp = StepInput((x, y, th), (gx, gy), neighbours, obstacles, others)
    res = Controller(p).step(inp)
    rows = build_rows(p, (res.px, res.py), th, (res.nominal_ux, res.nominal_uy), inp)
    u = (res.ux, res.uy)
    viol = lambda rs, s=0.0: max((ax * u[0] + ay * u[1] - b - s for ax, ay, b in rs), default=-1)  # noqa: E731
    if res.status in (STATUS_OK, STATUS_RELAXED):
        assert viol(rows.limits + rows.hard + list(rows.contact)) <= 1e-8
        assert viol(rows.soft, res.slack) <= 1e-8
    else:  # least-risk command: the limits still hold
        assert viol(rows.limits) <= 1e-8
    if uni:
        assert abs(res.v) <= p.max_speed + 1e-8 and abs(res.omega) <= p.max_turn_rate + 1e-6
    else:
        assert math.hypot(*u) <= p.max_speed + 1e-8


def test_without_constraints_the_command_is_the_clamped_p_controller_of_eq_4_2():
    p = ControlParams()
    res = Controller(p).step(StepInput((0.0, 0.0, 0.0), (0.05, 0.02)))
    assert (res.ux, res.uy) == pytest.approx((0.1, 0.04))
    assert nominal(2.0, 0.0, 0.0, 10.0, 0.0, 0.22) == pytest.approx((0.22, 0.0))


def test_no_safety_ignores_the_barriers():
    obstacle = [Obstacle(0.4, 0.0, 0.0, 0.0, 0.3)]  # right in the way
    safe = Controller(ControlParams()).step(StepInput((0.0, 0.0, 0.0), (5.0, 0.0), obstacles=obstacle))
    unsafe = Controller(ControlParams(safety=False)).step(
        StepInput((0.0, 0.0, 0.0), (5.0, 0.0), obstacles=obstacle))
    assert unsafe.ux == pytest.approx(0.22) and unsafe.status == "nominal"
    assert safe.ux < unsafe.ux


def view(cx, cy, gx, gy, vx=0.0, vy=0.0, alpha=0.0):
    return FormationView(Ellipse(cx, cy, alpha, 0.6, 0.3, vx, vy, 0.0), gx, gy)


def test_formations_meeting_head_on_both_keep_right():
    a = view(-1.5, 0.0, 5.0, 0.0, vx=0.2)
    b = view(1.5, 0.0, -5.0, 0.0, vx=-0.2)
    pa = tiebreak_push(a, [b.own], [], 0.22)
    pb = tiebreak_push(b, [a.own], [], 0.22)
    assert pa[1] < 0 and abs(pa[0]) < 1e-12  # A moves +x: right is -y
    assert pb[1] > 0 and abs(pb[0]) < 1e-12  # B moves -x: right is +y


def test_slightly_offset_formations_move_apart_not_across():
    a = view(-1.5, 0.0, 5.0, 0.0)
    b = view(1.5, 0.2, -5.0, 0.2)
    pa = tiebreak_push(a, [b.own], [], 0.22)
    pb = tiebreak_push(b, [a.own], [], 0.22)
    assert pa[1] < 0 < pb[1]  # A (below) goes down, B (above) goes up


def test_crossing_formations_turn_right_of_their_relative_motion():
    a = view(-1.5, 0.0, 5.0, 0.0, vx=0.22)  # heading +x
    b = view(0.0, -1.5, 0.0, 5.0, vy=0.22)  # heading +y, on a collision course
    pa = tiebreak_push(a, [b.own], [], 0.22)
    pb = tiebreak_push(b, [a.own], [], 0.22)
    # Relative motion of A w.r.t. B is along (1, -1): its right is (-1, -1) (A yields, passes
    # behind); B's relative motion is (-1, 1), right is (1, 1) (B goes ahead).
    assert pa[0] < 0 and pa[1] < 0 and pb[0] > 0 and pb[1] > 0


def test_every_member_gets_the_same_push_and_far_hazards_none():
    a = view(0.0, 0.0, 5.0, 0.0)
    obstacle = Obstacle(1.5, 0.1, 0.0, 0.0, 0.3)
    push = tiebreak_push(a, [], [obstacle], 0.22)
    assert push[1] < 0  # obstacle slightly left of the path: go right
    far = Obstacle(1.5, 3.0, 0.0, 0.0, 0.3)
    assert tiebreak_push(a, [], [far], 0.22) == (0.0, 0.0)
    behind = Obstacle(-1.5, 0.0, 0.0, 0.0, 0.3)
    assert tiebreak_push(a, [], [behind], 0.22) == (0.0, 0.0)


def test_a_formation_past_the_waypoint_weighs_by_its_reach_before_it_and_an_obstacle_whole():
    # A heads for a waypoint 0.5 m ahead; B (reach 0.6) sits just off A's path, its centre
    # moved from before the waypoint to past it by its whole reach. Near the waypoint a step
    # sideways turns the goal direction, so past it the side chosen flips back and forth
    # (route-head-on-aisle: 32 reversals); it now weighs by the part of it before the waypoint.
    a = view(0.0, 0.0, 0.5, 0.0)
    pushes = [tiebreak_push(a, [view(x, -0.02, -5.0, 0.0).own], [], 0.22)[1]
              for x in (0.4, 0.5, 0.65, 0.8, 0.95, 1.09, 1.11)]
    assert pushes[0] == pytest.approx(pushes[1]) and pushes[1] < 0  # before it: whole, keep right
    assert pushes[1] < pushes[2] < pushes[3] < pushes[4] < pushes[5] < 0  # fading, no jump
    assert pushes[5] > 0.05 * pushes[1] and pushes[6] == 0.0
    for x in (0.5, 0.95):  # an obstacle (a shelf's circle) there keeps its whole weight
        obstacle = Obstacle(x, -0.02, 0.0, 0.0, 0.6)
        assert tiebreak_push(a, [], [obstacle], 0.22)[1] == pytest.approx(pushes[1])


def test_a_still_formation_away_from_its_target_yields_after_the_stall_time():
    from agent.control import TUNING, Stall, update_stall

    jammed = view(0.0, 0.0, 5.0, 0.0)  # centroid velocity 0, target 5 m away
    s = Stall()
    ticks = 0
    while s.yielding == 0.0 and ticks < 1000:
        s = update_stall(s, jammed, 0.05)
        ticks += 1
    assert abs(ticks * 0.05 - TUNING.stall.time) <= 0.05 + 1e-9
    assert s.yielding == pytest.approx(TUNING.stall.yield_time)
    moving = view(0.0, 0.0, 5.0, 0.0, vx=0.2)
    assert update_stall(Stall(3.0), moving, 0.05).still == 0.0
    at_target = view(4.95, 0.0, 5.0, 0.0)
    assert update_stall(Stall(3.99), at_target, 0.05) == Stall(0.0, 0.0)


def test_only_the_formation_without_priority_yields_and_it_eases_off_at_the_end():
    from agent.control import TUNING, yield_command

    a = view(0.0, 0.0, 5.0, 0.0)._replace(name="A", other_names=("B",), yielding=TUNING.stall.yield_time)
    b = view(1.5, 0.0, -5.0, 0.0)._replace(name="B", other_names=("A",), yielding=TUNING.stall.yield_time)
    assert yield_command(a, [b.own], 0.22) is None  # A has priority: keeps going
    back = yield_command(b, [a.own], 0.22)
    assert back == pytest.approx((TUNING.stall.yield_gain * 0.22, 0.0))  # B backs away from A (+x)
    # over the last yield_ease seconds the backing slows to nothing: no instant turn back
    ease = TUNING.stall.yield_ease
    easing = [yield_command(b._replace(yielding=left), [a.own], 0.22)[0]
              for left in (ease, 0.75 * ease, 0.5 * ease, 0.01)]
    assert easing == sorted(easing, reverse=True) and easing[-1] < 0.02 * back[0]
    far = view(9.0, 0.0, -5.0, 0.0)._replace(name="B", other_names=("A",), yielding=TUNING.stall.yield_time)
    assert yield_command(far, [a.own], 0.22) is None


def test_unicycles_keep_a_sampling_margin_around_obstacles_and_integrators_none():
    uni = ControlParams(unicycle=True, lookahead=0.05, max_turn_rate=2.84, period=0.05,
                        gamma_obstacle=1.0)
    assert uni.sampling_margin == pytest.approx(0.5 * 0.05 * 2.84 ** 2 * 0.05)
    assert ControlParams(unicycle=False).sampling_margin == 0.0
    obstacle = [Obstacle(1.0, 0.0, 0.0, 0.0, 0.3)]
    rows = build_rows(uni, (0.0, 0.0), 0.0, (0.2, 0.0), StepInput(obstacles=obstacle))
    expected = 1.0 - (0.3 + 0.05 + uni.sampling_margin)  # distance to the grown circle
    assert math.sqrt(rows.h_obstacle + (0.3 + 0.05 + uni.sampling_margin) ** 2) == pytest.approx(1.0)
    assert expected > 0


_coord = st.floats(-5.0, 5.0)


@st.composite
def _shapes(draw):
    out = []
    for k in range(draw(st.integers(1, 8))):
        if draw(st.booleans()):
            out.append(shapes.segment(f"w{k}", (draw(_coord), draw(_coord)),
                                      (draw(_coord), draw(_coord)), draw(st.floats(0.1, 0.5))))
        else:
            out.append(shapes.box(f"b{k}", (draw(_coord), draw(_coord)),
                                  (draw(st.floats(0.01, 6.0)), draw(st.floats(0.01, 2.0))),
                                  draw(st.floats(-math.pi, math.pi)), draw(st.floats(0.1, 0.5))))
    return out


@settings(max_examples=300, deadline=None)
@given(_shapes(), _coord, _coord, st.floats(0.1, 2.0), st.floats(0.0, 0.1), st.floats(0.01, 1.0))
def test_wall_and_shelf_rows_skip_only_what_measuring_everything_would_not_change(
        shs, px, py, gamma, grow, reach):
    # the bounding circles only skip work: the same rows, in the same order, and the same
    # smallest h as measuring every shape
    rows: list = []
    hmin = shape_rows(px, py, shs, gamma, grow, reach, rows)
    every = [barriers.shape_row(px, py, sh, gamma, grow) for sh in shs]
    assert hmin == min(h for h, _ in every)
    assert rows == [row for _, row in every if row[2] < reach]
