"""The leader's footprint routes in the agent (``controller.method: rigid``): when to plan
again is :class:`leader.routing.Replanner`'s and the tick's driving of it
:class:`leader.route_driver.RouteDriver`'s (the simulator's too); this part turns what the leader
sees into the driver's terms and runs the plan off the control tick.

Lock-step: the plan is made in the tick that asks for it (simulated time waits; the run stays
deterministic). Real time: the plan runs in a worker process (one per agent process, its leaders
share it, started with the node before the ticks, ``spawn``: nothing of the agent's threads or
sessions is copied into it; at the lowest priority, :func:`lower`, so the plan takes only the
CPU the ticks leave) and the tick goes on at once; the route is taken at the first tick
after it is done. A thread would not do: the search is Python and holds the GIL, and a 20 Hz
tick beside it ended late (docs/navigation.md).
"""

from __future__ import annotations

import atexit
import contextlib
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, wait
from multiprocessing import get_context
from typing import TYPE_CHECKING, Any

from geometry.ellipse import Ellipse, wrap_angle
from geometry.footprint_plan import PLAN_MARGIN, Body
from geometry.shapes import Shape
from leader.navigation import Follower
from leader.route_driver import RouteDriver
from leader.routing import Other, Reason, Replanner, Thing, Update
from wire.payloads import EllipseMsg, ObstacleMsg

from .body import Footprint, pose_of

if TYPE_CHECKING:
    from .config import AgentConfig

PLAN_NICE = 19  # the worker's niceness (also where the idle policy is refused)
# [s] longest wait for a new plan worker's first job (start_plan_pool): about four times what
# its imports take on a quiet core; on a busy machine, where the worker at the idle policy may
# get no CPU for long, the agent goes on without it and subscribes (a peer waits for that)
WARM_S = 2.0


class LeaderRoutes:
    """One leader's replanning (module docstring)."""

    def __init__(self, fp: Footprint, radius: float, margin: float, goal: tuple[float, float],
                 start: tuple[float, float] | None, by_hand: bool, name: str = "",
                 speed: float = math.inf, mates: frozenset[str] = frozenset()) -> None:
        self.fp = fp
        # the formations of one it plans past as robots where no way keeps off their ellipses
        # (leader.routing.round_mates): a lifelong team's members standing near their slots, to
        # a member on its way to its own
        self.mates = mates
        self.speed = speed  # [m/s] the formation's top speed (a robot's)
        self.name = name  # the formation's
        self.body = Body(fp.slots, fp.load_points, radius, PLAN_MARGIN + margin)
        self.radius = radius
        replanner = Replanner(self.body, fp.goal_turn, (goal[0], goal[1], fp.goal_turn), (),
                              start, by_hand, speed)
        replanner.last_plan = 0.0
        replanner.name = name
        replanner.mates = mates
        replanner.due = None if by_hand else Reason.START  # the first tick plans (and may find none)
        self.driver = RouteDriver(replanner, fp.goal_turn, radius)

    @property
    def replanner(self) -> Replanner:
        """The policy of the goal the formation follows now."""
        return self.driver.replanner

    def heading(self, own: Ellipse) -> float:
        """The formation's heading (the goal shape's turn) from its ellipse."""
        return wrap_angle(pose_of(own, self.fp.alpha0).theta - self.fp.goal_turn)

    def new_goal(self, goal: tuple[float, float], heading: float | None, start: tuple[float, float],
                 by_hand: bool) -> None:
        """A goal taken: plan for it at the next tick (unless its route was given)."""
        turn = self.fp.goal_turn + (heading or 0.0)
        shapes = self.replanner.shapes
        replanner = Replanner(self.body, self.fp.goal_turn, (goal[0], goal[1], turn), shapes,
                              start, by_hand, self.speed)
        replanner.name = self.name
        replanner.mates = self.mates
        replanner.due = None if by_hand else Reason.NEW_GOAL
        self.driver.replanner = replanner

    def tick(self, stamp: float, lockstep: bool, own: Ellipse, follower: Follower,
             shapes: Sequence[Shape], obstacles: Sequence[ObstacleMsg],
             others: Sequence[EllipseMsg], reports: Mapping[str, Other] | None = None
             ) -> Update | None:
        """A new route (or an order to hold) when one is ready, else None; ``reports``: the
        other formations' statuses where they are seen (:class:`leader.routing.Other`)."""
        self.replanner.shapes = tuple(shapes)
        pose = pose_of(own, self.fp.alpha0)
        seen = self.things(obstacles, others, own)
        return self.driver.tick(stamp, (pose.cx, pose.cy, pose.theta), follower, seen,
                                reports or {}, None if lockstep else submit_plan)

    def things(self, obstacles: Sequence[ObstacleMsg], others: Sequence[EllipseMsg],
                own: Ellipse) -> list[Thing]:
        static = self.driver.look((o.id, o.vx, o.vy) for o in obstacles)
        out = [Thing(f"obstacle/{o.id}", o.x, o.y, math.hypot(o.vx, o.vy), o.ds, o.id in static,
                     o.vx, o.vy) for o in obstacles]
        out += [Thing(f"formation/{e.formation}", e.cx, e.cy, math.hypot(e.vx, e.vy),
                      e.a + self.radius) for e in others
                if math.dist((e.cx, e.cy), (own.cx, own.cy)) > 1e-9]
        return out

    def close(self) -> None:
        """This leader's plan in progress is dropped (the process's worker stays for others)."""
        self.driver.close()


