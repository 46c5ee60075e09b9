"""When a fleet robot's team counts a member lost (agent.errand): on positive knowledge of its
death (its liveliness token gone) from the first tick without its state of the tick before, or
after SILENT_S of silence; a member merely late is waited for. And where a robot known dead
stands for the other leaders (agent.leader_step.Deaths): the camera's newest pose of it, as a
formation of one at rest."""

from __future__ import annotations

import math
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from agent.errand import (
    FAILED,
    RELEASED,
    SILENT_S,
    Errand,
    ErrandSettings,
    Job,
    Seen,
    lost,
)
from agent.leader_step import Deaths
from leader.team import slot_points
from scenario import load_scenario
from wire.payloads import Pose

PALLET = Path(__file__).resolve().parent / "scenarios" / "lifelong" / "one-pallet-si.yaml"
DT = 0.05
LIMIT = round(SILENT_S / DT)


def job() -> Job:
    life = load_scenario(PALLET).lifelong
    assert life is not None
    kind = life.load_type("pallet")
    src, dst = life.station("dock").pose, life.station("rack").pose
    return Job("o1", "o1", kind, ("r1", "r2", "r3", "r4"), slot_points(src, kind.slots), src, dst, 1)


def errand(dead: set[str]) -> Errand:
    return Errand("r1", ErrandSettings(lift_ticks=5, lost_ticks=LIMIT, repeat_ticks=20,
                                       goal_tolerance=0.03, tick_s=DT), dead=dead.__contains__)


def mates(j: Job, k: int, late: dict[str, int]) -> dict[str, Seen]:
    """Every teammate of ``j`` but r1 at its slot, last heard at tick ``k - 1`` or, for those
    in ``late``, at that tick."""
    return {r: Seen(*s, late.get(r, k - 1)) for r, s in zip(j.robots, j.slots, strict=True)
            if r != "r1"}


def test_a_known_dead_teammate_is_lost_at_the_first_tick_without_its_state_of_the_tick_before(
        ) -> None:
    j = job()
    dead: set[str] = set()
    e = errand(dead)
    e.take(j, 0)
    far = (9.0, 9.0)  # r1 on its way to its slot: the team gathers
    e.step(1, far, mates(j, 1, {}))
    dead.add("r3")  # its token went while its state of tick 9 was its last
    move = e.step(10, far, mates(j, 10, {"r3": 9}))
    assert e.job is not None and not e.lost  # it still has its state of the tick before
    move = e.step(11, far, mates(j, 11, {"r3": 9}))
    assert move.done and move.status is not None
    assert (move.status.state, move.status.reason) == (RELEASED, "member lost: r3")


def test_a_live_teammate_late_by_seconds_is_waited_for_and_one_silent_past_the_limit_is_lost(
        ) -> None:
    j = job()
    e = errand(set())
    e.take(j, 0)
    far = (9.0, 9.0)  # r1 on its way to its slot: the team gathers
    k = 5 * round(1.0 / DT)  # five seconds late: it was lost after one second before
    move = e.step(k, far, mates(j, k, {"r2": 0}))
    assert e.job is not None and not e.lost and not move.done
    move = e.step(LIMIT + 1, far, mates(j, LIMIT + 1, {"r2": 0}))
    assert move.done and e.lost == {"r2"}


def test_after_the_lift_a_known_dead_member_fails_the_order_at_once() -> None:
    j = job()
    dead: set[str] = set()
    e = errand(dead)
    e.take(j, 0)
    k = 1
    while e.plan is None and k < 100:  # at the slots: the lift, then the team forms
        e.step(k, j.slots[0], mates(j, k, {}))
        k += 1
    assert e.plan is not None
    dead.add("r4")
    e.step(k, j.slots[0], mates(j, k, {"r4": k - 1}))
    move = e.step(k + 1, j.slots[0], mates(j, k + 1, {"r4": k - 1}))
    assert move.status is not None and (move.status.state, move.status.reason) == (
        FAILED, "member lost: r4")


@given(k=st.integers(1, 10_000), age=st.integers(0, 10_000), since=st.integers(0, 10_000),
       dead=st.booleans())
def test_lost_is_death_known_with_no_state_of_the_tick_before_or_silence_past_the_limit(
        k: int, age: int, since: int, dead: bool) -> None:
    seen = Seen(0.0, 0.0, k - 1 - age)
    quiet = k - max(seen.k, since)
    assert lost(k, seen, since, LIMIT, dead) == ((dead and age > 0) or quiet > LIMIT)
    assert lost(k, None, since, LIMIT, dead) == (dead or k - since > LIMIT)


def test_a_robot_known_dead_stands_at_the_cameras_newest_pose_of_it_as_a_formation_of_one(
        ) -> None:
    deaths = Deaths("r1", ("r1", "r2", "r3"), "warehouse", axes=(0.4, 0.3, 0.0), offset=0.05)
    deaths.see_pose("r2", Pose(1.0, 2.0, math.pi / 2, 3.0))
    assert deaths.body("r2") is None  # alive: its pose is nobody's business here
    deaths.hear("r2", alive=False)
    deaths.see_pose("r2", Pose(1.0, 2.0, math.pi / 2, 3.0))
    deaths.see_pose("r2", Pose(9.0, 9.0, 0.0, 2.0))  # older: kept out
    body = deaths.body("r2")
    assert body is not None and body.formation == "r2"
    assert (body.cx, body.cy) == (1.0 + 0.05 * math.cos(math.pi / 2), 2.05)  # its control point
    assert (body.a, body.b, body.vx, body.vy, body.alpha_rate, body.stamp) == (
        0.4, 0.3, 0.0, 0.0, 0.0, 3.0)
    deaths.hear("r2", alive=True)  # a restarted agent: the ordinary rules again
    assert deaths.body("r2") is None and not deaths.gone("r2")
