"""The simulated world of ``formation run``: the robots' bodies, the obstacles and the camera.

Each tick the world publishes ``obstacles`` and every robot's ``pose`` (the true pose with
``--camera truth``; with ``--camera synthetic`` the pose the camera service detects in a rendered
overhead frame; with ``--camera process`` it publishes only the rendered frame, and the real
camera process, :mod:`camera_service.simcam`, publishes poses and obstacles), collects every
robot's ``cmd``, integrates the kinematics exactly (single integrator, or the unicycle of eq. 6.1
through :func:`agent.unicycle.integrate`, or a double integrator's position and velocity under
its certified acceleration, :func:`agent.double_integrator.integrate`: a command without one,
or none, brakes it, :func:`agent.double_integrator.brake`) and feeds a
:class:`simulator.metrics.SafetyMonitor` with the true positions.

Two clocks:

* **lock-step** (default): publish the poses of tick k (stamped with the simulated time
  ``k * dt``), wait until every robot's command stamped ``k * dt`` has arrived (up to
  ``cmd_timeout``; a missing command is zero velocity and counted), integrate. Every command
  passes the one stamp check (:mod:`wire.stamps`) against the tick's simulated time: one stamped
  after the tick (a forged or runaway stamp) or older than the last kept is refused and counted
  (``stamp_rejected``), so it neither counts toward the step barrier nor replaces a good one;
  the barrier counts only well-formed commands stamped exactly ``k * dt``. Nothing a peer sends
  can make the world step early or wait longer than ``cmd_timeout``. Deterministic and
  as fast as the agents answer. Agents run with ``--lockstep`` and tick on pose arrival. A robot
  whose command timed out is *late*: later ticks do not wait for it until a command of its
  arrives again (a killed agent costs one timeout, then its robot just gets zero each tick).
* **real time**: integrate on the wall clock at 1/dt with the latest command of each robot (zero
  if none arrived within ``stale_after``); poses are stamped with ``time.time()``, so the delay
  from a pose's publication to the command computed from it (which carries the same stamp) is the
  end-to-end latency, recorded in ``latency_ms``. A command is applied while its *stamp* is at
  most ``stale_after`` old on the world's clock (not by when it arrived: a command computed from
  a pose delayed by a router stall is not applied); a robot without one gets zero, counted in
  ``missing_cmds`` as in lock-step. By default every pose of a tick leaves at once,
  as from one camera frame. ``pose_slots=S`` (real time, ``--camera truth``) spreads them over S
  evenly spaced slots of the period instead (robot k of N in slot ``k * S // N``), as robots
  that localise themselves on their own clocks would publish: each slot steps its own robots by
  ``dt`` and publishes their poses. On one machine this keeps N agents from all waking in the
  same instant; on robots, where each agent has its own CPU, it makes no difference.

Pose zones (:mod:`simulator.zones`, ``formation run --pose-zones Z``): given zone sessions,
each robot's pose is published, and its command taken, on its zone's session (a router its
agent connects to) instead of the world's; the obstacles stay on the world's session.

Faults (docs/faults.md): ``camera_dropouts`` stop publishing a robot's pose over a span of
simulated time, as a camera that loses that robot's marker would; ``run(on_tick=...)`` lets the
launcher kill and restart agents at given simulated times.

The time series rows (:data:`simulator.inprocess.ROBOT_COLUMNS`) hold true poses and the commands
applied; ``status``, ``slack`` and the ``h_*`` columns are not on the wire, so the world leaves
them empty (NaN) and the launcher fills them from the agents' own per-tick traces.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from agent import double_integrator, unicycle
from runtime.heap import freeze_startup
from runtime.shutdown import STEP_LIMIT_S, within
from scenario import Scenario
from wire import keys
from wire.payloads import Cmd, DecodeError, ObstacleMsg, Obstacles, Pose, decode_cmd
from wire.shapes import shape_to_msg
from wire.stamps import CLOCK_TOLERANCE_S, EPS, StampCounter, used_stamp
from wire.traffic import CountingPublisher, TrafficCounter

from .bases import RmwBase, RmwBaseReader
from .lab import LabWorld
from .metrics import SafetyMonitor
from .physics import world_for
from .series import Series, WorldResult

logger = logging.getLogger(__name__)

CAMERAS = ("truth", "synthetic", "process")
SYNTH_IMAGE = (1920, 1440)  # [px] the synthetic camera's frame
SYNTH_TILT = 0.1  # perspective tilt of the synthetic camera (far edge 10 % shorter)
SYNTH_MARKER_PX = 26.0  # [px] smallest marker side the synthetic camera must resolve
NAN = math.nan


class WorldAborted(RuntimeError):
    """The run was stopped from outside (a child crashed, Ctrl-C)."""


@dataclass(frozen=True)
class WorldOptions:
    realtime: bool = False
    camera: str = "truth"
    prefix: str = keys.DEFAULT_PREFIX
    cmd_timeout: float = 5.0  # [s] lock-step: longest wait for a tick's commands
    start_timeout: float = 60.0  # [s] longest wait for every agent to subscribe to its pose
    start_grace: float = 0.5  # [s] after every pose is matched, for the rest to propagate
    stale_after: float = 0.25  # [s] real time: an older command counts as zero
    stop_at_goal: bool = True
    record: bool = True
    camera_dropouts: tuple[tuple[str, float, float], ...] = ()  # (robot, from, until) [s]
    pose_slots: int = 1  # real time: publication slots per period (1: one camera frame)
    clock_offset: float = 0.0  # [s] real time: the camera's clock runs this far ahead of the
    # agents' (negative: behind); poses are stamped, and commands judged, on the camera's clock
    engine: str = "kinematic"  # or "mujoco": the robots are physics bodies (simulator.physics)
    # robot -> its base on rmw_zenoh (simulator.bases): commands come from there, not ``cmd``
    rmw_bases: Mapping[str, RmwBase] | None = None

    def __post_init__(self) -> None:
        self._check_clock()
        self._check_camera()
        for name in ("cmd_timeout", "start_timeout", "stale_after"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")

    def _check_clock(self) -> None:
        if isinstance(self.pose_slots, bool) or not isinstance(self.pose_slots, int) \
                or self.pose_slots < 1:
            raise ValueError(f"pose_slots: must be an integer >= 1, got {self.pose_slots!r}")
        if self.pose_slots > 1 and not (self.realtime and self.camera == "truth"):
            raise ValueError("pose_slots: more than one slot needs real time and --camera truth "
                             "(lock-step and the synthetic camera publish whole frames)")
        if not (isinstance(self.clock_offset, int | float) and math.isfinite(self.clock_offset)
                and abs(self.clock_offset) <= 10.0):
            raise ValueError(f"clock_offset: must be a number of seconds within +-10, "
                             f"got {self.clock_offset!r}")
        if self.clock_offset and not self.realtime:
            raise ValueError("clock_offset: needs real time (lock-step runs on simulated time)")

    def _check_camera(self) -> None:
        for rid, t0, t1 in self.camera_dropouts:
            if not (math.isfinite(t0) and math.isfinite(t1) and 0 <= t0 < t1):
                raise ValueError(f"camera_dropouts: {rid}: need 0 <= from < until, got {t0}, {t1}")
        if self.camera not in CAMERAS:
            raise ValueError(f"camera: {self.camera!r} is not one of {CAMERAS}")
        if self.camera == "process" and self.camera_dropouts:
            raise ValueError("camera_dropouts: not with --camera process (the real camera "
                             "process publishes the poses)")


def _undeclare(handles: Sequence[Any]) -> None:
    for h in handles:
        h.undeclare()


def step_pose(x: float, y: float, th: float, cmd: Cmd | None, dt: float, is_unicycle: bool):
    """The body pose after ``dt`` under ``cmd`` (``None``: stand still)."""
    if cmd is None:
        return x, y, th
    if is_unicycle:
        return unicycle.integrate(x, y, th, cmd.v, cmd.omega, dt)
    return x + cmd.ux * dt, y + cmd.uy * dt, th


ABORT_EVERY_S = 0.05  # [s] run(): the longest ``abort()`` is not called while waiting, and the
# shortest between two calls (a launcher's check polls every child process: at 8 pose slots and
# 32 agents, checking at every slot cost the world a fifth of its CPU)


def _at_most_every(period: float, fn: Callable[[], None]) -> Callable[[], None]:
    """``fn`` wrapped to run only when ``period`` seconds have passed since it last ran."""
    last = -math.inf

    def call() -> None:
        nonlocal last
        now = time.monotonic()
        if now - last >= period:
            last = now
            fn()

    return call


def _sleep_until(wall: float, abort: Callable[[], None]) -> None:
    """Sleep until ``time.monotonic()`` reaches ``wall``, calling ``abort()`` (which may raise)
    at least every 50 ms."""
    while True:
        abort()
        remaining = wall - time.monotonic()
        if remaining <= 0:
            return
        time.sleep(min(remaining, 0.05))


class _CmdInbox:
    """Latest command per robot, filled on Zenoh's threads, read by the world's loop."""

    def __init__(self, prefix: str, counter: TrafficCounter, robots: Sequence[str],
                 stale_after: float = 0.25) -> None:
        self._prefix = prefix
        self._counter = counter
        self.stamps = StampCounter()  # commands refused by the stamp check
        self.stale_after = stale_after
        self.realtime = False
        self.clock_offset = 0.0  # [s] real time: the camera's clock minus the wall clock
        self.now_t = 0.0  # lock-step: the simulated time of the tick under way
        self._robot_of = {keys.cmd_key(prefix, r): r for r in robots}  # cmd key -> robot
        self._cond = threading.Condition()
        self.latest: dict[str, tuple[Cmd, float]] = {}  # robot -> (cmd, local receive time)
        # robot -> its kept command's last used stamp, never later than the clock was when it
        # came (wire.stamps.used_stamp): one command stamped ahead cannot hide the later ones
        self._used: dict[str, float] = {}
        self.late: set[str] = set()  # lock-step: robots whose last command timed out
        self.malformed = 0
        self.latency_ms: list[float] = []
        self.measure_latency = False

    def callback(self, sample: zenoh.Sample) -> None:
        """The subscriber of every robot's ``cmd`` (one wildcard); other robots' are ignored."""
        key = str(sample.key_expr)
        rid = self._robot_of.get(key)
        if rid is None:
            return
        data = sample.payload.to_bytes()
        try:
            cmd = decode_cmd(data)
        except DecodeError:
            self._counter.count_recv(key, len(data))
            with self._cond:
                self.malformed += 1
            return
        self.offer(rid, cmd, key, len(data))

    def count_malformed(self) -> None:
        with self._cond:
            self.malformed += 1

    def offer(self, rid: str, cmd: Cmd, key: str, nbytes: int) -> None:
        """``rid``'s command ``cmd`` (``nbytes`` on ``key``), kept if its stamp passes."""
        self._counter.count_recv(key, nbytes)
        now = time.monotonic()
        with self._cond:
            prev = self.latest.get(rid)
            if self.realtime:
                clock, tolerance = time.time() + self.clock_offset, CLOCK_TOLERANCE_S
            else:
                clock, tolerance = self.now_t, 0.0  # only this tick's (or older) commands
            if not self.stamps.check(keys.CMD, clock, cmd.stamp,
                                     None if prev is None else self._used.get(rid, prev[0].stamp),
                                     tolerance, self.stale_after):
                return
            self._used[rid] = used_stamp(clock, cmd.stamp)
            if self.measure_latency and (prev is None or prev[0].stamp != cmd.stamp):
                self.latency_ms.append((time.time() + self.clock_offset - cmd.stamp) * 1e3)
            self.latest[rid] = (cmd, now)
            self.late.discard(rid)
            self._cond.notify_all()

    def expect(self, rid: str) -> None:
        """Lock-step: wait for ``rid``'s commands again (a restarted agent), instead of only once
        one of them arrives: the world does not run ahead of it."""
        with self._cond:
            self.late.discard(rid)

    def begin_tick(self, t: float) -> None:
        """Lock-step: the tick at simulated time ``t`` starts (before its poses go out): the
        stamp check's clock for the commands that arrive from now on."""
        with self._cond:
            self.now_t = t

    def fresh(self, now: float, max_age: float, robots: Sequence[str] | None = None) -> dict[str, Cmd]:
        """The latest command of each robot (of ``robots``; default every one heard) whose
        *stamp* is at most ``max_age`` before ``now`` (the camera's clock: ``time.time()`` plus
        the clock offset), however late it arrived."""
        with self._cond:
            if robots is None:
                return {r: c for r, (c, _rx) in self.latest.items() if now - c.stamp <= max_age}
            entries = ((r, self.latest.get(r)) for r in robots)
            return {r: e[0] for r, e in entries if e is not None and now - e[0].stamp <= max_age}

    def take_since(self, t: float, robots: Sequence[str]) -> tuple[dict[str, Cmd], list[str]]:
        """Lock-step: the commands stamped exactly ``t`` (the step barrier counts nothing else),
        and the robots of ``robots`` that sent none and were not late already (now marked
        late)."""
        with self._cond:
            got = {r: c for r, (c, _rx) in self.latest.items() if abs(c.stamp - t) <= EPS}
            late = [r for r in robots if r not in got and r not in self.late]
            self.late.update(late)
        return got, late

    def wait(self, ready: Callable[[], bool], timeout: float, abort: Callable[[], None]) -> bool:
        """Wait until ``ready()`` (checked under the lock) or the timeout; ``abort()`` is called
        between waits, outside the lock, and may raise."""
        deadline = time.monotonic() + timeout
        while True:
            with self._cond:
                if ready():
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.wait(min(remaining, 0.1))
                if ready():
                    return True
            abort()