_POOL: list[ProcessPoolExecutor] = []  # this process's plan worker, once started
ORPHAN_POLL_S = 1.0  # [s] how often the plan worker looks whether its agent is still there


def lower(pid: int) -> None:
    """Process ``pid`` (0: this one) at the lowest priority: niceness :data:`PLAN_NICE` and the
    kernel's idle policy (``SCHED_IDLE``) where it is granted. Niceness 19 alone still gets
    slices of a CPU that a waking tick then waits behind, and a fleet's leaders all plan at
    their first ticks, while each worker is still importing its modules: with fewer cores than
    busy processes, the ticks of a run's first seconds came late. Under the idle policy a
    waking tick takes the worker's CPU at once, and the kernel counts a CPU that runs only the
    worker as free when it places a waking thread; the worker still gets a small share of a
    busy CPU, so a plan is late, never lost."""
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, pid, PLAN_NICE)
    idle = getattr(os, "SCHED_IDLE", None)
    if idle is not None:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(pid, idle, os.sched_param(0))


def _worker_start(parent: int) -> None:
    """The plan worker's start: the lowest priority, and an exit once the agent that started it
    is gone. A killed agent's worker would otherwise wait on its job queue for ever (it holds
    the queue's write end itself, so it never reads an end of file)."""
    lower(0)
    threading.Thread(target=_exit_with, args=(parent,), name="orphan-watch", daemon=True).start()


def _exit_with(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(ORPHAN_POLL_S)
    os._exit(0)  # nothing to save: a plan in progress is for the agent that is gone


def submit_plan(fn: Callable[[Any], Any], arg: Any) -> Future[Any]:
    """Run ``fn(arg)`` on this process's plan worker (:func:`plan_pool`)."""
    return plan_pool().submit(fn, arg)


def plan_pool() -> ProcessPoolExecutor:
    """This process's plan worker (an agent host's leaders share one; their plans queue), started
    at its first use at the lowest priority from its birth: a worker's interpreter start and
    imports cost about a third of a CPU second, which a fleet's leaders starting together would
    take from the ticks at niceness 0 (``formation bench --fleets`` shows the missed ticks)."""
    if not _POOL:
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, ())
        pool = ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn"),
                                   initializer=_worker_start, initargs=(os.getpid(),))
        pool.submit(int)  # starts the process now, so it can be lowered before its imports
        # multiprocessing's resource tracker unblocks SIGINT and SIGTERM in the calling thread;
        # the agent takes them on its signal thread only (agent.__main__.SignalWatch): block again
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for pid in getattr(pool, "_processes", None) or ():  # the executor's own table
            lower(pid)
        atexit.register(pool.shutdown, wait=False, cancel_futures=True)
        _POOL.append(pool)
    return _POOL[0]


def may_plan(cfg: AgentConfig) -> bool:
    """Whether the agent of ``cfg`` may plan routes: a leader, its standby or a fleet robot
    (each leads a formation of one) of method rigid with the planner on."""
    return cfg.planner and cfg.footprint is not None and (
        cfg.leader is not None or cfg.standby is not None or cfg.lifelong is not None)


def start_plan_pool(cfgs: Sequence[AgentConfig], lockstep: bool) -> None:
    """Start the process's plan worker before its agents tick, where one of them may plan in
    real time (:func:`may_plan`; lock-step plans on the tick's thread), and wait up to
    :data:`WARM_S` for it to have run a first job: its interpreter and imports, and
    multiprocessing's resource tracker, are then behind the agents on a quiet machine, not
    inside a fleet's first ticks as when the worker is born at a leader's first plan."""
    if not lockstep and any(may_plan(c) for c in cfgs):
        wait([plan_pool().submit(int)], timeout=WARM_S)


def close_plan_pool() -> None:
    """The agent is stopping: its plan worker's queued plans are cancelled and the worker is
    killed (a plan in progress is for the agent that is going). Left to Python's exit, the
    executor's own exit hook waits for the worker's current job, which at niceness 19 on a busy
    CPU takes as long as the CPU is busy: an agent given SIGTERM would outlive the signal's
    bounded shutdown."""
    while _POOL:
        pool = _POOL.pop()
        workers = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in workers:
            with contextlib.suppress(OSError, ValueError):
                proc.kill()
