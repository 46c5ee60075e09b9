"""One robot's agent process: Zenoh inputs -> :func:`agent.control.control_step` -> Zenoh outputs.

The node is thin: it keeps the latest decoded message per key (a :class:`wire.traffic.Mailbox`
per key class, fed from Zenoh's threads through ``loop.call_soon_threadsafe``) and, each tick,
hands ``control_step`` the same inputs the in-process simulator builds
(:mod:`simulator.inprocess`): the neighbours' control points and last certified velocities from
their ``state``, the obstacles, the other formations' ellipses and a
:class:`agent.control.FormationView` of its own formation's ellipse, both from its leader's
``others`` message. The leader robot's node also runs :class:`leader.role.LeaderRole`.

Subscriptions are exact keys only: its own ``pose``, its neighbours' ``state``, its leader's
``others`` (members only), the other leaders' ``ellipse`` (leader only, reduced topology) and
``obstacles``. The all-to-all baseline subscribes to every robot's ``state`` with one wildcard.

A tick, for the pose stamped ``t``:

1. publish ``state`` = (own control point, velocity certified by the previous tick, ``t``);
2. leader: estimate the ellipse from every member's ``state`` (its own from itself), publish it on
   ``ellipse`` (reduced topology), then publish ``others`` = the other leaders' ellipses + its own;
3. if any input is stale (pose, a neighbour's state, ``others``, ``obstacles``; older than
   ``stale_after``), or a leader misses another formation's ellipse: command zero, count
   ``stale``; otherwise run ``control_step`` and publish ``cmd`` stamped ``t``.

Two clocks drive ticks. *Real time* (default): a tick runs as soon as a new pose arrives, on the
Zenoh thread that received it (the pose subscriber's callback is direct, ``indirect=False``), so
the command leaves one solve after the pose with no thread hand-over: on a loaded 2-core machine
each hand-over (Zenoh thread -> Python callback thread -> event loop) cost about 0.15 ms of CPU
and as much latency. Every other input waits in a Zenoh ring channel and is drained at the start
of the tick, so its local reception time is when the tick drained it. A pose stamped less than
``MIN_SPACING_PERIODS`` after the camera's schedule is stored but not ticked on (the next one is;
counted ``early_poses``), so a camera faster than 1/period does not raise the tick rate; the
spacing goes by the camera's stamps, not arrival times, so transport jitter never holds a tick
back, and the schedule moves on by a period, so one pose stamped late does not make the next
one too soon (:func:`agent.schedule.pose_due`). When no tick
has run for ``DEADLINE_PERIODS`` periods, the event loop ticks on its deadline anyway (on the
pose it has: a silent camera still ends in stale zero commands; counted ``deadline_ticks``). The
loop looks every ``stale_after`` less a deadline span while ticks come (at least a span), every
span after a deadline tick: the longest wait that still starts the deadline ticks before the
last pose is stale, so the zero command comes as early as if it looked every period. Each look
costs an agent about 0.15 ms of CPU on a loaded 2-core machine (8 % of its CPU when it
looked every 2.5 periods). A lock keeps
ticks one at a time whichever thread runs them, and once :meth:`AgentNode.close` starts no tick
runs. A tick longer than one period counts as an overrun. The tick itself is the same coroutine
as in lock-step; in real time it never suspends (its waits are lock-step only), so
:func:`agent.schedule.run_now` drives it to the end on the calling thread.

The node is wiring; each part owns its state: the inbox (:class:`agent.inbox.Inbox`: mailboxes,
subscribers, stamp and plausibility checks, link faults) over the transport
(:class:`agent.transport.Transport`: the session and what is declared on it), the clock
(:mod:`agent.clock`: what differs between lock-step and real time, so the tick is written
once), the scheduler (:mod:`agent.schedule`: its lock, stamps and timing counters) and the
leader's part (:class:`agent.leader_step.LeaderPart`: ellipse, listening, succession).
``NodeOptions(tick_on_pose=False)`` ticks on the own clock instead (against deadlines at
1/period, ``next_t += period``, overruns counted). Inputs are the latest received, staleness is
the local age since reception. *Lock-step* (``lockstep=True``, for the simulated world): a tick
starts when a new pose arrives, and each phase waits (up to ``lockstep_timeout``) for the inputs
stamped ``t``, so the run is deterministic and equals the in-process simulation; staleness is
``t - stamp``.

In lock-step a tick starts on the first of the frame's pose or obstacles message, so a robot whose
camera lost its marker still ticks: it waits for its pose like any input and, without one for
this frame, commands zero (counted ``stale``). An input whose wait timed out is *late*: later
ticks do not wait for it again until a message arrives on its key, so a dead neighbour, leader or
camera costs one timeout, not one per tick (counted ``lockstep_timeouts``).

Faults (docs/faults.md): :class:`agent.faults.LinkFaults` in :class:`NodeOptions` drops (seeded,
per message) and delays the inter-robot classes at this node's subscribers
(:class:`agent.fault_inject.FaultInjector`); a lost message counts in ``fault_dropped`` and, in
lock-step, ends the wait for it. A leader whose copy of another
formation's ellipse is stale keeps using it inflated by ``max_speed * age`` (both semi-axes), the
region that formation can have reached, for up to ``ellipse_hold`` seconds, then stops.

Fault containment (:mod:`leader.succession`): the leader's node holds a Zenoh liveliness token
(``{prefix}/formation/{fid}/leader``); the formation's successor (``cfg.standby``) watches it and,
when it goes, takes the leader role for the formation, which now stands still: it publishes the
ellipse estimated from the members' last positions at rest, exchanges ellipses with the other
leaders and relays them on ``others``, so the other formations keep avoiding it without
inflating a stale ellipse; it steps down when the token comes back (``takeovers``,
``acting_leader_ticks``).

Malformed or non-finite payloads are dropped and counted per key class. On stop (SIGINT/SIGTERM
in ``python -m agent``) the node publishes a zero command, undeclares everything and closes the
session; :meth:`AgentNode.stats` holds every counter for the launcher.
"""

