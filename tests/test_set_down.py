"""The set-down's judgement (agent.errand.arrived): a team is judged on where its load is and on
where it comes to rest, the speaker standing still from the judging tick and the other members
moving on through the set-down; a still team is judged on where it stands."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from agent.errand import (
    CARRYING,
    SET_DOWN_RAD,
    SETTING_DOWN,
    Errand,
    ErrandSettings,
    Job,
    Seen,
    arrived,
    per_tick,
    rest_points,
)
from leader.team import Point, Pose, TeamPlan, load_pose, plan_team, pose_error, slot_points
from scenario import load_scenario

SLOTS = ((-0.4, -0.3), (0.4, -0.3), (0.4, 0.3), (-0.4, 0.3))  # a pallet's four corners
OUTLINE = ((-0.5, -0.4), (0.5, -0.4), (0.5, 0.4), (-0.5, 0.4))
DST = (5.0, 2.0, math.pi / 2)
LIFT = 40  # [ticks] a set-down's
REACH = 0.15  # [m] a unicycle member's reach of its goal (goal tolerance plus twice 5 cm)


def team() -> TeamPlan:
    """Four members that lifted the load at the origin (their slots) to set it down at DST."""
    return plan_team("o1", ("r1", "r2", "r3", "r4"), SLOTS, OUTLINE, SLOTS,
                     ((0.0, 0.0, 0.0), DST))


def turned(plan: TeamPlan, deg: float) -> list[Point]:
    """The members at their goals turned by ``deg`` about the station's centre."""
    return turned_about(plan.goals, DST, deg)


