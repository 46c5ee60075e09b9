"""The leader's goal handling (Navigator) and every member's route walk (Follower)."""

from __future__ import annotations

import math

import pytest

from geometry.route import ROUTE_MARGIN
from geometry.shapes import box, path_clearance
from leader.navigation import SAME_GOAL, Follower, Navigator
from wire.navigation import GoalMsg, PlanMsg

REF = {"a1": (0.25, 0.0), "a2": (-0.25, 0.0)}
SHELF = box("shelf", (2.0, 0.0), (0.6, 2.0), 0.0, 0.15)


def navigator(**kw) -> Navigator:
    return Navigator("A", "a1", REF, (0.0, 0.0), **kw)


def test_a_goal_with_a_heading_turns_the_goal_shape_and_gives_each_member_its_goal():
    nav = navigator()
    assert nav.accept(GoalMsg("A", 4.0, 1.0, math.pi / 2, (), 1.0), 1.0, (0.0, 0.0), []) is None
    plan = nav.plan(1.5)
    assert plan.goal_stamp == 1.0 and (plan.cx, plan.cy) == (4.0, 1.0) and plan.heading == math.pi / 2
    assert plan.goal_of("a1") == pytest.approx((4.0, 1.25))
    assert plan.goal_of("a2") == pytest.approx((4.0, 0.75))
    assert plan.route == ((4.0, 1.0),)  # nothing in the way
    # no heading: the shape keeps its last heading
    assert nav.accept(GoalMsg("A", 0.0, 0.0, None, (), 2.0), 2.0, (4.0, 1.0), []) is None
    assert nav.plan(2.0).goal_of("a1") == pytest.approx((0.0, 0.25))


def test_the_leader_routes_around_shelves_from_where_the_formation_is():
    nav = navigator()
    assert nav.accept(GoalMsg("A", 4.0, 0.0, None, (), 1.0), 1.0, (0.0, 0.0), [SHELF]) is None
    route = nav.plan(1.0).route
    assert len(route) > 1 and route[-1] == (4.0, 0.0)
    pts = [(0.0, 0.0), *route]
    for a, b in zip(pts, pts[1:], strict=False):
        assert path_clearance(a, b, SHELF) >= SHELF.ds + 0.25 + ROUTE_MARGIN - 1e-9
    # given waypoints are used as they are; planning off goes straight
    assert nav.accept(GoalMsg("A", 4.0, 0.0, None, ((2.0, 2.0),), 2.0), 2.0, (0.0, 0.0), [SHELF]) is None
    assert nav.plan(2.0).route == ((2.0, 2.0), (4.0, 0.0))
    off = navigator(planner=False)
    assert off.accept(GoalMsg("A", 4.0, 0.0, None, (), 1.0), 1.0, (0.0, 0.0), [SHELF]) is None
    assert off.plan(1.0).route == ((4.0, 0.0),)


@pytest.mark.parametrize("goal, why", [
    (GoalMsg("B", 4.0, 0.0, None, (), 1.0), "not 'A'"),
    (GoalMsg("A", 2.0, 0.0, None, (), 1.0), "within the safe distance of box 'shelf'"),
    (GoalMsg("A", 2.0, 1.3, math.pi / 2, (), 1.0), "goal of 'a2' lies within the safe distance"),
    (GoalMsg("A", 4.0, 0.0, None, ((2.0, 0.5),), 1.0), "waypoint 0 lies within"),
])
def test_goals_inside_a_shape_or_for_another_formation_are_refused_and_counted(goal, why):
    nav = navigator()
    assert why in nav.accept(goal, 1.0, (0.0, 0.0), [SHELF])
    assert nav.rejected == 1 and nav.goal == (0.0, 0.0)


def test_an_older_goal_never_replaces_a_newer_one():
    nav = navigator()
    assert nav.accept(GoalMsg("A", 4.0, 0.0, None, (), 5.0), 5.0, (0.0, 0.0), []) is None
    assert "not newer" in nav.accept(GoalMsg("A", 1.0, 0.0, None, (), 4.0), 4.0, (0.0, 0.0), [])
    assert nav.goal == (4.0, 0.0)