from __future__ import annotations

import asyncio
import logging
import math
import statistics
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import zenoh

from agent import double_integrator
from agent.barriers import Obstacle
from agent.base import Base, make_base
from agent.clock import STATS_WINDOW, Clock, LockstepClock, RealtimeClock
from agent.config import AgentConfig
from agent.control import Controller, Stall, StepResult
from agent.faults import EPS, LinkFaults
from agent.hard_rows import HardRowCounter
from agent.inbox import RING_CAPACITY, Inbox, Receiver
from agent.inputs import carry_pose, step_inputs, with_waypoint
from agent.leader_step import LeaderPart
from agent.margins import carried_age
from agent.navigation import STALLED_AFTER_S, NavPart
from agent.plausibility import ObstacleMemory, held_obstacle, speed_bound
from agent.qp import STATUS_FAILED, STATUS_FALLBACK, STATUS_RELAXED, make_solver
from agent.replan import plan_pool
from agent.schedule import ClockLoop, LockstepLoop, PoseScheduler, TickGate
from agent.stats import AgentStats
from agent.transport import Transport
from agent.unicycle import control_point
from leader.role import msg_to_ellipse
from runtime.heap import freeze_startup
from runtime.shutdown import STEP_LIMIT_S, undeclare_all, within
from wire import keys
from wire.diag import DiagPublisher
from wire.payloads import Cmd, Obstacles, Others, Pose, State
from wire.stamps import LOCKSTEP_AHEAD_PERIODS, check_stamp, validate_window
from wire.traffic import TrafficCounter
from wire.zconf import UsrPwdAuth, ZenohSettings, explain_open_failure, read_auth_file

logger = logging.getLogger(__name__)

STATUS_STALE = "stale"  # trace status of a tick that commanded zero for stale inputs
IMPLAUSIBLE = "implausible"  # stale_why: a tick that commanded zero after an implausible input
CONTESTED = "contested"  # stale_why: zero, no state: an input had a second source (agent.inbox)
POSE_AT_SEND = "pose_at_send"  # stale_why: the pose went stale while the command was computed
TRACE_COLUMNS = ("t", "px", "py", "ux", "uy", "v", "omega", "status", "slack",
                 "h_formation", "h_obstacle", "h_formations", "solve_us")
States = dict[str, State]