class World:
    """The simulated world over one Zenoh session (see the module docstring)."""

    def __init__(self, scenario: Scenario, session: zenoh.Session, options: WorldOptions,
                 zones: Sequence[zenoh.Session] = (),
                 zone_of: Mapping[str, int] | None = None) -> None:
        """``zones`` (pose zones, :mod:`simulator.zones`): sessions (routers the agents of each
        zone connect to) that carry robot ``r``'s pose and command instead of ``session``:
        ``zones[zone_of[r]]``; obstacles stay on ``session``."""
        self.scenario = scenario
        self.session = session
        self.options = options
        self.lab = lab_world(scenario, options)  # None: the ideal world
        self.counter = TrafficCounter(options.prefix)
        self.ids = scenario.robot_ids
        self.formation_of = {rid: scenario.formation_of(rid).name for rid in self.ids}
        # double integrators: every robot's velocity and the acceleration it was last given
        self._vel: list[tuple[float, float]] = [(0.0, 0.0)] * len(self.ids)
        self._acc: list[tuple[float, float]] = list(self._vel)
        p = options.prefix
        for o in scenario.obstacles:
            keys.validate_id(o.name, "obstacle name")
        if zones and (zone_of is None or any(not 0 <= zone_of.get(r, -1) < len(zones)
                                             for r in self.ids)):
            raise ValueError("zones: every robot needs a zone (zone_of) among the sessions given")
        self.zones = tuple(zones)
        self.zone_of = dict(zone_of) if zones and zone_of is not None else {}
        self._pose_pubs = [CountingPublisher(self._session_of(r).declare_publisher(
            keys.pose_key(p, r)), self.counter) for r in self.ids]
        self._shape_msgs = tuple(shape_to_msg(sh) for sh in scenario.shapes)  # static walls, shelves
        self._obs_pub = CountingPublisher(session.declare_publisher(keys.obstacles_key(p)),
                                          self.counter)
        self.inbox = _CmdInbox(p, self.counter, self.ids, options.stale_after)
        self.inbox.realtime = options.realtime
        self.inbox.clock_offset = options.clock_offset
        self.result: WorldResult | None = None  # the last run's, also when it was aborted
        # one wildcard subscriber for every robot's command, called right on the Zenoh thread
        # that received it (``indirect=False``: no hand-over to a Python thread per command; the
        # callback only decodes and stores under the inbox lock). With zones, one subscriber per
        # robot on its zone's session: its command arrives there, never through another zone.
        if options.rmw_bases:
            self._subs = RmwBaseReader(options.rmw_bases, self.inbox.offer,
                                       self.inbox.count_malformed).declare(self._session_of)
        elif self.zones:
            self._subs = [self._session_of(r).declare_subscriber(
                keys.cmd_key(p, r), zenoh.handlers.Callback(self.inbox.callback, indirect=False))
                for r in self.ids]
        else:
            self._subs = [session.declare_subscriber(
                keys.all_robots_key(p, keys.CMD),
                zenoh.handlers.Callback(self.inbox.callback, indirect=False))]
        self._camera = None
        for rid, _t0, _t1 in options.camera_dropouts:
            if rid not in self.ids:
                raise ValueError(f"camera_dropouts: unknown robot {rid!r}")
        self.camera_dropped = 0
        if options.camera == "synthetic":
            self._camera = _SyntheticCamera(scenario)
        self.frames = None  # --camera process: frames out, the camera process does the rest
        if options.camera == "process":
            from camera_service.simcam import FramePublisher

            self.frames = FramePublisher(scenario, session, p)

    def _session_of(self, rid: str) -> zenoh.Session:
        """The session that carries ``rid``'s pose and command (its zone's, else the world's)."""
        return self.zones[self.zone_of[rid]] if self.zones else self.session

    def close(self, step_limit: float = STEP_LIMIT_S) -> None:
        """Undeclare the world's subscribers and publishers, each step waiting at most
        ``step_limit`` seconds (:func:`runtime.shutdown.within`: a hung step is logged, not waited
        for); the session is its owner's to close."""
        subs, pubs = list(self._subs), [*self._pose_pubs, self._obs_pub]
        within(step_limit, f"world: undeclaring {len(subs)} subscribers", lambda: _undeclare(subs))
        within(step_limit, f"world: undeclaring {len(pubs)} publishers", lambda: _undeclare(pubs))
        self._subs.clear()
        self._pose_pubs.clear()
        if self.frames is not None:
            self.frames.undeclare()

    def wait_for_agents(self, abort: Callable[[], None] = lambda: None,
                        robots: Sequence[str] | None = None, grace: bool = True) -> None:
        """Wait until every robot's (or each of ``robots``') pose has a subscriber (the agent
        declares it last)."""
        deadline = time.monotonic() + self.options.start_timeout
        if self.frames is not None:
            self.frames.wait_subscribed(self.options.start_timeout, abort)
        for rid, pub in zip(self.ids, self._pose_pubs, strict=True):
            if robots is not None and rid not in robots:
                continue
            while not pub.publisher.matching_status.matching:  # type: ignore[attr-defined]
                abort()
                if time.monotonic() > deadline:
                    raise TimeoutError(f"agent {rid} did not subscribe to its pose within "
                                       f"{self.options.start_timeout} s")
                time.sleep(0.02)
        if grace:
            time.sleep(self.options.start_grace)

    def wait_unsubscribed(self, rid: str, timeout: float = 5.0) -> bool:
        """Wait until nothing subscribes to ``rid``'s pose (its agent is gone); False if the
        timeout passed first."""
        pub = self._pose_pubs[self.ids.index(rid)]
        deadline = time.monotonic() + timeout
        while pub.publisher.matching_status.matching:  # type: ignore[attr-defined]
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    # --- the loop ----------------------------------------------------------------------------

    def run(  # noqa: C901 (15: the lock-step and real-time loop; to split into a tick object next)
        self,
        progress: Callable[[int, int, float], None] | None = None,
        abort: Callable[[], None] = lambda: None,
        on_tick: Callable[[int, float], None] | None = None,
        stop: Callable[[], bool] = lambda: False,
        started: Callable[[], None] | None = None,
    ) -> WorldResult:
        """Run the scenario; ``abort()`` is called while waiting and may raise to stop;
        ``started()`` once the run can keep what it measured (a Ctrl-C from then on still
        leaves a result: ``formation run`` writes its endpoint file there);
        ``on_tick(k, t)`` before the poses of tick ``k`` (simulated time ``t``) are published;
        ``stop()`` True ends the run after the tick in progress (``formation run --hold``)."""
        sc = self.scenario
        opts = self.options
        abort = _at_most_every(ABORT_EVERY_S, abort)
        dt = sc.dt
        off = sc.robot.control_offset
        state: list[tuple[float, float, float]] = [
            (r.start[0], r.start[1], r.start[2]) for r in sc.robots]
        self._vel = [(0.0, 0.0)] * len(state)  # double integrators: at rest at the start
        self._acc = [(0.0, 0.0)] * len(state)
        monitor = SafetyMonitor(sc)
        series = Series()
        inbox = self.inbox
        inbox.measure_latency = opts.realtime
        freeze_startup()  # no full collection of start-up's objects mid-run (runtime.heap)
        counts = _Counts()
        stamps: list[float] = []
        robot_stamps: list[list[float]] = []
        publish_ms: list[float] = []
        wall0 = time.monotonic()
        monitor.update(0.0, np.array([s[:2] for s in state]),
                       [o.position(0.0) for o in sc.obstacles])
        k = 0
        t = 0.0
        next_wall = time.monotonic()

        def settle(k: int, t_done: float, done: list | None, cmds: list, t_now: float,
                   now: list) -> bool:
            """Record the period that began at ``t_done`` in state ``done`` (None: none ended),
            check the state ``now`` at ``t_now``, report progress; True to stop."""
            if done is not None:
                if opts.record:
                    self._record(series, t_done, done, cmds, off)
                monitor.update(t_now, np.array([s[:2] for s in now]),
                               [o.position(t_now) for o in sc.obstacles])
            if progress is not None:
                progress(k + 1, sc.steps, t_now)
            return (opts.stop_at_goal and monitor.all_reached) or stop()

        def result(steps: int, sim_time: float) -> WorldResult:
            return WorldResult(
                steps=steps, sim_time=sim_time, monitor=monitor, series=series,
                traffic=self.counter.snapshot(), missing_cmds=counts.missing,
                zero_cmds=counts.zero, cmd_timeouts=counts.timeouts,
                camera_dropped=self.camera_dropped, malformed_cmds=inbox.malformed,
                stamp_rejected=inbox.stamps.snapshot(), clock_offset=opts.clock_offset,
                latency_ms=list(inbox.latency_ms), wall_s=time.monotonic() - wall0, stamps=stamps,
                robot_stamps=robot_stamps, publish_ms=publish_ms,
                physics={} if self.lab is None else self.lab.summary_fields(),
            )

        try:
            if started is not None:
                started()
            for k in range(sc.steps):
                t = k * dt
                if on_tick is not None:
                    on_tick(k, t)
                if opts.pose_slots > 1:
                    # each slot steps its robots over the previous period, then publishes them: the
                    # same rows and checks as below, one period later
                    stamps.append(time.time() + opts.clock_offset)
                    before = state
                    state, cmds = self._publish_slots(k, state, next_wall, abort, robot_stamps)
                    next_wall += dt
                    if k > 0:  # tick 0 only publishes: nothing was applied
                        counts.applied(cmds)
                    if settle(k, t - dt, before if k > 0 else None, cmds, t, state):
                        break
                    continue
                stamp = time.time() + opts.clock_offset if opts.realtime else t
                stamps.append(stamp)
                if not opts.realtime:
                    inbox.begin_tick(t)  # before the poses: no command for t exists yet
                self._publish(t, stamp, state)
                if opts.realtime:
                    publish_ms.append((time.time() + opts.clock_offset - stamp) * 1e3)
                    next_wall += dt
                    _sleep_until(next_wall, abort)
                    # judged by the command's stamp, not by its arrival
                    got = inbox.fresh(time.time() + opts.clock_offset, opts.stale_after)
                else:
                    got = self._lockstep_commands(k, t, abort, counts)
                cmds = [got.get(r) for r in self.ids]
                counts.applied(cmds)  # no command (either clock): zero velocity, counted
                before = state
                state = self._step(state, cmds)
                t = (k + 1) * dt
                if settle(k, k * dt, before, cmds, t, state):
                    break
        except BaseException:
            # aborted (a child died, Ctrl-C): what was measured over the ticks completed
            self.result = result(k, k * dt)
            raise
        self._last_commands_in(opts.realtime, dt)
        self.result = result(k + 1, t)
        return self.result

    @staticmethod
    def _last_commands_in(realtime: bool, dt: float) -> None:
        """Real time: give the commands computed from the last frame's poses their period to
        arrive before the run's latencies are taken (with pose slots, the last slot's poses went
        out a fraction of a period before the end, and their commands counted as missed)."""
        if realtime:
            time.sleep(dt)

    def _lockstep_commands(self, k: int, t: float, abort: Callable[[], None],
                           counts: _Counts) -> dict[str, Cmd]:
        """Lock-step: wait (up to ``cmd_timeout``) for every robot's command of tick ``k``
        stamped ``t`` (robots late since a timeout not waited for); the commands that came."""
        inbox = self.inbox

        def ready() -> bool:
            return all(r in inbox.latest and abs(inbox.latest[r][0].stamp - t) <= EPS
                       for r in self.ids if r not in inbox.late)

        if not inbox.wait(ready, self.options.cmd_timeout, abort):
            counts.timeouts += 1
        got, late = inbox.take_since(t, self.ids)
        if late:
            logger.info("tick %d: no command from %s in time: zero", k, ", ".join(late))
        return got

    def _publish_slots(self, k: int, state: Sequence[tuple[float, float, float]], start: float,
                       abort: Callable[[], None], robot_stamps: list[list[float]],
                       ) -> tuple[list, list[Cmd | None]]:
        """Real time with ``pose_slots`` > 1, tick ``k``, starting at wall time ``start``: in
        slot s (robots i with ``i * slots // n == s``), step those robots by ``dt`` with their
        latest command (not at ``k == 0``: the start poses go out as they are), then publish
        their poses. Returns at the period's end with the new state and the commands applied;
        appends the stamp each robot's pose went out with to ``robot_stamps`` (the agents' traces
        are keyed by it)."""
        opts = self.options
        dt = self.scenario.dt
        t = k * dt
        n, slots = len(state), opts.pose_slots
        inbox = self.inbox
        new = list(state)
        cmds: list[Cmd | None] = [None] * n
        is_uni = self.scenario.robot.is_unicycle
        sent = [math.nan] * n
        robot_stamps.append(sent)
        for s in range(slots):
            _sleep_until(start + s * dt / slots, abort)
            mine = range(-(-s * n // slots), -(-(s + 1) * n // slots))
            stamp = time.time() + opts.clock_offset  # the camera's clock
            fresh = inbox.fresh(stamp, opts.stale_after, [self.ids[i] for i in mine])
            for i in mine:
                cmds[i] = fresh.get(self.ids[i])
            if s == 0:
                self._publish_obstacles(t, stamp)
            for i in mine:
                if k > 0:
                    new[i] = self._pose_after(i, new[i], cmds[i], is_uni)
                sent[i] = stamp
                self._publish_pose(i, t, stamp, new[i])
        _sleep_until(start + dt, abort)
        return new, cmds

    def _step(self, state: Sequence[tuple[float, float, float]],
              cmds: Sequence[Cmd | None]) -> list[tuple[float, float, float]]:
        """Every robot's pose one period on: exact kinematics (:func:`step_pose`), or the lab's
        wheels (:mod:`simulator.lab`)."""
        is_uni = self.scenario.robot.is_unicycle
        if self.lab is None:
            return [self._pose_after(i, s, c, is_uni)
                    for i, (s, c) in enumerate(zip(state, cmds, strict=True))]
        return self.lab.move(state, [None if c is None else (c.ux, c.uy, c.v, c.omega)
                                     for c in cmds])

    def _pose_after(self, i: int, s: tuple[float, float, float], cmd: Cmd | None,
                    is_uni: bool) -> tuple[float, float, float]:
        """Robot ``i``'s body pose one period on from ``s`` under ``cmd`` (:func:`step_pose`);
        a double integrator's velocity moves on with it."""
        dt, robot = self.scenario.dt, self.scenario.robot
        if not robot.is_double_integrator:
            return step_pose(*s, cmd, dt, is_uni)
        vx, vy = self._vel[i]
        if cmd is not None and cmd.ax is not None and cmd.ay is not None:
            a = (cmd.ax, cmd.ay)
        else:  # a zero command (version 1) or none: brake
            a = double_integrator.brake(vx, vy, robot.max_accel or math.inf, dt)
        x, y, vx, vy = double_integrator.integrate(s[0], s[1], vx, vy, a[0], a[1], dt,
                                                   robot.max_speed)
        self._vel[i], self._acc[i] = (vx, vy), a
        return x, y, s[2]

    def _publish_obstacles(self, t: float, stamp: float) -> list[ObstacleMsg]:
        obs = []
        seen = [o.position(t) for o in self.scenario.obstacles] if self.lab is None \
            else self.lab.obstacles(round(t / self.scenario.dt))
        for o, (x, y) in zip(self.scenario.obstacles, seen, strict=True):
            vx, vy = o.velocity_at(t)
            obs.append(ObstacleMsg(o.name, x, y, vx, vy, o.safe_distance))
        self._obs_pub.put_message(Obstacles(stamp, tuple(obs), self._shape_msgs))
        return obs

    def _publish_pose(self, i: int, t: float, stamp: float, p: tuple[float, float, float]) -> None:
        """Publish robot ``i``'s pose, unless its camera dropout covers ``t`` (counted)."""
        rid = self.ids[i]
        if any(r == rid and t0 <= t + 1e-9 < t1 for r, t0, t1 in self.options.camera_dropouts):
            self.camera_dropped += 1
            return
        self._pose_pubs[i].put_message(Pose(p[0], p[1], p[2], stamp))

    def _publish(self, t: float, stamp: float, state: Sequence[tuple[float, float, float]]) -> None:
        if self.frames is not None:  # the camera process publishes poses and obstacles
            self.frames.publish(state, [(o.name, *o.position(t), o.safe_distance)
                                        for o in self.scenario.obstacles], stamp)
            return
        obs = self._publish_obstacles(t, stamp)
        if self._camera is not None:
            seen = self._camera.poses(state, [(m.x, m.y, m.ds) for m in obs], stamp)
        else:
            poses = state if self.lab is None else self.lab.sense(round(t / self.scenario.dt), state)
            seen = {rid: s for rid, s in zip(self.ids, poses, strict=True)}
        for i, rid in enumerate(self.ids):
            p = seen.get(rid)
            if p is not None:  # an undetected marker publishes nothing: the agent sees it stale
                self._publish_pose(i, t, stamp, p)

    def _record(self, series: Series, t: float, state, cmds, off: float) -> None:
        for rid, s, c in zip(self.ids, state, cmds, strict=True):
            px, py = unicycle.control_point(s[0], s[1], s[2], off)
            ux, uy, v, w = (0.0, 0.0, 0.0, 0.0) if c is None else (c.ux, c.uy, c.v, c.omega)
            series.robots.append((t, rid, self.formation_of[rid], s[0], s[1], s[2], px, py,
                                  ux, uy, v, w, "", NAN, NAN, NAN, NAN) + self._accel_cells(rid))
        for o in self.scenario.obstacles:
            x, y = o.position(t)
            series.obstacles.append((t, o.name, x, y, o.safe_distance))


    def _accel_cells(self, rid: str) -> tuple[float, ...]:
        """robots.csv's ``ax, ay`` (double integrators only): the acceleration the robot was
        given over the period just recorded."""
        if not self.scenario.robot.is_double_integrator:
            return ()
        return self._acc[self.ids.index(rid)]


def lab_world(scenario: Scenario, options: WorldOptions) -> LabWorld | None:
    """The lab world of ``scenario`` (None: ideal and kinematic), or its physics world with
    ``options.engine`` "mujoco" (:func:`simulator.physics.world_for`). Its camera replaces
    ``--camera truth``; the synthetic and process cameras render the true poses, so only the
    lab's wheels apply there. Lab worlds publish whole frames (pose slots are for robots that
    localise themselves)."""
    world = world_for(scenario, options.engine)
    if world is not None and options.pose_slots > 1:
        raise ValueError(f"pose_slots: not in the {scenario.world.profile} world (its camera "
                         "publishes whole frames)")
    return world


class _SyntheticCamera:
    """Render an overhead frame of the true poses and detect the markers back (camera_service).

    The camera sees the scenario's floor (every start, goal and static obstacle, plus 1 m) in a
    SYNTH_IMAGE frame with a mild perspective tilt; each robot carries ArUco marker k (its index
    in the scenario), sized to at least SYNTH_MARKER_PX pixels so the camera can resolve it.
    A marker the detector misses publishes nothing that tick (the agent sees a stale pose)."""

    def __init__(self, scenario: Scenario) -> None:
        from camera_service import CameraConfig, CameraService, synthetic_camera

        xs = [r.start[0] for r in scenario.robots] + [r.goal[0] for r in scenario.robots]
        ys = [r.start[1] for r in scenario.robots] + [r.goal[1] for r in scenario.robots]
        for o in scenario.obstacles:
            if o.velocity == (0.0, 0.0):
                xs += [o.center[0] - o.safe_distance, o.center[0] + o.safe_distance]
                ys += [o.center[1] - o.safe_distance, o.center[1] + o.safe_distance]
        arena = (min(xs) - 1.0, min(ys) - 1.0, max(xs) + 1.0, max(ys) + 1.0)
        self.calibration = synthetic_camera(image_size=SYNTH_IMAGE, arena=arena, tilt=SYNTH_TILT)
        scale = min((SYNTH_IMAGE[0] - 32) / (arena[2] - arena[0]),
                    (SYNTH_IMAGE[1] - 32) / (arena[3] - arena[1]))  # [px/m] near edge
        self.marker_side = max(0.08, SYNTH_MARKER_PX / (scale * (1.0 - SYNTH_TILT)))  # [m]
        self.marker_ids = {rid: k for k, rid in enumerate(scenario.robot_ids)}
        self.radius = scenario.robot.radius
        self.service = CameraService(CameraConfig(self.calibration, marker_ids=self.marker_ids))

    def poses(self, state, obstacles, stamp):
        from camera_service import render_aruco_frame

        truth = {rid: tuple(s) for rid, s in zip(self.marker_ids, state, strict=True)}
        frame = render_aruco_frame(truth, self.calibration, self.marker_ids, obstacles,
                                   marker_side=self.marker_side, robot_radius=self.radius)
        return {o.robot_id: (o.x, o.y, o.theta) for o in self.service.process(frame, stamp)}


# --- python -m simulator.world -----------------------------------------------------------------

def world_summary(result: WorldResult) -> dict:
    return {
        "steps": result.steps,
        "sim_time_s": round(result.sim_time, 6),
        **result.monitor.summary_fields(),
        "missing_cmds": result.missing_cmds,
        "zero_cmds": result.zero_cmds,
        "malformed_cmds": result.malformed_cmds,
        "stamp_rejected": result.stamp_rejected,
        "traffic": result.traffic,
        "wall_s": result.wall_s,
        "latency_ms": result.latency_ms,
    }


@dataclass
class _Counts:
    """What a run counts about the commands it applied."""

    missing: int = 0  # robot-ticks with no command: zero velocity
    zero: int = 0  # robot-ticks whose command was zero
    timeouts: int = 0  # lock-step waits for a tick's commands that timed out

    def applied(self, cmds: Sequence[Cmd | None]) -> None:
        self.missing += sum(c is None for c in cmds)
        self.zero += sum(_is_zero(c) for c in cmds)


def _is_zero(c: Cmd | None) -> bool:
    return c is not None and c.v == 0.0 and c.omega == 0.0 and c.ux == 0.0 and c.uy == 0.0


def main(argv: Sequence[str] | None = None) -> int:
    from runtime.lifeline import watch_parent
    from scenario import ScenarioError, load_scenario
    from wire.zconf import add_zenoh_args, open_session, settings_from_args, use_zenoh_threads

    parser = argparse.ArgumentParser(prog="python -m simulator.world",
                                     description="The simulated world of a multi-process run.")
    parser.add_argument("scenario")
    parser.add_argument("--realtime", action="store_true")
    parser.add_argument("--camera", default="truth", choices=CAMERAS)
    parser.add_argument("--summary", type=Path, default=None, help="write the result here (JSON)")
    parser.add_argument("--log-level", default="WARNING")
    add_zenoh_args(parser)
    ns = parser.parse_args(argv)
    logging.basicConfig(level=ns.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        scenario = load_scenario(ns.scenario)
        options = WorldOptions(realtime=ns.realtime, camera=ns.camera, prefix=ns.key_prefix)
        settings = settings_from_args(ns)
        settings.to_config()  # ValueError naming a setting zenoh rejects
    except (ScenarioError, ValueError) as exc:
        print(f"world: {exc}", file=sys.stderr)
        return 2
    watch_parent()  # started by a launcher: stop when it dies
    use_zenoh_threads("relay")
    try:
        session = open_session(settings, "world")  # says so when the credentials are refused
    except ConnectionError as exc:
        print(exc, file=sys.stderr)
        return 1
    with session:
        world = World(scenario, session, options)
        try:
            world.wait_for_agents()
            result = world.run()
        except (KeyboardInterrupt, TimeoutError) as exc:
            print(f"world: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 1
        finally:
            world.close()
    summary = world_summary(result)
    if ns.summary is not None:
        ns.summary.write_text(json.dumps(summary, default=float), encoding="utf-8")
    print(json.dumps({k: v for k, v in summary.items() if k not in ("traffic", "latency_ms")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