def turned_about(points: Sequence[Point], centre: Pose, deg: float) -> list[Point]:
    """``points`` turned by ``deg`` about ``centre``'s position."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return [(centre[0] + c * (x - centre[0]) - s * (y - centre[1]),
             centre[1] + s * (x - centre[0]) + c * (y - centre[1])) for x, y in points]


def still(n: int) -> list[Point]:
    return [(0.0, 0.0)] * n


def judged(plan: TeamPlan, at: list[Point], steps: list[Point]) -> bool:
    return arrived(plan, at, steps, (0.0, 0.0, 0.0), DST, REACH, LIFT)


def test_a_still_team_is_judged_on_where_its_load_stands() -> None:
    plan = team()
    assert judged(plan, list(plan.goals), still(4))
    assert judged(plan, turned(plan, 2.5), still(4))
    assert not judged(plan, turned(plan, 3.5), still(4))  # past the 3 degrees: not yet


def test_a_turning_team_whose_load_is_within_the_tolerance_now_but_rests_past_it_has_not_arrived(
) -> None:
    plan = team()
    now, then = turned(plan, 2.5), turned(plan, 2.45)  # a twentieth of a degree a tick
    steps = [per_tick(p, q, 1) for p, q in zip(now, then, strict=True)]
    load = load_pose(plan.starts, now, (0.0, 0.0, 0.0))
    assert pose_error(load, DST)[1] < SET_DOWN_RAD  # within the tolerance where it is
    turns = [pose_error(load_pose(plan.starts, c, (0.0, 0.0, 0.0)), DST)[1]
             for c in rest_points(now, steps, LIFT)]
    assert max(turns) > SET_DOWN_RAD  # and past it where it may come to rest
    assert not judged(plan, now, steps)
    # the same team turning back towards the station's heading rests within it: arrived
    back = [(-dx, -dy) for dx, dy in steps]
    assert judged(plan, now, back)


def test_a_team_whose_load_drives_on_past_the_station_has_not_arrived() -> None:
    plan = team()
    at = [(x, y - 0.04) for x, y in plan.goals]  # 4 cm short, the whole team driving on
    assert judged(plan, at, still(4))
    drive = [(0.0, 0.005)] * 4  # 10 cm/s
    assert not judged(plan, at, drive)


def test_the_speaker_moves_one_tick_more_and_each_other_member_stops_or_goes_on() -> None:
    at = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0)]
    steps = [(0.01, 0.0), (0.0, 0.01), (0.0, -0.02)]
    corners = list(rest_points(at, steps, 4))
    assert sorted(corners) == sorted([
        [(0.01, 0.0), (1.0, 0.01), (2.0, -0.02)], [(0.01, 0.0), (1.0, 0.05), (2.0, -0.02)],
        [(0.01, 0.0), (1.0, 0.01), (2.0, -0.1)], [(0.01, 0.0), (1.0, 0.05), (2.0, -0.1)]])
    assert all(c == at for c in rest_points(at, still(3), 4))  # a still team: where it stands


def test_a_team_whose_followers_go_on_while_one_stops_by_the_speaker_has_not_arrived() -> None:
    plan = team()
    at = turned(plan, 2.5)
    # the whole team drifting a little along the station's axis: all going on, it stays within
    # 3 degrees; the speaker standing and its neighbour stopping, the two others going on, the
    # load turns past them
    drift = [(0.0, 0.0008)] * 4
    going = list(rest_points(at, drift, LIFT))
    turns = [math.degrees(pose_error(load_pose(plan.starts, c, (0.0, 0.0, 0.0)), DST)[1])
             for c in going]
    assert min(turns) < 3.0 < max(turns)
    assert not judged(plan, at, drift)


def test_a_member_far_off_its_goal_has_not_arrived_whatever_its_load() -> None:
    plan = team()
    at = list(plan.goals)
    at[2] = (at[2][0] + 0.2, at[2][1])
    assert not judged(plan, at, still(4))


def test_a_teammates_motion_is_over_its_last_two_reports_and_unknown_is_standing() -> None:
    assert Seen(1.0, 2.0, 10).motion() == (0.0, 0.0)
    assert Seen(1.0, 2.0, 10, (0.9, 2.2, 9)).motion() == (1.0 - 0.9, 2.0 - 2.2)
    dx, dy = Seen(1.0, 2.0, 10, (0.8, 2.0, 8)).motion()  # a report lost between: per tick
    assert math.isclose(dx, 0.1) and dy == 0.0
    assert per_tick((1.0, 1.0), (0.0, 0.0), 0) == (0.0, 0.0)


PALLET = Path(__file__).resolve().parent / "scenarios" / "lifelong" / "one-pallet-si.yaml"


def test_a_speaker_waits_for_its_turning_team_and_sets_down_once_it_stands() -> None:
    life = load_scenario(PALLET).lifelong
    assert life is not None
    kind = life.load_type("pallet")
    src, dst = life.station("dock").pose, life.station("rack").pose
    robots = ("r1", "r2", "r3", "r4")
    job = Job("o1", "p1", kind, robots, slot_points(src, kind.slots), src, dst, 1)
    e = Errand("r1", ErrandSettings(lift_ticks=LIFT, lost_ticks=10, repeat_ticks=20,
                                    goal_tolerance=0.03, offset=0.05))
    e.take(job, 0)
    def at_slots(k: int) -> dict[str, Seen]:
        return {r: Seen(*s, k - 1) for r, s in zip(robots, job.slots, strict=True) if r != "r1"}

    for k in range(1, LIFT + 2):
        move = e.step(k, job.slots[0], at_slots(k))  # gathered, lifted: the team formed
    plan = move.team
    assert plan is not None and e.phase == CARRYING

    def tick(k: int, deg: float, was: float) -> None:
        now, then = turned_about(plan.goals, dst, deg), turned_about(plan.goals, dst, was)
        mates = {r: Seen(*p, k - 1, (*q, k - 2))
                 for r, p, q in zip(robots, now, then, strict=True) if r != "r1"}
        e.step(k, now[0], mates)

    tick(LIFT + 2, 2.45, 2.40)
    tick(LIFT + 3, 2.5, 2.45)  # within 3 degrees, turning a twentieth of a degree a tick
    assert e.phase == CARRYING
    tick(LIFT + 4, 2.5, 2.5)  # the team stands
    assert e.phase == SETTING_DOWN