@dataclass(frozen=True)
class NodeOptions:
    lockstep: bool = False  # tick on pose arrival (simulated world) instead of the own clock
    lockstep_timeout: float = 2.0  # [s] longest wait for one phase's inputs in lock-step
    trace: bool = True  # keep one row per tick (TRACE_COLUMNS) for the launcher's time series
    # (unbounded: about 400 bytes a tick; ``python -m agent --no-trace`` for long runs)
    connect_timeout: float = 10.0  # [s] keep retrying the router this long when opening
    faults: LinkFaults = LinkFaults()  # loss and delay applied to received inter-robot messages
    ellipse_hold: float = 10.0  # [s] leader: longest use of another formation's stale ellipse
    auth: UsrPwdAuth | None = None  # log in to the router as this user (access control)
    tick_on_pose: bool = True  # real time: tick on pose arrival (deadline fallback), not the clock
    zenoh_config_file: str | None = None  # a full Zenoh JSON5 config (deploy's, e.g. with TLS)
    sim_start: float = 0.0  # [s] lock-step: the simulated time the agent starts at (a restarted
    # agent joins a run under way); stamps beyond it plus LOCKSTEP_AHEAD_PERIODS are refused

    def __post_init__(self) -> None:
        if not isinstance(self.faults, LinkFaults):
            raise ValueError(f"faults: must be a LinkFaults, got {type(self.faults).__name__}")
        if not (isinstance(self.sim_start, int | float) and math.isfinite(self.sim_start)
                and self.sim_start >= 0):
            raise ValueError(f"sim_start: must be a finite number >= 0, got {self.sim_start!r}")
        for name in ("lockstep_timeout", "connect_timeout", "ellipse_hold"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")


def zenoh_config(cfg: AgentConfig, connect_timeout: float | None = None,
                 auth: UsrPwdAuth | None = None) -> zenoh.Config:
    """The ``zenoh.Config`` of an agent from its configuration's Zenoh settings (and the
    user/password it logs in with, if any)."""
    z = cfg.zenoh
    return ZenohSettings(
        mode=z.mode, connect=tuple(z.connect), listen=tuple(z.listen),
        multicast_scouting=z.multicast_scouting,
        connect_timeout_s=connect_timeout if z.connect else None, auth=auth,
    ).to_config()


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _median(values: Any) -> float | None:
    return statistics.median(values) if values else None


@dataclass
class TickCounts:
    """What the tick counts (gathered into :class:`agent.stats.AgentStats` by the node)."""

    ticks: int = 0
    stale: int = 0
    waiting: int = 0  # ticks before the first pose arrived (zero command, not stale)
    stale_why: dict[str, int] = field(default_factory=dict)  # stale ticks by the stale input
    solves: int = 0
    escape_ticks: int = 0  # ticks whose nominal was the formation-level escape
    obstacle_held_ticks: int = 0  # ticks that avoided an obstacle missing from the list
    status_counts: dict[str, int] = field(default_factory=lambda: {
        STATUS_RELAXED: 0, STATUS_FALLBACK: 0, STATUS_FAILED: 0})
    min_h: dict[str, float] = field(default_factory=lambda: {
        "formation": math.inf, "obstacle": math.inf, "formations": math.inf})
    solve_us: deque[float] = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # [us]
    trace: list[tuple] = field(default_factory=list)
    tick_errors: int = 0  # ticks that raised: answered with the zero command
    error_kinds: set[str] = field(default_factory=set)  # exception type + where, logged once


class AgentNode:
    """The agent of one robot; ``await node.run(stop)`` until ``stop`` is set."""

    def __init__(self, cfg: AgentConfig, options: NodeOptions = NodeOptions()) -> None:
        self.cfg = cfg
        self.options = options
        p = cfg.prefix
        self.counter = TrafficCounter(p)
        self.pose_key = keys.pose_key(p, cfg.robot_id)
        self.state_key = keys.state_key(p, cfg.robot_id)
        self.cmd_key = keys.cmd_key(p, cfg.robot_id)
        self.others_key = keys.others_key(p, cfg.formation)
        self.obstacles_key = keys.obstacles_key(p)
        self.all_to_all = cfg.topology == "all-to-all"
        self.neighbour_keys = {keys.state_key(p, n): df for n, df in cfg.neighbours}
        self.foreign_keys = tuple(keys.state_key(p, r) for r in cfg.foreign_robots)
        # separation rows: every other member (graph neighbour or not), then foreign robots
        self.partner_keys = tuple(keys.state_key(p, r) for r in cfg.partners)
        # every robot's state this node reads each tick (built once, not per tick)
        extra = tuple(k for k in self.partner_keys if k not in self.neighbour_keys)
        self._state_keys = tuple(self.neighbour_keys) + extra + (self.foreign_keys if self.all_to_all
                                                                 else ())
        self.gate = TickGate()  # ticks one at a time whichever thread runs them
        self._tolerance = (LOCKSTEP_AHEAD_PERIODS * cfg.period if options.lockstep
                           else cfg.clock_tolerance)
        validate_window(self._tolerance, cfg.stale_after)
        self.clock: Clock = (
            LockstepClock(cfg.stale_after, options.lockstep_timeout, options.sim_start,
                          cfg.robot_id, EPS) if options.lockstep
            else RealtimeClock(cfg.stale_after, cfg.control.offset))
        receiver = Receiver(self.clock.now, self.clock.starved, self._tolerance, cfg.stale_after,
                            speed_bound(cfg.control))
        self.inbox = Inbox(cfg.robot_id, receiver, self.counter, options.faults,
                           (cfg.period, options.lockstep), self.gate.lock,
                           polled=not options.lockstep and options.tick_on_pose)
        self.leader = LeaderPart(cfg, options.lockstep, options.ellipse_hold, options.trace,
                                 self.inbox, self.clock, self.neighbour_keys)
        self.inbox.subscribed_keys.update(self._subscription_keys())
        self.nav = NavPart(cfg, leader=self.leader.leading)  # routes, goals, plan, status
        if self.nav.routes is not None and not options.lockstep:
            plan_pool()  # started before the ticks (agent.replan.plan_pool)
        self.scheduler = self._scheduler()
        self.counts = TickCounts()
        self.obstacle_memory = ObstacleMemory()
        self.hard = HardRowCounter()  # ticks on which a hard row was not met
        self._solve = make_solver(cfg.solver)  # the config's QP solver (exact by default)
        # the tick's memory
        self.last_u = (0.0, 0.0)
        self.last_stamp = 0.0
        self._last_pose_used: float | None = None
        self._stall = Stall()  # this member's copy of its formation's jam state
        self._tick_point: tuple[float, float, float, float] | None = None
        self._ahead = 0.0  # [s] this tick's pose carried forward by its measured age (_carried)
        self._cpu0 = time.process_time()
        self._wall0 = time.monotonic()
        # outputs and life
        self.transport: Transport | None = None
        self._diag: DiagPublisher | None = None
        self._base: Base | None = None  # a real robot base adapter (agent.base), when cfg.base is not "world"
        self._stop: asyncio.Event | None = None
        self.zero_sent = False  # the zero command of the way out has been published
        # Commands go out one at a time, and none but zero after the way out's zero: a tick
        # that outlived closing (the tick lock not had in time) must not follow the zero.
        self._cmd_lock = threading.Lock()
        self.late_commands = 0  # commands of such a tick, dropped and logged

    def _scheduler(self) -> LockstepLoop | PoseScheduler | ClockLoop:
        cfg = self.cfg
        if isinstance(self.clock, LockstepClock):
            return LockstepLoop(self.tick, self.clock, self.inbox,
                                (self.pose_key, self.obstacles_key))
        if self.options.tick_on_pose:
            return PoseScheduler(self.tick, self.gate, self.inbox, self.pose_key, cfg.period,
                                 cfg.pose_period or cfg.period, cfg.stale_after)
        return ClockLoop(self.tick, cfg.period)

    # --- read-only views ------------------------------------------------------------------------

    @property
    def subscribed_keys(self) -> dict[str, str]:
        """Every key subscribed to -> the mailbox class that holds it."""
        return self.inbox.subscribed_keys

    @property
    def ticks(self) -> int:
        return self.counts.ticks

    @property
    def stale(self) -> int:
        return self.counts.stale

    @property
    def stale_why(self) -> dict[str, int]:
        return self.counts.stale_why

    @property
    def status_counts(self) -> dict[str, int]:
        return self.counts.status_counts

    @property
    def dropped_malformed(self) -> int:
        return self.inbox.dropped_malformed

    # --- wiring ---------------------------------------------------------------------------------

    def _subscription_keys(self) -> dict[str, str]:
        """Every key this node subscribes to -> the mailbox class that holds it."""
        subs: dict[str, str] = {}
        if self.all_to_all:
            subs[keys.all_robots_key(self.cfg.prefix, keys.STATE)] = keys.STATE
        else:
            for k in self.neighbour_keys:
                subs[k] = keys.STATE
            for k in self.partner_keys:  # members that are not graph neighbours (separation)
                subs[k] = keys.STATE
        role = self.leader.role
        if role is None:
            subs[self.others_key] = keys.OTHERS
        elif self.options.lockstep:  # both topologies: the tie-break and the jam rule read them
            for k in role.other_keys:
                subs[k] = keys.ELLIPSE
        else:  # real time: every beacon; an ellipse once its formation is near (leader.listen)
            subs[keys.all_formations_key(self.cfg.prefix, keys.BEACON)] = keys.BEACON
        subs[self.obstacles_key] = keys.OBSTACLES
        subs[self.pose_key] = keys.POSE  # last: once the pose is matched, all else is declared
        return subs

    def _ring_caps(self) -> dict[str, int]:
        """Real time: ring channels that hold more than one key's samples (wildcards)."""
        caps = {}
        if self.all_to_all:  # one wildcard for every robot's state
            caps[keys.STATE] = RING_CAPACITY * max(1, len(self.foreign_keys)
                                                   + len(self.neighbour_keys))
        if self.leader.role is not None:  # every formation's beacon, one wildcard
            caps[keys.BEACON] = 2 * (len(self.leader.role.other_keys) + 1)
        return caps

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        """Open the session, declare publishers and the exact subscriptions."""
        self._stop = self._stop or asyncio.Event()
        if isinstance(self.clock, LockstepClock):
            self.clock.stop = self._stop
        session = self.open_session()
        t = self.transport = Transport(session, self.counter)
        for k in [self.state_key, self.cmd_key, *self.leader.publish_keys()]:
            t.publisher(k)
        self._diag = DiagPublisher(session, self.cfg.prefix, self.cfg.robot_id,
                                   self.cfg.formation, self.cfg.goal)
        self.nav.open(session, self.counter)
        if self.cfg.base != "world":
            # A real robot base (TurtleBot3 behind zenoh-bridge-ros2dds): every command also goes
            # to its cmd_vel key as CDR; the cmd key stays for monitoring.
            self._base = make_base(self.cfg, session)
        sched = self.scheduler
        on_pose = sched.on_sample if isinstance(sched, PoseScheduler) else None
        self.inbox.open(t, loop, on_pose or self.inbox.mailbox(keys.POSE).callback,
                        self._ring_caps())
        for k, cls in list(self.subscribed_keys.items()):
            self.inbox.declare(k, cls)
        self.leader.open(t, loop, self.gate)
        logger.info("%s: subscribed to %s", self.cfg.robot_id, ", ".join(self.subscribed_keys))

    @property
    def base(self) -> Base | None:
        """The real robot base this agent drives (agent.base), when ``cfg.base`` is not "world"."""
        return self._base

    def open_session(self) -> zenoh.Session:
        """This node's Zenoh session (an agent host, :mod:`agent.host`, may hand it a shared
        one); ``ConnectionError`` saying why it did not open."""
        if self.options.zenoh_config_file is not None:
            conf = zenoh.Config.from_file(self.options.zenoh_config_file)
        else:
            conf = zenoh_config(self.cfg, self.options.connect_timeout, self.options.auth)
        try:
            return zenoh.open(conf)
        except Exception as exc:  # noqa: BLE001 - zenoh says "Timeout!" for refused credentials
            raise ConnectionError(self._open_failure(exc)) from None

    def _open_failure(self, exc: BaseException) -> str:
        """Why the session did not open, in words (refused credentials, no router)."""
        connect, auth = tuple(self.cfg.zenoh.connect), self.options.auth
        if self.options.zenoh_config_file is not None:
            try:
                found = read_auth_file(self.options.zenoh_config_file)
                connect, auth = found.connect or connect, found.auth
            except ValueError:  # no credentials in it
                pass
        return explain_open_failure(exc, connect, auth)

    def close_session(self, session: zenoh.Session) -> None:
        """Close what :meth:`open_session` opened."""
        session.close()

    def close(self, step_limit: float = STEP_LIMIT_S) -> None:
        """Zero command, undeclare, close the session (idempotent). Every step waits at most
        ``step_limit`` seconds (:func:`runtime.shutdown.within`): a step that hangs (a router that
        is gone) is logged and left behind, and closing goes on, zero command first."""
        rid = self.cfg.robot_id
        if not self.gate.close(step_limit):  # a tick in progress ends first
            logger.warning("%s: a tick still runs after %.1f s: closing anyway", rid, step_limit)
        t = self.transport
        if t is None:
            return

        def zero() -> None:
            with self._cmd_lock:
                self._send(Cmd(0.0, 0.0, 0.0, 0.0, self.last_stamp))
                self.zero_sent = True

        within(step_limit, f"{rid}: zero command on exit", zero)
        token = self.leader.take_token()
        handles = [*([] if token is None else [token]), *t.handles()]
        within(step_limit, f"{rid}: undeclaring {len(handles)} tokens, subscribers and publishers",
               lambda: undeclare_all(handles))
        self.nav.close(self.last_stamp)
        if self._base is not None:
            base = self._base  # zero velocity on the real base, then undeclare
            within(step_limit, f"{rid}: stopping the base", base.stop)
            self._base = None
        t.clear()
        self.inbox.close()
        self.transport = None
        within(step_limit, f"{rid}: closing the Zenoh session",
               lambda: self.close_session(t.session))

    def emergency_zero(self) -> bool:
        """From any thread and without the tick lock (a shutdown that overran its time limit):
        publish the zero command unless :meth:`close` already did. True once it is sent. The
        command lock is waited for at most ``STEP_LIMIT_S`` (a publish that hangs holds it)."""
        if self.zero_sent:
            return True
        t = self.transport
        locked = self._cmd_lock.acquire(timeout=STEP_LIMIT_S)
        try:
            if self.zero_sent:
                return True
            if t is None or not t.publish(self.cmd_key, Cmd(0.0, 0.0, 0.0, 0.0, self.last_stamp)):
                return False
            if self._base is not None:
                self._base.send(0.0, 0.0, self.last_stamp)
        except Exception:  # noqa: BLE001 - last resort: report, the caller exits anyway
            logger.exception("%s: emergency zero command failed", self.cfg.robot_id)
            return False
        finally:
            if locked:
                self._cmd_lock.release()
        self.zero_sent = True
        return True

    # --- life -----------------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        """Open, tick until ``stop`` is set, close."""
        self._stop = stop
        loop = asyncio.get_running_loop()
        try:
            # inside the try: a session opened by an open() that fails half-way is closed too
            await loop.run_in_executor(None, self.open, loop)
            freeze_startup()  # no full collection of start-up's objects mid-run (runtime.heap)
            await self.scheduler.run(stop)
        finally:
            self.close()

    # --- one tick -------------------------------------------------------------------------------

    async def tick(self, t: float | None) -> StepResult | None:
        """One control tick; ``t`` is the frame's stamp in lock-step, None in real time (only
        the clock reads it). The clock decides when ``state`` goes out: lock-step before the
        command (the neighbours and the leader wait for it), real time after it, with the
        velocity just certified (zero after a stale tick), the freshest it can share."""
        self.counts.ticks += 1
        self._tick_point = None
        try:
            res = await self._tick(t)
            if self._diag is not None:  # viewers' diagnostics: a few a second, not counted
                self._diag.tick(self, res)
            return res
        except Exception as exc:  # noqa: BLE001 - no message may make an agent raise
            self._tick_failed(t, exc)
            return None
        finally:
            self.clock.state_after(self._send_state)

    def _tick_failed(self, t: float | None, exc: Exception) -> None:
        """A tick that raised: counted (``tick_errors``), answered with the zero command and
        logged once per kind (exception type and where it was raised), not once per tick."""
        c = self.counts
        c.tick_errors += 1
        frame = traceback.extract_tb(exc.__traceback__)[-1:] or None
        where = f"{frame[0].filename}:{frame[0].lineno}" if frame else "?"
        kind = f"{type(exc).__name__} at {where}"
        if kind not in c.error_kinds:
            c.error_kinds.add(kind)
            logger.error("%s: a tick raised %s: %s (answered with the zero command; logged "
                         "once per kind)", self.cfg.robot_id, kind, exc)
        self._tick_point = None
        self.last_u = self._halted()
        try:
            self.send_command(Cmd(0.0, 0.0, 0.0, 0.0, self.clock.cmd_stamp(t, self.last_stamp)))
        except Exception:  # noqa: BLE001 - the zero command itself failed: logged, go on
            logger.debug("%s: zero command after a tick error failed", self.cfg.robot_id,
                         exc_info=True)

    def _halted(self) -> tuple[float, float]:
        """This robot's velocity one period after a zero command: zero, or for a double
        integrator what one period of braking leaves (the world brakes it so:
        :func:`agent.double_integrator.brake`)."""
        c = self.cfg.control
        if not c.double_integrator:
            return (0.0, 0.0)
        vx, vy = self.last_u
        ax, ay = double_integrator.brake(vx, vy, c.max_accel or math.inf, c.period)
        _, _, vx, vy = double_integrator.integrate(0.0, 0.0, vx, vy, ax, ay, c.period, c.max_speed)
        return (vx, vy)

    def _send_state(self) -> None:
        if self._tick_point is not None and self.transport is not None:
            px, py, stamp, th = self._tick_point
            self.transport.publish(self.state_key, State(px, py, *self.last_u, stamp, th))

    async def _tick(self, t: float | None) -> StepResult | None:
        """The pose part of the tick: which pose, if any, it runs on."""
        clock = self.clock
        await clock.start(self.inbox, [(keys.POSE, self.pose_key)], t)
        pose_entry = self.inbox.latest(keys.POSE, self.pose_key)
        if pose_entry is None:  # not localised yet (start-up): zero, counted apart from stale
            self.counts.waiting += 1
            self.send_command(Cmd(0.0, 0.0, 0.0, 0.0, clock.cmd_stamp(t, self.last_stamp)))
            return None
        pose: Pose = pose_entry[0]
        if self.inbox.contested():  # two sources on an input: neither is trusted (no state sent)
            return self._zero(t, CONTESTED)
        # lock-step: no pose in this frame (camera dropout); the second check cannot fail (the
        # mailbox keeps stamps in order)
        if not clock.pose_current(pose_entry, t) or check_stamp(
                clock.at(t), pose.stamp, self._last_pose_used, self._tolerance,
                self.cfg.stale_after) is not None:
            return self._zero(t, "pose")
        self._last_pose_used = pose.stamp
        clock.note_pose(pose_entry)
        self.last_stamp = pose.stamp
        pose, self._ahead = self._carried(pose, clock.at(t))
        off = self.cfg.control.offset
        px, py = control_point(pose.x, pose.y, pose.theta, off) if self.cfg.control.unicycle \
            else (pose.x, pose.y)
        self._tick_point = (px, py, pose.stamp + self._ahead, pose.theta)
        clock.state_before(self._send_state)
        return await self._step(t, pose, px, py)

    async def _step(self, t: float | None, pose: Pose, px: float, py: float
                    ) -> StepResult | None:
        """The rest of the tick, on the pose stamped ``stamp``: the leader's part, the inputs,
        the control step, the command."""
        clock, stamp = self.clock, pose.stamp
        others_ready = True
        if self.leader.leading:
            others_ready = await self.leader.lead(px, py, stamp, stamp, self.last_u, pose.theta)
        await clock.wait(self.inbox, self._tick_inputs(), stamp)
        fresh = self._fresh_inputs(stamp, others_ready)
        if isinstance(fresh, str):
            return self._zero(t, fresh)
        states, obstacles, others_msg = fresh
        obs = self._obstacles(obstacles, clock.at(stamp), px, py)
        if self.inbox.take_implausible():  # an input broke physics since the last tick
            return self._zero(t, IMPLAUSIBLE)
        shapes = self.nav.update_shapes(obstacles.shapes)
        own = None if others_msg.own is None else msg_to_ellipse(others_msg.own)
        target, waypoint = self.nav.follower.goal, self.cfg.formation_goal
        if own is not None:  # walk the route (the leader takes new goals first)
            target, waypoint = self.nav.step(stamp, clock.lockstep, own.cx, own.cy, own,
                                             (obstacles.obstacles, others_msg.ellipses))
        return self._control(t, pose, clock.align(states, stamp + self._ahead), obs, shapes, own,
                             target, waypoint, others_msg)

    def _carried(self, pose: Pose, now: float) -> tuple[Pose, float]:
        """The pose carried forward by its measured age ``now - stamp``, at most the declared
        latency (``controller.bounds``: :func:`agent.margins.carried_age`), under the last
        certified command; the stamp stays the camera's. Without bounds, and in lock-step (each
        pose is its tick's: age 0, as in the in-process simulator), the pose as it came."""
        ahead = carried_age(now - pose.stamp, self.cfg.control.bounds.latency)
        if ahead <= 0.0 or self.clock.lockstep:
            return pose, 0.0
        x, y, th = carry_pose(pose.x, pose.y, pose.theta, *self.last_u, ahead,
                              self.cfg.control.offset)
        return Pose(x, y, th, pose.stamp), ahead

    def _control(self, t: float | None, pose: Pose, states: States, obs: list[Obstacle],
                 shapes: Any, own: Any, target: Any, waypoint: Any, others_msg: Others
                 ) -> StepResult | None:
        """The control step on the tick's inputs, and its command."""
        cfg, stamp = self.cfg, pose.stamp
        inputs = step_inputs(
            ((states[k].x, states[k].y, states[k].ux, states[k].uy, df, states[k].theta)
             for k, df in self.neighbour_keys.items()),
            own, cfg.formation, waypoint,
            [(m.formation, msg_to_ellipse(m)) for m in others_msg.ellipses],
            self._stall, cfg.period,  # the jam rule's memory
            [(states[k].x, states[k].y, states[k].ux, states[k].uy, states[k].theta)
             for k in self.foreign_keys] if self.all_to_all else None,
            [(states[k].x, states[k].y, states[k].ux, states[k].uy, states[k].theta)
             for k in self.partner_keys],
        )
        self._stall = inputs.stall
        inputs = with_waypoint(inputs, self.nav.follower.heading, self.nav.follower.arriving)
        res = Controller(cfg.control, self._solve, time.perf_counter_ns).step(inputs._replace(
            pose=(pose.x, pose.y, pose.theta), goal=target, obstacles=obs, last_u=self.last_u,
            shapes=shapes, footprint=cfg.footprint))
        if self.clock.gone_stale(stamp):
            return self._zero(t, POSE_AT_SEND)  # never send a command from a pose gone stale
        if self.leader.leading:
            stall = self._stall
            self.nav.report(stamp, stall.still >= STALLED_AFTER_S, False)
        accel = (res.ax, res.ay) if cfg.control.double_integrator else (None, None)
        self.send_command(Cmd(res.v, res.omega, res.ux, res.uy, stamp, *accel))
        self.last_u = (res.ux, res.uy)
        self._record(res, stamp)
        return res

    def _fresh_inputs(self, ts: float, others_ready: bool
                      ) -> tuple[States, Obstacles, Others] | str:
        """Every input of the step if all are fresh (``ts``: the reference stamp, lock-step),
        else the name of the first stale one (the reason counted for the zero command)."""
        clock, inbox = self.clock, self.inbox
        states: States = {}
        for k in self._state_keys:
            entry = inbox.latest(keys.STATE, k)
            if entry is None or not clock.fresh(entry, ts):
                return "state"
            states[k] = entry[0]
        obs_entry = inbox.latest(keys.OBSTACLES, self.obstacles_key)
        if obs_entry is None or not clock.fresh(obs_entry, ts):
            return "obstacles"
        if self.leader.leading:
            own_others = self.leader.own_others
            if not others_ready or own_others is None:
                return "ellipse"
            return states, obs_entry[0], own_others
        entry = inbox.latest(keys.OTHERS, self.others_key)
        if entry is None or not clock.fresh(entry, ts):
            return "others"
        return states, obs_entry[0], entry[0]

    def _obstacles(self, obstacles: Obstacles, now: float, px: float, py: float) -> list[Obstacle]:
        """The step's obstacles: the newest list's, plus those missing from it but seen within
        the hold time, grown where they can have gone (agent.plausibility; counted)."""
        memory = self.obstacle_memory
        memory.update(obstacles)
        obs = [Obstacle(o.x, o.y, o.vx, o.vy, o.ds) for o in obstacles.obstacles]
        held = memory.held(now)
        if held:
            self.counts.obstacle_held_ticks += 1
            obs += [held_obstacle(o, age, px, py) for o, age in held]
        return obs

    def _record(self, res: StepResult, stamp: float) -> None:
        """Count a solved step: statuses, lowest barrier values, hard rows not met, solve time,
        trace row."""
        c = self.counts
        self.hard.add(res)
        c.solves += 1
        c.escape_ticks += res.escape
        c.solve_us.append(res.solve_us)
        if res.status in c.status_counts:
            c.status_counts[res.status] += 1
        c.min_h["formation"] = min(c.min_h["formation"], res.h_formation)
        c.min_h["obstacle"] = min(c.min_h["obstacle"], res.h_obstacle)
        c.min_h["formations"] = min(c.min_h["formations"], res.h_formations)
        if self.options.trace:
            c.trace.append((stamp, res.px, res.py, res.ux, res.uy, res.v, res.omega, res.status,
                            res.slack, res.h_formation, res.h_obstacle, res.h_formations,
                            res.solve_us))

    def _tick_inputs(self) -> list[tuple[str, str]]:
        inputs = [(keys.STATE, k) for k in self._state_keys]
        inputs.append((keys.OBSTACLES, self.obstacles_key))
        if not self.leader.leading:
            inputs.append((keys.OTHERS, self.others_key))
        return inputs

    def _zero(self, t: float | None, why: str) -> StepResult | None:
        """Command zero for a stale input ``why`` (counted); None, the tick's result."""
        c = self.counts
        c.stale_why[why] = c.stale_why.get(why, 0) + 1
        c.stale += 1
        self.last_u = self._halted()
        stamp = self.clock.cmd_stamp(t, self.last_stamp)
        self.send_command(Cmd(0.0, 0.0, 0.0, 0.0, stamp))
        if self.leader.leading:
            self.nav.report(stamp, False, True)
        logger.debug("%s: stale %s, zero command", self.cfg.robot_id, why)
        if self.options.trace:
            nan = math.nan
            c.trace.append((stamp, nan, nan, 0.0, 0.0, 0.0, 0.0, STATUS_STALE, 0.0,
                            nan, nan, nan, nan))
        return None

    def send_command(self, cmd: Cmd) -> None:
        """Publish a tick's command (and drive the base), unless the way out's zero went first:
        then a non-zero command is dropped and counted (``late_commands``)."""
        moving = any((cmd.v, cmd.omega, cmd.ux, cmd.uy))
        with self._cmd_lock:
            if self.zero_sent and moving:
                self.late_commands += 1
                logger.warning("%s: a tick outlived closing: its command after the zero dropped",
                               self.cfg.robot_id)
                return
            self._send(cmd, moving)

    def _send(self, cmd: Cmd, moving: bool = False) -> None:
        """Under the command lock: publish ``cmd`` (``moving``: not zero) and drive the base."""
        self.inbox.note_command(moving)
        if self.transport is not None:
            self.transport.publish(self.cmd_key, cmd)
        if self._base is not None:
            self._base.send(cmd.v, cmd.omega, cmd.stamp)

    # --- counters -------------------------------------------------------------------------------

    def stats(self) -> AgentStats:
        """Every counter, JSON-ready (non-finite numbers as None). The ``*_us_median`` figures
        are over the newest ``stats_window`` ticks (:data:`agent.clock.STATS_WINDOW`); the
        counts over all."""
        c, sc, ld, inbox = self.counts, self.scheduler.counts, self.leader, self.inbox
        boxes = inbox.counts()
        return AgentStats(
            robot=self.cfg.robot_id, formation=self.cfg.formation,
            leader=self.cfg.leader is not None,  # by configuration (see takeovers)
            acting_leader=ld.acting,  # a successor leading for a dead leader at the end
            lockstep=self.options.lockstep, ticks=c.ticks, overruns=sc.overruns,
            deadline_ticks=sc.deadline_ticks, early_poses=sc.early_poses, stale=c.stale,
            waiting=c.waiting, lockstep_timeouts=self.clock.timeouts,
            stale_why=dict(c.stale_why), stamp_rejected=inbox.stamps.snapshot(),
            lockstep_catch_ups=inbox.catch_ups, implausible=dict(inbox.implausible),
            obstacles_missing=self.obstacle_memory.missing,
            obstacles_dropped_after_hold=self.obstacle_memory.dropped,
            obstacle_held_ticks=c.obstacle_held_ticks, hard_row_unmet_ticks=self.hard.ticks,
            hard_row_unmet=dict(self.hard.by_reason), inflated=ld.inflated,
            listening=sorted(ld.listening),  # leader.listen: formations heard every tick
            listen_changes=ld.listen_changes, takeovers=ld.takeovers,
            acting_leader_ticks=ld.acting_ticks, nav=self.nav.stats(), goal_refusal=self.nav.refusal,
            fault_dropped=dict(inbox.faults.dropped), fault_delayed=inbox.faults.delayed,
            solves=c.solves, escape_ticks=c.escape_ticks, tick_errors=c.tick_errors,
            reacquired=inbox.reacquired,
            relaxed=c.status_counts[STATUS_RELAXED], fallback=c.status_counts[STATUS_FALLBACK],
            failed=c.status_counts[STATUS_FAILED], solve_us_median=_median(c.solve_us),
            tick_us_median=_median(sc.tick_us), pose_age_us_median=_median(self.clock.pose_age_us),
            pose_in_us_median=_median(self.clock.pose_in_us), stats_window=STATS_WINDOW,
            min_h={k: _finite_or_none(v) for k, v in c.min_h.items()},
            dropped=boxes["dropped"], rejected=boxes["rejected"], received=boxes["received"],
            subscriptions=sorted(self.subscribed_keys), traffic=self.counter.snapshot(),
            cpu_s=time.process_time() - self._cpu0, wall_s=time.monotonic() - self._wall0,
            trace_columns=list(TRACE_COLUMNS),
            trace=[[_finite_or_none(v) if isinstance(v, float) else v for v in row]
                   for row in c.trace],
            ellipse_trace=[list(row) for row in ld.ellipse_trace],
        )
