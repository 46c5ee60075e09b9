"""The goals a run is judged against: the scenario's, or the last goal each formation was sent
at run time (``formation goal`` to a ``formation run --hold`` fleet).

A formation's leader takes a goal as its centroid and, optionally, a heading; each member's goal
is then the goal centroid plus the member's goal offset from the scenario's goal centroid,
turned by the heading when there is one (:class:`leader.navigation.Navigator`: the plan it sends
its members). The run's verdict (``all_reached``, ``time_to_goal_s``, the per-formation times)
and the goals drawn in ``trajectories.png`` use these goals, so a held run whose formations
reached the goals they were sent is judged complete.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

from leader.navigation import turn
from scenario import Scenario
from scenario.routes import goal_offsets

from .series import Series, WorldResult

Point = tuple[float, float]


def goals_sent(scenario: Scenario, followed: Mapping[str, Mapping[str, Any]],
               ) -> dict[str, dict[str, Any]]:
    """Of the goals the leaders follow (formation -> ``{"goal": [x, y], "heading": h,
    "goal_stamp": s}``, their last statuses), those sent at run time, as ``{"goal", "heading"}``:
    a goal stamped after the start, or one other than the scenario's (a lock-step leader stamps
    a goal with the tick's simulated time, which is 0 at the first tick)."""
    out: dict[str, dict[str, Any]] = {}
    for f in scenario.formations:
        got = followed.get(f.name)
        if got is None:
            continue
        goal, heading = (got["goal"][0], got["goal"][1]), got.get("heading")
        if got.get("goal_stamp", 0.0) > 0.0 or goal != f.goal_centroid or heading is not None:
            out[f.name] = {"goal": [goal[0], goal[1]], "heading": heading}
    return out


def sent_goal(goal: Point, heading: float | None, offsets: Mapping[str, Point]) -> dict[str, Point]:
    """Each member's goal for a formation sent the goal centroid ``goal`` with ``heading``
    (None: the scenario's shape as it is); ``offsets``: each member's goal offset from the goal
    centroid in the scenario."""
    turned = turn(offsets, heading) if heading is not None else offsets
    return {m: (goal[0] + ox, goal[1] + oy) for m, (ox, oy) in turned.items()}


def with_goals(scenario: Scenario, sent: Mapping[str, Mapping[str, Any]]) -> Scenario:
    """``scenario`` with each robot of a formation in ``sent`` (formation -> ``{"goal": [x, y],
    "heading": h}``, as ``goals_sent`` of summary.json holds it) at the goal its formation was
    sent; the other formations' goals as they are."""
    if not sent:
        return scenario
    formations = []
    for f in scenario.formations:
        got = sent.get(f.name)
        if got is None:
            formations.append(f)
            continue
        offsets = dict(zip(f.robot_ids, goal_offsets(f), strict=True))
        goals = sent_goal((got["goal"][0], got["goal"][1]), got.get("heading"), offsets)
        robots = tuple(dataclasses.replace(r, goal=goals[r.id]) for r in f.robots)
        formations.append(dataclasses.replace(f, robots=robots))
    return dataclasses.replace(scenario, formations=tuple(formations))


def first_at_goals(series: Series, goals: Mapping[str, Point], tolerance: float,
                   robots: Sequence[str]) -> float | None:
    """The first time in ``series`` at which every robot of ``robots`` was within ``tolerance``
    of its goal in ``goals`` (None if never)."""
    at: dict[float, set[str]] = {}
    for row in series.robots:
        t, rid, x, y = row[0], row[1], row[3], row[4]
        gx, gy = goals[rid]
        if math.hypot(x - gx, y - gy) <= tolerance:
            at.setdefault(t, set()).add(rid)
    ids = set(robots)
    return next((t for t in sorted(at) if ids <= at[t]), None)


def judge_by_goals_sent(scenario: Scenario, result: WorldResult,
                        sent: Mapping[str, Mapping[str, Any]]) -> Scenario:
    """``scenario`` with the goals ``sent`` at run time (:func:`with_goals`), and ``result``'s
    monitor judging the run against them (:meth:`simulator.metrics.SafetyMonitor.retarget`);
    ``scenario`` and ``result`` as they are when no goal was sent."""
    if not sent:
        return scenario
    judged = with_goals(scenario, sent)
    goals = {r.id: r.goal for r in judged.robots}
    first = first_at_goals(result.series, goals, judged.goal_tolerance, judged.robot_ids)
    result.monitor.retarget([goals[r] for r in judged.robot_ids], first, result.sim_time)
    return judged
