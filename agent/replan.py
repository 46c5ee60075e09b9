"""The leader's footprint routes in the agent (issue 26, ``controller.method: rigid``): when to
plan again is :class:`leader.routing.Replanner`'s; this part feeds it what the leader sees each
tick and runs the plan off the control tick.

Lock-step: the plan is made in the tick that asks for it (simulated time waits; the run stays
deterministic). Real time: the plan runs in a worker process (one per agent process, its leaders
share it, started with the node before the ticks, ``spawn``: nothing of the agent's threads or
sessions is copied into it; at the lowest priority, :data:`PLAN_NICE`, so on a busy machine the
plan waits, not the ticks) and the tick goes on at once; the route is taken at the first tick
after it is done. A thread would not do: the search is Python and holds the GIL, and a 20 Hz
tick beside it ended late (docs/navigation.md).
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import math
import os
import signal
import threading
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from multiprocessing import get_context

from geometry.ellipse import Ellipse, wrap_angle
from geometry.footprint_plan import PLAN_MARGIN, Body
from geometry.shapes import Shape
from leader.navigation import Follower
from leader.routing import (
    GIVE_WAY,
    JobResult,
    Other,
    Replanner,
    StillThings,
    Thing,
    Update,
    give_way_job,
    plan_job,
    traffic,
)
from wire.payloads import EllipseMsg, ObstacleMsg

from .body import Footprint, pose_of

logger = logging.getLogger(__name__)

PLAN_NICE = 19  # the worker's niceness: on a busy machine the ticks come first, the plan waits


class LeaderRoutes:
    """One leader's replanning (module docstring)."""

    def __init__(self, fp: Footprint, radius: float, margin: float, goal: tuple[float, float],
                 start: tuple[float, float] | None, by_hand: bool, name: str = "",
                 speed: float = math.inf) -> None:
        self.fp = fp
        self.speed = speed  # [m/s] the formation's top speed (a robot's)
        self.name = name  # the formation's
        self.body = Body(fp.slots, fp.load_points, radius, PLAN_MARGIN + margin)
        self.radius = radius
        self.replanner = Replanner(self.body, fp.goal_turn, (goal[0], goal[1], fp.goal_turn), (),
                                   start, by_hand, speed)
        self.replanner.last_plan = 0.0
        self.replanner.name = name
        self.replanner.due = "" if by_hand else "start"  # the first tick plans (and may find none)
        self.still = StillThings()
        self._first = True
        self._static: set[str] = set()
        self._job: Future | None = None
        self._why = ""

    def heading(self, own: Ellipse) -> float:
        """The formation's heading (the goal shape's turn) from its ellipse."""
        return wrap_angle(pose_of(own, self.fp.alpha0).theta - self.fp.goal_turn)

    def new_goal(self, goal: tuple[float, float], heading: float | None, start: tuple[float, float],
                 by_hand: bool) -> None:
        """A goal taken: plan for it at the next tick (unless its route was given)."""
        turn = self.fp.goal_turn + (heading or 0.0)
        shapes = self.replanner.shapes
        self.replanner = Replanner(self.body, self.fp.goal_turn, (goal[0], goal[1], turn), shapes,
                                   start, by_hand, self.speed)
        self.replanner.name = self.name
        self.replanner.due = "" if by_hand else "new goal"

    def tick(self, stamp: float, lockstep: bool, own: Ellipse, follower: Follower,
             shapes: Sequence[Shape], obstacles: Sequence[ObstacleMsg],
             others: Sequence[EllipseMsg], reports: Mapping[str, Other] | None = None
             ) -> Update | None:
        """A new route (or an order to hold) when one is ready, else None; ``reports``: the
        other formations' statuses where they are seen (:class:`leader.routing.Other`)."""
        r = self.replanner
        r.shapes = tuple(shapes)
        pose = pose_of(own, self.fp.alpha0)
        p3 = (pose.cx, pose.cy, pose.theta)
        seen = self._things(obstacles, others, own)
        things = self.still.update(stamp, seen)
        if self._first:
            r.planned, self._first = things, False
        if self._job is not None:
            return self._collect()
        want = follower.heading
        turn = 0.0 if want is None else wrap_angle(pose.theta - self.fp.goal_turn - want)
        reports = reports or {}
        why = r.check(stamp, p3, follower.route, follower.index, things, turn,
                      traffic(p3, self.body.rho, seen), reports, seen)
        if why is None:
            return None
        if why == GIVE_WAY:
            return self._give_way(stamp, lockstep, p3, things, reports)
        plan = r.job_for(stamp, p3, things, why, seen)
        if plan is None:
            return None
        if lockstep or not (plan.shapes or plan.circles or plan.lanes):  # open floor: no search
            return r.finish(plan_job(plan), why)  # lock-step, or nothing worth a worker
        self._job = plan_pool().submit(plan_job, plan)
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
        except Exception:  # noqa: BLE001 - a worker that died: keep the route, plan later
            logger.warning("a route plan failed", exc_info=True)
            return None
        if isinstance(res, JobResult):
            return self.replanner.finish(res, self._why)
        return self.replanner.finish_give_way(res, self._why)

    def _give_way(self, stamp: float, lockstep: bool, p3: tuple[float, float, float],
                  things: tuple, reports: Mapping[str, Other]) -> Update | None:
        """Stand aside for the formation :meth:`leader.routing.Replanner.give_way` names."""
        r = self.replanner
        keeper = r.give_way(stamp, reports, p3)
        aside = r.begin_give_way(stamp, p3, things, keeper, reports[keeper], self.radius)
        if lockstep:
            return r.finish_give_way(give_way_job(aside), keeper)
        self._job = plan_pool().submit(give_way_job, aside)
        self._why = keeper
        return None

    def _things(self, obstacles: Sequence[ObstacleMsg], others: Sequence[EllipseMsg],
                own: Ellipse) -> list[Thing]:
        if self._first:  # a circle still when the leader first looks is planned round at once
            self._static = {o.id for o in obstacles if o.vx == 0.0 and o.vy == 0.0}
        out = [Thing(f"obstacle/{o.id}", o.x, o.y, math.hypot(o.vx, o.vy), o.ds, o.id in self._static,
                     o.vx, o.vy) for o in obstacles]
        out += [Thing(f"formation/{e.formation}", e.cx, e.cy, math.hypot(e.vx, e.vy),
                      e.a + self.radius) for e in others
                if math.dist((e.cx, e.cy), (own.cx, own.cy)) > 1e-9]
        return out

    def close(self) -> None:
        """This leader's plan in progress is dropped (the process's worker stays for others)."""
        if self._job is not None:
            self._job.cancel()
            self._job = None


