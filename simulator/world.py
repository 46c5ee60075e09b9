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
  arrives again (a killed agent costs one timeout, then its robot just gets zero each tick; one
  restarted while the world waits is not waited for at that tick, whose poses it never saw).
  The world waits longer than an agent's phases in a row (:data:`wire.stamps.LOCKSTEP_WORLD_WAIT_S`),
  so around a dead agent its neighbours give up and command first.
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

Under ``controller.localisation: fused`` the world also publishes every robot's wheel odometry
on ``robot/{id}/odom`` after each frame (:mod:`simulator.odom_out`) and stamps each pose at the
frame's capture, where the agents' filters fuse it; ``world.camera_faults`` misread, forge or
lose poses as in process (:func:`simulator.fused.apply_faults`).

A lifelong scenario (a fleet; the world's scenario is its robots as formations of one,
:func:`simulator.lifelong.fleet_base`) also has the world keep its loads
(:class:`simulator.world_loads.WorldLoads`): before each frame's poses it lets loads appear and
leave and puts every load on ``world/loads``; it hears each order's status on its own session
(the one the commands come on, so in lock-step every status a leader put before its command of
a tick is taken at that tick); once the robots moved, carried loads follow their teams. The run
ends when every order is done and the fleet manager has no more to post (``more_orders``), or at
its duration.

Faults (docs/faults.md): ``camera_dropouts`` stop publishing a robot's pose over a span of
simulated time, as a camera that loses that robot's marker would; ``run(on_tick=...)`` lets the
launcher kill and restart agents at given simulated times.

The time series rows (:data:`simulator.inprocess.ROBOT_COLUMNS`) hold true poses and the commands
applied; ``status``, ``slack`` and the ``h_*`` columns are not on the wire, so the world leaves
them empty (NaN) and the launcher fills them from the agents' own per-tick traces.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import zenoh

from runtime.heap import freeze_startup
from runtime.shutdown import STEP_LIMIT_S, within
from scenario import Scenario
from wire import keys
from wire.odom import odom_key
from wire.orders import OrderMsg, OrderStatusMsg, all_orders_key, encode_loads, read_order_message
from wire.payloads import Cmd, ObstacleMsg, Obstacles, Pose
from wire.reader import DecodeError
from wire.shapes import shape_to_msg
from wire.stamps import LOCKSTEP_WORLD_WAIT_S
from wire.traffic import CountingPublisher, TrafficCounter, in_order

from .bases import RmwBase, RmwBaseReader
from .cmd_inbox import CmdInbox
from .fused import apply_faults
from .lab import LabWorld
from .odom_out import OdomOut, capture_stamp
from .odometry import seen_by_camera
from .pacing import ABORT_EVERY_S, at_most_every, sleep_until
from .physics import world_for
from .series import WorldResult
from .synthetic_camera import SyntheticCamera
from .tick import FleetTick
from .tick import Pose as BodyPose
from .world_loads import WorldLoads

logger = logging.getLogger(__name__)

CAMERAS = ("truth", "synthetic", "process")


class WorldAborted(RuntimeError):
    """The run was stopped from outside (a child crashed, Ctrl-C)."""


