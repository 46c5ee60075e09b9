"""A roster to a team's formation (leader.team)."""

from __future__ import annotations

import math

import pytest
from numpy.testing import assert_allclose

from leader.team import (
    at_slots,
    carry_goals,
    carry_reach,
    load_pose,
    plan_team,
    pose_error,
    rectangle,
    slot_points,
    team_edges,
    to_load,
    to_world,
)

SLOTS = ((-0.3, -0.15), (0.3, -0.15), (0.3, 0.15), (-0.3, 0.15))


def test_world_and_load_frames_are_inverse():
    pose = (2.0, -1.0, 0.7)
    p = to_world(pose, (0.4, -0.2))
    assert_allclose(to_load(pose, p), (0.4, -0.2), atol=1e-12)


def test_every_pair_of_slots_gets_an_edge_at_its_distance():
    edges = team_edges(["a", "b", "c", "d"], SLOTS)
    assert len(edges) == 6
    assert ("a", "c", math.dist(SLOTS[0], SLOTS[2])) in edges


def test_the_first_slot_leads_and_the_second_succeeds():
    plan = plan_team("o1", ["r3", "r1"], SLOTS[:2], rectangle((0.8, 0.4)),
                     slot_points((0, 0, 0), SLOTS[:2]), ((0, 0, 0), (5, 0, 0)))
    assert plan.leader == "r3" and plan.successor == "r1"


def test_members_reaching_their_goals_set_the_load_down_at_the_destination():
    src, dst = (1.0, 2.0, 0.3), (-4.0, 3.0, 1.9)
    starts = [(x + 0.01 * k, y - 0.02) for k, (x, y) in enumerate(slot_points(src, SLOTS))]
    goals = carry_goals(starts, src, dst)
    d, a = pose_error(load_pose(starts, goals, src), dst)
    assert d < 1e-9 and a < 1e-9


def test_the_outline_is_centred_on_the_members_start_centroid():
    src = (3.0, 1.0, math.pi / 2)
    starts = slot_points(src, SLOTS)
    plan = plan_team("o1", ["a", "b", "c", "d"], SLOTS, rectangle((0.8, 0.4)), starts,
                     (src, src))
    assert_allclose([sum(p[0] for p in plan.outline), sum(p[1] for p in plan.outline)],
                    [0.0, 0.0], atol=1e-12)
    assert_allclose(sorted(abs(p[0]) for p in plan.outline), [0.2] * 4, atol=1e-12)


def test_members_are_at_their_slots_only_within_tolerance_and_facing():
    slots = slot_points((0, 0, 0), SLOTS[:2])
    assert at_slots(slots, [None, None], slots, 0.05, 0.0, 0.05)
    assert not at_slots([(slots[0][0] + 0.1, slots[0][1]), slots[1]], [None, None], slots, 0.05,
                        0.0, 0.05)
    assert at_slots(slots, [math.pi, 0.01], slots, 0.05, 0.0, 0.05)  # either end
    assert not at_slots(slots, [0.5, 0.0], slots, 0.05, 0.0, 0.05)


def test_a_unicycle_member_turned_since_its_shape_was_taken_is_within_reach_of_its_goal():
    # the formation holds control points in the shape they had facing east; at the end each
    # member faces another way, its control point where the rigid carry puts it
    lookahead, tol = 0.05, 0.05
    plan = plan_team("o1", ("a", "b", "c", "d"), SLOTS, rectangle((0.8, 0.4)),
                     slot_points((0.0, 0.0, 0.0), SLOTS), ((0.0, 0.0, 0.0), (3.0, 1.0, 0.0)))
    reach = carry_reach(tol, lookahead)
    for heading in (math.pi / 2, math.pi, -2.0):
        bodies = [(gx + lookahead * (1.0 - math.cos(heading)), gy - lookahead * math.sin(heading))
                  for gx, gy in plan.goals]
        off = [math.dist(b, g) for b, g in zip(bodies, plan.goals, strict=True)]
        assert max(off) > tol  # the goal tolerance alone would keep the team short for good
        assert max(off) <= reach


def test_a_holonomic_member_reaches_its_goal_within_the_goal_tolerance_alone():
    assert carry_reach(0.05, 0.0) == 0.05  # exactly: holonomic teams set down as before
    assert carry_reach(0.05, 0.05) == pytest.approx(0.15)