_POOL: list[ProcessPoolExecutor] = []  # this process's plan worker, once started
ORPHAN_POLL_S = 1.0  # [s] how often the plan worker looks whether its agent is still there


def _worker_start(parent: int) -> None:
    """The plan worker's start: the lowest priority, and an exit once the agent that started it
    is gone. A killed agent's worker would otherwise wait on its job queue for ever (it holds
    the queue's write end itself, so it never reads an end of file)."""
    os.nice(PLAN_NICE)
    threading.Thread(target=_exit_with, args=(parent,), name="orphan-watch", daemon=True).start()


def _exit_with(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(ORPHAN_POLL_S)
    os._exit(0)  # nothing to save: a plan in progress is for the agent that is gone


def plan_pool() -> ProcessPoolExecutor:
    """This process's plan worker (an agent host's leaders share one; their plans queue), started
    at its first use at the lowest priority from its birth: a worker's interpreter start and
    imports cost about a third of a CPU second, which a fleet's leaders starting together took
    from the ticks at niceness 0 (``formation bench --fleets``: hundreds of missed ticks)."""
    if not _POOL:
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, ())
        pool = ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn"),
                                   initializer=_worker_start, initargs=(os.getpid(),))
        pool.submit(int)  # starts the process now, so it can be lowered before its imports
        # multiprocessing's resource tracker unblocks SIGINT and SIGTERM in the calling thread;
        # the agent takes them on its signal thread only (agent.__main__.SignalWatch): block again
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for pid in getattr(pool, "_processes", None) or ():  # the executor's own table
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, pid, PLAN_NICE)
        atexit.register(pool.shutdown, wait=False, cancel_futures=True)
        _POOL.append(pool)
    return _POOL[0]


def close_plan_pool() -> None:
    """The agent is stopping: its plan worker's queued plans are cancelled and the worker is
    killed (a plan in progress is for the agent that is going). Left to Python's exit, the
    executor's own exit hook waited for the worker's current job, which at niceness 19 on a busy
    CPU took as long as the CPU was busy: an agent got SIGTERM and was still there 15 s later (a
    fresh clone's make test, load about 6), past the signal's bounded shutdown."""
    while _POOL:
        pool = _POOL.pop()
        workers = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in workers:
            with contextlib.suppress(OSError, ValueError):
                proc.kill()
