"""The one driver of a formation's replanning, shared by the agent's leader
(:class:`agent.replan.LeaderRoutes`) and the in-process simulator (:mod:`simulator.replans`).

Each tick the caller hands it what the leader sees (the formation's pose, the round things, the
other formations' reports) and the leader's follower; it keeps the still things
(:class:`leader.routing.StillThings`), asks the policy (:meth:`leader.routing.Replanner.check`)
whether to plan again, and runs the plan or the stand-aside it asks for: at once, or through
``submit`` (a worker process: the agent in real time), in which case the result is taken at the
first tick after it is done. Pure: no clock, no network, no process of its own.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future
from typing import Any

from geometry.ellipse import wrap_angle
from geometry.footprint_plan import Pose3
from leader.navigation import Follower
from leader.routing import (
    JobResult,
    Other,
    Reason,
    Replanner,
    StillThings,
    Thing,
    Update,
    give_way_job,
    plan_job,
    traffic,
)

logger = logging.getLogger(__name__)

Submit = Callable[[Callable[[Any], Any], Any], "Future[Any]"]  # runs fn(arg) elsewhere


def still_circles(circles: Iterable[tuple[str, float, float]]) -> frozenset[str]:
    """The names of the circles (name, vx, vy) that stand still: at a leader's first look these
    are its static ones (:attr:`leader.routing.Thing.static`, planned round at once). A robot
    knows only what it sees: a forklift parked before the formation exists is as still as a
    post, and one that drives at that moment counts as still only once it has stood for
    :attr:`leader.routing.Stillness.still_s` (:class:`leader.routing.StillThings`)."""
    return frozenset(name for name, vx, vy in circles if vx == 0.0 and vy == 0.0)


class RouteDriver:
    """One formation's replanning, tick by tick (module docstring)."""

    def __init__(self, replanner: Replanner, goal_turn: float, radius: float) -> None:
        self.replanner = replanner  # replaced when the formation takes a new goal
        self.goal_turn = goal_turn  # [rad] the rotation from the start shape to the goal shape
        self.radius = radius  # [m] a robot's: how far a formation standing aside keeps off
        self.still = StillThings()
        self.first = True  # no tick yet: the first one's still things count as planned round
        self.static: frozenset[str] = frozenset()  # the circles still at the first look
        self._job: Future[Any] | None = None
        self._why = Reason.START  # what the plan in progress is for
        self._keeper = ""  # or the formation it stands aside for

    def look(self, circles: Iterable[tuple[str, float, float]]) -> frozenset[str]:
        """The static circles among ``circles`` (name, vx, vy) as this tick sees them: those
        still at the formation's first look (:func:`still_circles`), kept for its life; call it
        before :meth:`tick`. Each formation has its own: one that comes into being later looks
        first then."""
        if self.first:
            self.static = still_circles(circles)
        return self.static

    def tick(self, t: float, pose: Pose3, follower: Follower, seen: Sequence[Thing],
             reports: Mapping[str, Other], submit: Submit | None = None) -> Update | None:
        """A new route (or an order to hold) when one is ready, else None. ``pose``: the
        formation's (centroid and the footprint's rotation), ``seen``: every round thing this
        tick, ``reports``: the other formations' statuses where they are seen, ``submit``: run
        the plan elsewhere (None: now)."""
        r = self.replanner
        things = self.still.update(t, seen)
        if self.first:
            r.planned, self.first = things, False
        if self._job is not None:
            return self._collect()
        want = follower.heading
        turn = 0.0 if want is None else wrap_angle(pose[2] - self.goal_turn - want)
        why = r.check(t, pose, follower.route, follower.index, things, turn,
                      traffic(pose, r.body.rho, seen), reports, seen)
        if why is None:
            return None
        if why == Reason.GIVE_WAY:
            return self._give_way(t, pose, things, reports, submit)
        plan = r.job_for(t, pose, things, why, seen)
        if plan is None:
            return None
        if submit is None or not (plan.shapes or plan.circles or plan.lanes):  # open floor: no search
            return r.finish(plan_job(plan), why)
        self._job = submit(plan_job, plan)
        self._why = why
        return None

    def _collect(self) -> Update | None:
        """The plan the worker was given, once it is done (a route, a hold, a place aside)."""
        assert self._job is not None
        if not self._job.done():
            return None
        job, self._job = self._job, None
        try:
            res = job.result()
        except Exception:  # a worker that died: keep the route, plan later
            logger.warning("a route plan failed", exc_info=True)
            return None
        if isinstance(res, JobResult):
            return self.replanner.finish(res, self._why)
        return self.replanner.finish_give_way(res, self._keeper)

    def _give_way(self, t: float, pose: Pose3, things: tuple, reports: Mapping[str, Other],
                  submit: Submit | None) -> Update | None:
        """Stand aside for the formation :meth:`leader.routing.Replanner.give_way` names."""
        r = self.replanner
        keeper = r.give_way(t, reports, pose)
        aside = r.begin_give_way(t, pose, things, keeper, reports[keeper], self.radius)
        if submit is None:
            return r.finish_give_way(give_way_job(aside), keeper)
        self._job = submit(give_way_job, aside)
        self._keeper = keeper
        return None

    def close(self) -> None:
        """The plan in progress is dropped."""
        if self._job is not None:
            self._job.cancel()
            self._job = None