@dataclass(frozen=True)
class WorldOptions:
    realtime: bool = False
    camera: str = "truth"
    prefix: str = keys.DEFAULT_PREFIX
    cmd_timeout: float = LOCKSTEP_WORLD_WAIT_S  # [s] lock-step: longest wait for a tick's commands
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
        self.tick = FleetTick(scenario, self.lab)  # the run's (run() starts a new one)
        p = options.prefix
        for o in scenario.obstacles:
            keys.validate_id(o.name, "obstacle name")
        if zones and (zone_of is None or any(not 0 <= zone_of.get(r, -1) < len(zones)
                                             for r in self.ids)):
            raise ValueError("zones: every robot needs a zone (zone_of) among the sessions given")
        self.zones = tuple(zones)
        self.zone_of = dict(zone_of) if zones and zone_of is not None else {}
        self.pose_pubs = [CountingPublisher(self._session_of(r).declare_publisher(
            keys.pose_key(p, r)), self.counter) for r in self.ids]
        self._shape_msgs = tuple(shape_to_msg(sh) for sh in scenario.shapes)  # static walls, shelves
        self.obs_pub = CountingPublisher(session.declare_publisher(keys.obstacles_key(p)),
                                         self.counter)
        self.inbox = CmdInbox(p, self.counter, self.ids, options.stale_after)
        self.inbox.realtime = options.realtime
        self.inbox.clock_offset = options.clock_offset
        self.result: WorldResult | None = None  # the last run's, also when it was aborted
        # one wildcard subscriber for every robot's command, called right on the Zenoh thread
        # that received it (``indirect=False``: no hand-over to a Python thread per command; the
        # callback only decodes and stores under the inbox lock). With zones, one subscriber per
        # robot on its zone's session: its command arrives there, never through another zone.
        if options.rmw_bases:
            self.subs = RmwBaseReader(options.rmw_bases, self.inbox.offer,
                                      self.inbox.count_malformed).declare(self._session_of)
        elif self.zones:
            self.subs = [self._session_of(r).declare_subscriber(
                keys.cmd_key(p, r), in_order(self.inbox.callback))
                for r in self.ids]
        else:
            self.subs = [session.declare_subscriber(
                keys.all_robots_key(p, keys.CMD),
                in_order(self.inbox.callback))]
        # controller.localisation fused: every robot's wheel odometry (simulator.odom_out)
        self.fused = scenario.controller.localisation == "fused"
        self.odom = OdomOut(scenario, [CountingPublisher(self._session_of(r).declare_publisher(
            odom_key(p, r)), self.counter) for r in self.ids]) if self.fused else None
        self._camera: SyntheticCamera | None = None
        for rid, _t0, _t1 in options.camera_dropouts:
            if rid not in self.ids:
                raise ValueError(f"camera_dropouts: unknown robot {rid!r}")
        self.camera_dropped = 0
        if options.camera == "synthetic":
            self._camera = SyntheticCamera(scenario)
        self.frames = None  # --camera process: frames out, the camera process does the rest
        if options.camera == "process":
            from camera_service.simcam import FramePublisher

            self.frames = FramePublisher(scenario, session, p)
        self._declare_loads(session)

    def _declare_loads(self, session: zenoh.Session) -> None:
        """A lifelong scenario's loads (module docstring): ``world/loads`` out, the orders'
        status in; the launcher sets ``more_orders`` (the fleet manager has orders to post),
        ``tally`` (told the orders delivered and posted before each progress report) and
        ``passed_on`` (told each status as the world takes it: the fleet manager's book then
        holds, at tick ``k``, every status the world took by then, as ``formation sim``'s)."""
        life = self.scenario.lifelong
        self.loads = WorldLoads(self.scenario) if life is not None else None
        self.more_orders: Callable[[], bool] = lambda: False
        self.tally: Callable[[int, int], None] | None = None
        self.passed_on: Callable[[OrderStatusMsg], None] | None = None
        self.status_dropped = 0  # malformed or forged order statuses
        self._statuses: list[OrderStatusMsg] = []
        self._status_lock = threading.Lock()
        self.loads_pub: CountingPublisher | None = None
        if self.loads is None:
            return
        p = self.options.prefix
        self.loads_pub = CountingPublisher(
            session.declare_publisher(keys.loads_key(p)), self.counter)
        self.subs.append(session.declare_subscriber(
            all_orders_key(p) + "/status",
            in_order(self._on_status)))
        # the keys fleet robots start to put or hear at run time (a team's formation keys, a
        # teammate's state) have a subscriber here from the start: a publisher that knows of no
        # subscriber sends nothing, so without one the first puts of a new leader could miss
        # the subscriptions its listeners declared a tick before (lock-step waits them out)
        for key in [keys.all_formations_key(p, kind) for kind in keys.FORMATION_CLASSES] + [
                keys.all_robots_key(p, keys.STATE)]:
            self.subs.append(session.declare_subscriber(
                key, in_order(_ignore)))

    def _on_status(self, sample: zenoh.Sample) -> None:
        """An order's status, kept for the next tick (on Zenoh's thread)."""
        if sample.kind == zenoh.SampleKind.DELETE:
            return
        key = str(sample.key_expr)
        self.counter.count_recv(key, len(sample.payload))
        try:
            msg = read_order_message(self.options.prefix, key, sample.payload.to_bytes())
        except DecodeError:
            with self._status_lock:
                self.status_dropped += 1
            return
        if isinstance(msg, OrderStatusMsg):
            self.hear(msg)

    def hear(self, msg: OrderStatusMsg) -> None:
        """An order's status from elsewhere than the wire (the fleet manager's book cancels a
        waiting order without a team to say so), taken at the next tick as one heard."""
        with self._status_lock:
            self._statuses.append(msg)

    def post_order(self, msg: OrderMsg, t: float, refused: str = "") -> None:
        """An order the fleet manager posted at ``t`` (``refused``: why it cannot be served)."""
        if self.loads is not None:
            self.loads.post(msg, t, refused)

    def _loads_out(self, t: float, stamp: float, state: Sequence[BodyPose]) -> None:
        """Before tick ``t``'s poses: loads leave and appear, and every load goes out."""
        if self.loads is None or self.loads_pub is None:
            return
        self.loads.events(t, state)
        self.loads_pub.put(encode_loads(self.loads.message(stamp)))

    def _statuses_in(self, t: float, state: Sequence[BodyPose]) -> None:
        """The orders' statuses heard by now, taken at tick ``t`` (robots at ``state``)."""
        if self.loads is None:
            return
        with self._status_lock:
            heard, self._statuses = self._statuses, []
        for msg in heard:
            self.loads.take_status(msg, t, state)
            if self.passed_on is not None:
                self.passed_on(msg)

    def _loads_after(self, t: float, state: Sequence[BodyPose]) -> None:
        """Once the robots moved to ``state`` at ``t``: carried loads follow their teams."""
        if self.loads is None:
            return
        self.loads.after(t, state, self.scenario.dt, self.tick.obstacle_positions(t))
        if self.tally is not None:
            self.tally(*self.loads.delivered())

    def _session_of(self, rid: str) -> zenoh.Session:
        """The session that carries ``rid``'s pose and command (its zone's, else the world's)."""
        return self.zones[self.zone_of[rid]] if self.zones else self.session

    def close(self, step_limit: float = STEP_LIMIT_S) -> None:
        """Undeclare the world's subscribers and publishers, each step waiting at most
        ``step_limit`` seconds (:func:`runtime.shutdown.within`: a hung step is logged, not waited
        for); the session is its owner's to close."""
        subs, pubs = list(self.subs), [*self.pose_pubs, self.obs_pub]
        if self.loads is not None and self.loads_pub is not None:
            pubs.append(self.loads_pub)
            self.loads_pub = None
        within(step_limit, f"world: undeclaring {len(subs)} subscribers", lambda: _undeclare(subs))
        within(step_limit, f"world: undeclaring {len(pubs)} publishers", lambda: _undeclare(pubs))
        self.subs.clear()
        self.pose_pubs.clear()
        if self.frames is not None:
            self.frames.undeclare()
        if self.odom is not None:
            odom = self.odom
            within(step_limit, "world: undeclaring the odometry publishers", odom.undeclare)

    def wait_for_agents(self, abort: Callable[[], None] = lambda: None,
                        robots: Sequence[str] | None = None, grace: bool = True) -> None:
        """Wait until every robot's (or each of ``robots``') pose has a subscriber (the agent
        declares it last)."""
        deadline = time.monotonic() + self.options.start_timeout
        if self.frames is not None:
            self.frames.wait_subscribed(self.options.start_timeout, abort)
        for rid, pub in zip(self.ids, self.pose_pubs, strict=True):
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
        pub = self.pose_pubs[self.ids.index(rid)]
        deadline = time.monotonic() + timeout
        while pub.publisher.matching_status.matching:  # type: ignore[attr-defined]
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return True

    # --- the loop ----------------------------------------------------------------------------

    def run(
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
        dt = self.scenario.dt
        abort = at_most_every(ABORT_EVERY_S, abort)
        run = self._begin(progress, stop)
        try:
            if started is not None:
                started()
            for k in range(self.scenario.steps):
                run.k = k
                if on_tick is not None:
                    on_tick(k, k * dt)
                if self._period(run, k, abort):
                    break
        except BaseException:
            # aborted (a child died, Ctrl-C): what was measured over the ticks completed
            self.result = self._result(run, run.k, run.k * dt)
            raise
        self._last_commands_in(self.options.realtime, dt)
        self.result = self._result(run, run.k + 1, run.t)
        return self.result

    def _begin(self, progress: Callable[[int, int, float], None] | None,
               stop: Callable[[], bool]) -> _Run:
        """A run's start: the fleet's tick (:class:`simulator.tick.FleetTick`) with every robot
        at its start, at rest."""
        sc, opts = self.scenario, self.options
        loads = self.loads
        if loads is not None:  # a lifelong run: until every order is done, not at the goals
            def done() -> bool:
                return stop() or loads.finished(self.more_orders())

            self.tick = tick = FleetTick(sc, self.lab, False, progress, done)
        else:
            self.tick = tick = FleetTick(sc, self.lab, opts.stop_at_goal, progress, stop)
        state: list[BodyPose] = [(r.start[0], r.start[1], r.start[2]) for r in sc.robots]
        self.inbox.measure_latency = opts.realtime
        freeze_startup()  # no full collection of start-up's objects mid-run (runtime.heap)
        wall0 = time.monotonic()
        tick.start(state)
        return _Run(tick, state, wall0=wall0, next_wall=time.monotonic())

    def _period(self, run: _Run, k: int, abort: Callable[[], None]) -> bool:
        """Tick ``k``: poses out, commands in, every robot moved, the period recorded and
        checked; True to stop."""
        if self.options.pose_slots > 1:
            return self._slot_period(run, k, abort)
        return self._frame_period(run, k, abort)

    def _frame_period(self, run: _Run, k: int, abort: Callable[[], None]) -> bool:
        """One frame a period: publish every pose of tick ``k`` at once, take the commands
        (lock-step: wait for them; real time: the period's end), move every robot."""
        opts = self.options
        dt = self.scenario.dt
        t = k * dt
        stamp = time.time() + opts.clock_offset if opts.realtime else t
        run.stamps.append(stamp)
        if not opts.realtime:
            self.inbox.begin_tick(t)  # before the poses: no command for t exists yet
        self._loads_out(t, stamp, run.state)
        self._publish(t, stamp, run.state)
        if opts.realtime:
            got = self._realtime_commands(run, stamp, abort)
        else:
            got = self._lockstep_commands(k, t, abort, run.counts)
        self._statuses_in(t, run.state)
        cmds = [got.get(r) for r in self.ids]
        run.counts.applied(cmds)  # no command (either clock): zero velocity, counted
        before = run.state
        run.state = run.tick.move(before, cmds)
        run.t = (k + 1) * dt
        self._record(t, before, cmds)
        self._loads_after(run.t, run.state)
        return run.tick.check(k, run.t, run.state)

    def _slot_period(self, run: _Run, k: int, abort: Callable[[], None]) -> bool:
        """Pose slots: each slot steps its robots over the previous period, then publishes
        them (:meth:`_publish_slots`): the same rows and checks as :meth:`_frame_period`, one
        period later."""
        dt = self.scenario.dt
        run.t = t = k * dt
        run.stamps.append(time.time() + self.options.clock_offset)
        before = run.state
        run.state, cmds = self._publish_slots(k, run.state, run.next_wall, abort,
                                              run.robot_stamps)
        run.next_wall += dt
        if k == 0:  # tick 0 only publishes: nothing was applied
            return run.tick.check(k, t, None)
        run.counts.applied(cmds)
        self._record(t - dt, before, cmds)
        return run.tick.check(k, t, run.state)

    def _realtime_commands(self, run: _Run, stamp: float,
                           abort: Callable[[], None]) -> dict[str, Cmd]:
        """Real time: the period's end, and the commands whose stamps are fresh then (judged by
        the command's stamp, not by its arrival)."""
        opts = self.options
        run.publish_ms.append((time.time() + opts.clock_offset - stamp) * 1e3)
        run.next_wall += self.scenario.dt
        sleep_until(run.next_wall, abort)
        return self.inbox.fresh(time.time() + opts.clock_offset, opts.stale_after)

    def _result(self, run: _Run, steps: int, sim_time: float) -> WorldResult:
        inbox, counts = self.inbox, run.counts
        return WorldResult(
            steps=steps, sim_time=sim_time, monitor=run.tick.monitor, series=run.tick.series,
            traffic=self.counter.snapshot(), missing_cmds=counts.missing,
            zero_cmds=counts.zero, cmd_timeouts=counts.timeouts,
            camera_dropped=self.camera_dropped, malformed_cmds=inbox.malformed,
            stamp_rejected=inbox.stamps.snapshot(), clock_offset=self.options.clock_offset,
            latency_ms=list(inbox.latency_ms), wall_s=time.monotonic() - run.wall0,
            stamps=run.stamps, robot_stamps=run.robot_stamps, publish_ms=run.publish_ms,
            physics={} if self.lab is None else self.lab.summary_fields(),
        )

    @staticmethod
    def _last_commands_in(realtime: bool, dt: float) -> None:
        """Real time: give the commands computed from the last frame's poses their period to
        arrive before the run's latencies are taken (with pose slots, the last slot's poses went
        out a fraction of a period before the end, and their commands counted as missed)."""
        if realtime:
            time.sleep(dt)

    def _lockstep_commands(self, k: int, t: float, abort: Callable[[], None],
                           counts: Counts) -> dict[str, Cmd]:
        """Lock-step: wait (up to ``cmd_timeout``) for every robot's command of tick ``k``
        stamped ``t`` (robots late since a timeout not waited for); the commands that came."""
        inbox = self.inbox
        if not inbox.wait(lambda: inbox.all_in(t, self.ids), self.options.cmd_timeout, abort):
            counts.timeouts += 1
        got, late = inbox.take_since(t, self.ids)
        if late:
            logger.info("tick %d: no command from %s in time: zero", k, ", ".join(late))
        return got

    def _publish_slots(self, k: int, state: Sequence[BodyPose], start: float,
                       abort: Callable[[], None], robot_stamps: list[list[float]],
                       ) -> tuple[list[BodyPose], list[Cmd | None]]:
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
        new = list(state)
        cmds: list[Cmd | None] = [None] * n
        sent = [math.nan] * n
        robot_stamps.append(sent)
        for s in range(slots):
            sleep_until(start + s * dt / slots, abort)
            mine = range(-(-s * n // slots), -(-(s + 1) * n // slots))
            stamp = time.time() + opts.clock_offset  # the camera's clock
            fresh = self.inbox.fresh(stamp, opts.stale_after, [self.ids[i] for i in mine])
            for i in mine:
                cmds[i] = fresh.get(self.ids[i])
            if s == 0:
                self._publish_obstacles(t, stamp)
            for i in mine:
                if k > 0:
                    new[i] = self.tick.pose_after(i, new[i], cmds[i])
                sent[i] = stamp
                self._publish_pose(i, t, stamp, new[i])
        sleep_until(start + dt, abort)
        return new, cmds

    def _publish_obstacles(self, t: float, stamp: float) -> list[ObstacleMsg]:
        obs = []
        seen = [o.position(t) for o in self.scenario.obstacles] if self.lab is None \
            else self.lab.obstacles(round(t / self.scenario.dt))
        for o, (x, y) in zip(self.scenario.obstacles, seen, strict=True):
            vx, vy = o.velocity_at(t)
            obs.append(ObstacleMsg(o.name, x, y, vx, vy, o.safe_distance))
        self.obs_pub.put_message(Obstacles(stamp, tuple(obs), self._shape_msgs))
        return obs

    def _publish_pose(self, i: int, t: float, stamp: float, p: tuple[float, float, float]) -> None:
        """Publish robot ``i``'s pose, unless its camera dropout covers ``t`` (counted)."""
        rid = self.ids[i]
        if any(r == rid and t0 <= t + 1e-9 < t1 for r, t0, t1 in self.options.camera_dropouts):
            self.camera_dropped += 1
            return
        self.pose_pubs[i].put_message(Pose(p[0], p[1], p[2], stamp))

    def _publish(self, t: float, stamp: float, state: Sequence[tuple[float, float, float]]) -> None:
        """Tick ``t``'s frame (or poses) and obstacles stamped ``stamp``; under ``fused``, the
        odometry after them (:mod:`simulator.odom_out`)."""
        self._publish_frame(t, stamp, state)
        if self.odom is not None:
            self.odom.publish(stamp, state, self.lab)

    def _publish_frame(self, t: float, stamp: float,
                       state: Sequence[tuple[float, float, float]]) -> None:
        if self.frames is not None:  # the camera process publishes poses and obstacles
            self.frames.publish(state, [(o.name, *o.position(t), o.safe_distance)
                                        for o in self.scenario.obstacles], stamp)
            return
        obs = self._publish_obstacles(t, stamp)
        k = round(t / self.scenario.dt)
        if self._camera is not None:
            seen = self._camera.poses(state, [(m.x, m.y, m.ds) for m in obs], stamp)
        else:
            poses = state if self.lab is None else self.lab.sense(k, state)
            seen = {rid: s for rid, s in zip(self.ids, poses, strict=True)}
            if self.scenario.world.camera_blind:  # on blind floor the camera sees nothing
                captured = state if self.lab is None else self.lab.captured(k)[1]
                for rid, shown in zip(self.ids, seen_by_camera(self.scenario.world, captured),
                                      strict=True):
                    if not shown:
                        del seen[rid]
            if self.scenario.world.camera_faults:  # a misread, forged or lost pose
                seen = self._faulted(k, t, poses, seen)
            if self.fused:  # the agents' filters fuse each pose when it was captured
                stamp = capture_stamp(self.lab, k, t, stamp)
        for i, rid in enumerate(self.ids):
            p = seen.get(rid)
            if p is not None:  # an undetected marker publishes nothing: the agent sees it stale
                self._publish_pose(i, t, stamp, p)

    def _faulted(self, k: int, t: float, poses: Sequence[Sequence[float]],
                 seen: dict[str, Any]) -> dict[str, Any]:
        """Tick ``k``'s published poses under ``world.camera_faults``, judged at the frame's
        capture (:func:`simulator.fused.apply_faults`, as in process)."""
        at = t if self.lab is None else self.lab.captured(k)[0]
        out = apply_faults(self.scenario.world.camera_faults, at, self.ids, poses,
                           [seen.get(rid) for rid in self.ids])
        return {rid: p for rid, p in zip(self.ids, out, strict=True) if p is not None}

    def _record(self, t: float, state: Sequence[BodyPose], cmds: Sequence[Cmd | None]) -> None:
        """robots.csv's rows of the period that began at ``t`` in ``state`` (true poses, the
        commands applied), and the obstacles where they truly were."""
        if self.options.record:
            self.tick.record_robots(t, state, cmds)
            self.tick.record_obstacles(t, self.tick.obstacle_positions(t))


def _ignore(sample: zenoh.Sample) -> None:
    """A subscriber that keeps nothing (:meth:`World._declare_loads`)."""


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


@dataclass
class Counts:
    """What a run counts about the commands it applied."""

    missing: int = 0  # robot-ticks with no command: zero velocity
    zero: int = 0  # robot-ticks whose command was zero
    timeouts: int = 0  # lock-step waits for a tick's commands that timed out

    def applied(self, cmds: Sequence[Cmd | None]) -> None:
        self.missing += sum(c is None for c in cmds)
        self.zero += sum(is_zero(c) for c in cmds)


def is_zero(c: Cmd | None) -> bool:
    """Whether ``c`` is a command to stand still."""
    return c is not None and c.v == 0.0 and c.omega == 0.0 and c.ux == 0.0 and c.uy == 0.0


@dataclass
class _Run:
    """One run of the world under way: its tick, its state, what it counts and stamps."""

    tick: FleetTick
    state: list[BodyPose]
    counts: Counts = field(default_factory=Counts)
    stamps: list[float] = field(default_factory=list)  # the pose stamp of each tick
    robot_stamps: list[list[float]] = field(default_factory=list)  # pose slots: each robot's
    publish_ms: list[float] = field(default_factory=list)  # real time: stamp -> last pose put
    wall0: float = 0.0  # [s] monotonic time at the start
    next_wall: float = 0.0  # [s] real time: monotonic time at which the next period starts
    k: int = 0  # the tick under way
    t: float = 0.0  # [s] the simulated time the run has reached