def test_a_follower_adopts_only_newer_plans_naming_it_and_walks_the_route():
    f = Follower("a2", (1.0, 0.0), (1.25, 0.0))
    assert f.step(0.0, 0.0) == ((1.0, 0.0), (1.25, 0.0))  # the scenario's goal
    plan = PlanMsg("A", 3.0, 4.0, 0.0, None, ((2.0, 2.0), (4.0, 0.0)), (("a1", 4.25, 0.0), ("a2", 3.75, 0.0)),
                   3.0)
    assert f.adopt(plan)
    assert not f.adopt(plan)  # the same goal again: nothing changes
    assert not f.adopt(PlanMsg("A", 9.0, 0.0, 0.0, None, ((0.0, 0.0),), (("a1", 0.0, 0.0),), 9.0))
    assert f.step(0.0, 0.0) == ((1.75, 2.0), (2.0, 2.0))  # waypoint + offset
    assert f.step(2.0, 2.05) == ((3.75, 0.0), (4.0, 0.0))  # at the waypoint: the last leg, own goal


def test_status_says_moving_reached_stalled_or_stopped_with_the_distance_to_go():
    nav = navigator()
    nav.accept(GoalMsg("A", 4.0, 0.0, None, ((2.0, 2.0),), 1.0), 1.0, (0.0, 0.0), [])
    f = Follower("a1", (0.25, 0.0), (0.0, 0.0))
    f.adopt(nav.plan(1.0))
    f.step(0.0, 0.0)
    s = nav.status(f, (0.0, 0.0), stalled=False, stopped=False, stamp=2.0)
    assert (s.state, s.waypoint, s.waypoints, s.wx, s.wy) == ("moving", 0, 2, 2.0, 2.0)
    assert s.distance == pytest.approx(2 * math.sqrt(8.0))
    assert s.goal_stamp == 1.0 and (s.gx, s.gy) == (4.0, 0.0) and s.leader == "a1"
    assert nav.status(f, (0.0, 0.0), True, False, 2.0).state == "stalled"
    assert nav.status(f, (0.0, 0.0), True, True, 2.0).state == "stopped"
    f.step(2.0, 2.0)
    f.step(4.0, 0.01)
    assert nav.status(f, (4.0, 0.01), False, False, 3.0).state == "reached"


def test_the_same_goal_sent_again_changes_nothing_and_is_not_counted_as_refused():
    nav = navigator()
    assert nav.accept(GoalMsg("A", 4.0, 0.0, 0.3, (), 5.0), 5.0, (0.0, 0.0), [SHELF]) is None
    route = nav.route
    assert nav.accept(GoalMsg("A", 4.0, 0.0, None, (), 6.0), 6.0, (1.0, 1.0), [SHELF]) == SAME_GOAL
    assert nav.accept(GoalMsg("A", 4.0, 0.0, 0.3, (), 7.0), 7.0, (1.0, 1.0), [SHELF]) == SAME_GOAL
    assert nav.goal_stamp == 5.0 and nav.route == route and nav.rejected == 0
    assert nav.accept(GoalMsg("A", 4.0, 0.0, 0.6, (), 8.0), 8.0, (1.0, 1.0), [SHELF]) is None


def test_real_time_goal_stamps_far_ahead_or_stale_are_refused():
    from agent.navigation import GOAL_FUTURE_S, GOAL_MAX_AGE_S, stamp_problem

    assert stamp_problem(100.0, 100.0) is None
    assert stamp_problem(100.0 + GOAL_FUTURE_S * 0.5, 100.0) is None
    assert "in the future" in stamp_problem(100.0 + GOAL_FUTURE_S + 0.1, 100.0)
    assert "ago" in stamp_problem(100.0 - GOAL_MAX_AGE_S - 0.1, 100.0)


def test_a_refused_goal_put_again_is_counted_once_and_a_new_one_again():
    nav = navigator()
    inside = GoalMsg("A", 2.0, 0.0, None, (), 1.0)  # inside the shelf's safe distance
    for _ in range(3):  # formation goal puts it again each second until the status shows it
        assert "safe distance" in nav.accept(inside, 1.0, (0.0, 0.0), [SHELF])
    assert nav.rejected == 1
    again = GoalMsg("A", 2.0, 0.0, None, (), 2.0)  # the same place asked anew: a new goal
    assert nav.accept(again, 2.0, (0.0, 0.0), [SHELF]) is not None
    assert nav.rejected == 2
