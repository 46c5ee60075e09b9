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
:func:`agent.schedule.run_now` drives it to the end on the calling thread. The schedulers are
:mod:`agent.schedule`'s; the leader's part (its step in a tick, a successor taking over) is
:mod:`agent.leader_step`'s.
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
(:mod:`agent.fault_inject`); a lost message counts in ``fault_dropped`` and, in lock-step, ends
the wait for it. A leader whose copy of another
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
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, TypeGuard

import zenoh

from agent.barriers import Obstacle
from agent.base import Base, make_base
from agent.config import AgentConfig
from agent.control import Stall, StepResult, control_step
from agent.fault_inject import faulty_sample, offer
from agent.faults import EPS, DelayLine, LinkFaults, lag
from agent.hard_rows import HardRowCounter
from agent.inputs import predict_state, step_inputs
from agent.leader_step import lead, on_leader_token
from agent.navigation import STALLED_AFTER_S, NavPart
from agent.plausibility import (
    JUMP_MARGIN_M,
    ObstacleMemory,
    ellipses_ok,
    held_obstacle,
    jump_ok,
    speed_bound,
    velocity_ok,
)
from agent.qp import STATUS_FAILED, STATUS_FALLBACK, STATUS_RELAXED, make_solver
from agent.schedule import (
    TickQueue,
    lockstep_loop,
    on_pose_sample,
    pose_loop,
    realtime_loop,
    wait_current,
)
from agent.unicycle import control_point
from leader.role import LeaderRole, msg_to_ellipse
from leader.succession import leader_token_key
from runtime.heap import freeze_startup
from runtime.shutdown import STEP_LIMIT_S, undeclare_all, within
from wire import keys
from wire.diag import DiagPublisher
from wire.payloads import (
    Cmd,
    Obstacles,
    Others,
    Pose,
    State,
    decode_ellipse,
    decode_obstacles,
    decode_others,
    decode_pose,
    decode_state,
)
from wire.stamps import FUTURE, LOCKSTEP_AHEAD_PERIODS, StampCounter, check_stamp, validate_window
from wire.traffic import CountingPublisher, Mailbox, TrafficCounter
from wire.zconf import UsrPwdAuth, ZenohSettings, explain_open_failure, read_auth_file

logger = logging.getLogger(__name__)

RING_CAPACITY = 256  # real time: samples kept per key between two ticks (a flood beyond it
# loses its oldest samples uncounted; about one per tick arrives in normal operation)
STATS_WINDOW = 10_000  # per-tick timings kept for the medians in stats() (the newest ticks)
STATUS_STALE = "stale"  # trace status of a tick that commanded zero for stale inputs
IMPLAUSIBLE = "implausible"  # stale_why: a tick that commanded zero after an implausible input
POSE_AT_SEND = "pose_at_send"  # stale_why: the pose went stale while the command was computed
DECODERS: dict[str, Callable[[bytes], Any]] = {  # mailbox class -> payload reader
    keys.POSE: decode_pose, keys.STATE: decode_state, keys.OTHERS: decode_others,
    keys.ELLIPSE: decode_ellipse, keys.OBSTACLES: decode_obstacles, keys.BEACON: decode_ellipse,
}
TRACE_COLUMNS = ("t", "px", "py", "ux", "uy", "v", "omega", "status", "slack",
                 "h_formation", "h_obstacle", "h_formations", "solve_us")


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


class DecodeMemo:
    """A payload decoder that remembers the values of the last payloads it decoded, shared by
    every agent of one process: in an agent host each agent decodes the same ``obstacles``
    message every tick, the members of a formation the same ``others`` and the neighbours of a
    robot its same ``state`` (issue 18: a host of 32 decoded each obstacles list 32 times).
    Decoded messages are frozen, so sharing one changes nothing an agent sees; a payload that
    does not decode raises every time (each agent counts its own drop). Thread-safe under
    the GIL (a lost insert costs one more decode); emptied when it holds ``size`` payloads."""

    def __init__(self, decode: Callable[[bytes], Any], size: int = 256) -> None:
        self._decode = decode
        self._size = size
        self._values: dict[bytes, Any] = {}

    def __call__(self, payload: bytes) -> Any:
        if type(payload) is not bytes:  # only bytes are hashable keys; decode anything else
            return self._decode(payload)
        value = self._values.get(payload)
        if value is None:
            value = self._decode(payload)
            if len(self._values) >= self._size:
                self._values.clear()
            self._values[payload] = value
        return value


#: mailbox class -> the process's memo of its decoder (:class:`DecodeMemo`)
MEMOS: dict[str, DecodeMemo] = {cls: DecodeMemo(decode) for cls, decode in DECODERS.items()}


def _stamped(decode: Callable[[bytes], Any]) -> Callable[[bytes], tuple[Any, float]]:
    """A decoder that also keeps the local reception time (taken on Zenoh's thread)."""

    def run(payload: bytes) -> tuple[Any, float]:
        return decode(payload), time.monotonic()

    return run


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


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
        self.role = LeaderRole(cfg.formation, cfg.leader, p) if cfg.leader is not None else None
        self._member_keys: dict[str, str] = {}  # leader: member -> its state key
        if self.role is not None:
            self._member_keys = {m: keys.state_key(p, m) for m in self.role.members
                                 if m != cfg.robot_id}
            missing = [m for m in self.role.members
                       if m != cfg.robot_id and keys.state_key(p, m) not in self.neighbour_keys]
            if missing:
                raise ValueError(f"leader: {cfg.robot_id} is not adjacent to member {missing[0]}")
        self.subscribed_keys = self._subscription_keys()
        self.nav = NavPart(cfg, leader=self.role is not None)  # routes, goals, plan, status
        # counters
        self.ticks = 0
        self.overruns = 0
        self.deadline_ticks = 0  # real time: ticks with no new pose for DEADLINE_PERIODS periods
        self.early_poses = 0  # real time: poses not ticked on, too soon (agent.schedule.pose_due)
        self.stale = 0
        self.waiting = 0  # ticks before the first pose arrived (zero command, not stale)
        self.lockstep_timeouts = 0
        self.inflated = 0  # leader ticks that used another formation's stale ellipse, inflated
        self.stale_why: dict[str, int] = {}  # stale ticks by the input that was stale
        # the one stamp check (wire.stamps) at every mailbox: rejections per class and reason
        self.stamps = StampCounter()
        self.lockstep_catch_ups = 0  # lock-step: future frames taken after the world went on
        self.implausible: dict[str, int] = {}  # inputs refused as physically impossible, by class
        self._implausible_pending: set[str] = set()  # classes refused since the last tick
        self._speed = speed_bound(cfg.control)  # [m/s] plausibility bound
        self.obstacle_memory = ObstacleMemory()
        self.obstacle_held_ticks = 0  # ticks that avoided an obstacle missing from the list
        self.hard = HardRowCounter()  # ticks on which a hard row was not met
        self._pose_period = cfg.pose_period or cfg.period  # [s] how often poses really come
        # the receiver's clock: simulated (the frame it is on) in lock-step, wall time otherwise
        self._frame = options.sim_start
        self._tolerance = (LOCKSTEP_AHEAD_PERIODS * cfg.period if options.lockstep
                           else cfg.clock_tolerance)
        validate_window(self._tolerance, cfg.stale_after)
        self._last_pose_used: float | None = None
        self.fault_dropped = {cls: 0 for cls in (keys.STATE, keys.ELLIPSE, keys.OTHERS)}
        self.fault_delayed = 0
        self._lost: dict[str, float] = {}  # key -> newest stamp lost to fault injection
        self._late: set[str] = set()  # lock-step: keys whose last wait timed out
        self._lag = lag(options.faults.delay, cfg.period)
        self._delay_line: DelayLine | None = None
        self.status_counts = {STATUS_RELAXED: 0, STATUS_FALLBACK: 0, STATUS_FAILED: 0}
        self._solve = make_solver(cfg.solver)  # the config's QP solver (exact by default)
        self.solves = 0
        self.escape_ticks = 0  # ticks whose nominal was the formation-level escape
        # the newest STATS_WINDOW samples only, so a long-running agent's memory stays bounded
        self.solve_us: deque[float] = deque(maxlen=STATS_WINDOW)
        self.pose_age_us: deque[float] = deque(maxlen=STATS_WINDOW)  # [us] real time: pose
        # reception -> tick start
        self.pose_in_us: deque[float] = deque(maxlen=STATS_WINDOW)  # [us] real time: pose stamp
        # -> reception (wall clock; the bench's split of the latency)
        self.tick_us: deque[float] = deque(maxlen=STATS_WINDOW)  # [us] from tick start (or pose
        # arrival) to cmd put
        self.min_h = {"formation": math.inf, "obstacle": math.inf, "formations": math.inf}
        self.trace: list[tuple] = []
        self.ellipse_trace: list[tuple] = []  # leader: (stamp, *Ellipse) per tick
        self.last_u = (0.0, 0.0)
        self.last_stamp = 0.0
        self._cpu0 = time.process_time()
        self._wall0 = time.monotonic()
        self._session: zenoh.Session | None = None
        self._subs: list[Any] = []
        self._sub_by_key: dict[str, Any] = {}  # subscribed key -> its subscriber
        self._rings: list[tuple[Any, Callable[[zenoh.Sample], None]]] = []  # polled subscribers
        # real time on pose arrival: inline mailboxes, ring channels drained by the tick
        self._polled = not options.lockstep and options.tick_on_pose
        self._pubs: dict[str, CountingPublisher] = {}
        self._diag: DiagPublisher | None = None
        self._base: Base | None = None  # a real robot base adapter (agent.base), when cfg.base is not "world"
        self._stall = Stall()  # this member's copy of its formation's jam state
        self._boxes: dict[str, Mailbox] = {}
        self._arrived: asyncio.Event | None = None
        self._stop: asyncio.Event | None = None
        self._own_others: Others | None = None
        self._tick_point: tuple[float, float, float, float] | None = None
        # real time on pose arrival: ticks run on Zenoh's thread or the loop, one at a time
        self._tick_lock = threading.Lock()
        self._closing = False  # set (under the lock) when close() starts: no more ticks
        self.zero_sent = False  # the zero command of the way out has been published
        self._pose_anchor: float | None = None  # the camera's schedule (agent.schedule.pose_due)
        self._last_tick = -math.inf  # [s, monotonic] when the last tick of any kind started
        self._loop: asyncio.AbstractEventLoop | None = None
        # real time on pose arrival under an agent host (agent.host): its one tick thread, on
        # which a pose callback queues this node instead of ticking on Zenoh's thread
        self.tick_worker: TickQueue | None = None
        # fault containment (leader.succession): the leader holds a liveliness token; its
        # successor watches it and takes the role of a standing formation when it goes
        self.acting = False  # this successor leads now, for a dead leader
        self.takeovers = 0  # times this successor led at least one tick for a dead leader
        self.acting_ticks = 0
        self._acting_since_tick = False
        self._token: Any = None
        # leader.listen: the other formations whose ellipse is subscribed to (all in lock-step;
        # in real time none at the start, then those near), the set the last tick asked for,
        # the stamp of the last beacon put
        self.listening: frozenset[str] = frozenset(
            self.role.other_keys.values()) if self.role is not None and options.lockstep \
            else frozenset()
        self._listen_want: frozenset[str] | None = None
        self.beacon_stamp: float | None = None
        self.listen_changes = 0  # subscription changes made for leader.listen
        self._quiet: dict[str, float] = {}  # formation -> leader.listen.quiet_until

    # --- what is accepted ---------------------------------------------------------------------

    def _now(self) -> float:
        """The receiver's clock for the stamp check: the frame it is on in lock-step (simulated
        time), the wall clock otherwise (stamps are the camera's ``time.time()``)."""
        return self._frame if self.options.lockstep else time.time()

    def _acceptor(self, cls: str) -> Callable[[str, tuple[Any, float], tuple[Any, float] | None],
                                              bool]:
        """The mailbox's ``accept`` for class ``cls``: the stamp check (future, stale, older than
        the one kept; counted per reason), then plausibility against the one kept (counted;
        the next tick commands zero). Runs where the mailbox stores: the loop's thread, or
        under the tick lock."""
        counter, stale_after = self.stamps, self.cfg.stale_after

        def accept(_key: str, value: tuple[Any, float], prev: tuple[Any, float] | None) -> bool:
            msg = value[0]
            last = None if prev is None else prev[0].stamp
            now = self._now()
            reason = check_stamp(now, msg.stamp, last, self._tolerance, stale_after)
            if reason == FUTURE and self._starved():
                reason = None  # lock-step: the world went on without this agent; catch up
                self.lockstep_catch_ups += 1
            if reason is not None:
                counter.count(cls, reason)
                return False
            # plausible after the kept message while that one is fresh; a stale one says nothing
            # any more (a robot carried elsewhere, or a forged first pose: it blocks for at most
            # stale_after)
            ref = None if prev is None or now - prev[0].stamp > stale_after else prev[0]
            if not self._plausible(cls, msg, ref):
                self.implausible[cls] = self.implausible.get(cls, 0) + 1
                self._implausible_pending.add(cls)
                logger.info("%s: implausible %s refused", self.cfg.robot_id, cls)
                return False
            return True

        return accept

    def _starved(self) -> bool:
        """Lock-step: this agent has ticked before but not for ``lockstep_timeout``: the world
        stopped waiting for it (it was late) and its frames may now run more than the window
        ahead; the next one is taken (counted ``lockstep_catch_ups``), not refused for ever."""
        return (self.options.lockstep and self.ticks > 0
                and time.monotonic() - self._last_tick > self.options.lockstep_timeout)

    def _plausible(self, cls: str, msg: Any, prev: Any | None) -> bool:
        """Whether ``msg`` is physically possible after ``prev`` (agent.plausibility)."""
        speed = self._speed
        if cls == keys.POSE:
            return prev is None or jump_ok(prev.x, prev.y, prev.stamp, msg.x, msg.y, msg.stamp,
                                           speed, JUMP_MARGIN_M)
        if cls == keys.STATE:
            if not velocity_ok(msg.ux, msg.uy, speed):
                return False
            return prev is None or jump_ok(prev.x, prev.y, prev.stamp, msg.x, msg.y, msg.stamp,
                                           speed, JUMP_MARGIN_M)
        if cls in (keys.ELLIPSE, keys.BEACON):
            return velocity_ok(msg.vx, msg.vy, speed)
        if cls == keys.OTHERS:
            return ellipses_ok(msg.ellipses, speed) and (
                msg.own is None or velocity_ok(msg.own.vx, msg.own.vy, speed))
        return True

    # --- wiring ------------------------------------------------------------------------------

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
        if self.role is None:
            subs[self.others_key] = keys.OTHERS
        elif self.options.lockstep:  # both topologies: the tie-break and the jam rule read them
            for k in self.role.other_keys:
                subs[k] = keys.ELLIPSE
        else:  # real time: every beacon; an ellipse once its formation is near (leader.listen)
            subs[keys.all_formations_key(self.cfg.prefix, keys.BEACON)] = keys.BEACON
        subs[self.obstacles_key] = keys.OBSTACLES
        subs[self.pose_key] = keys.POSE  # last: once the pose is matched, all else is declared
        return subs

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        """Open the session, declare publishers and the exact subscriptions."""
        self._arrived = asyncio.Event()
        self._stop = self._stop or asyncio.Event()
        self._loop = loop
        self._session = s = self._open_session()
        pub_keys = [self.state_key, self.cmd_key]
        if self.role is not None:
            pub_keys += [self.role.others_key, self.role.ellipse_key]
            if not self.options.lockstep:  # real time: leader.listen's beacon
                pub_keys.append(self.role.beacon_key)
        for k in pub_keys:
            self._pubs[k] = CountingPublisher(s.declare_publisher(k), self.counter)
        self._diag = DiagPublisher(s, self.cfg.prefix, self.cfg.robot_id, self.cfg.formation,
                                   self.cfg.goal)
        self.nav.open(s, self.counter)
        if self.cfg.base != "world":
            # A real robot base (TurtleBot3 behind zenoh-bridge-ros2dds): every command also goes
            # to its cmd_vel key as CDR; the cmd key stays for monitoring.
            self._base = make_base(self.cfg, s)
        faults = self.options.faults
        if faults.delay > 0 and self.options.lockstep:
            self._delay_line = DelayLine(faults.delay, partial(offer, self))
        for k, cls in list(self.subscribed_keys.items()):
            self._declare_subscriber(k, cls)
        self._declare_succession(s, loop)
        logger.info("%s: subscribed to %s", self.cfg.robot_id, ", ".join(self.subscribed_keys))

    def _declare_subscriber(self, k: str, cls: str) -> None:
        """Subscribe to ``k`` into the mailbox of class ``cls`` (made on first use), from
        :meth:`open` and for a successor taking the leader role. Real time on pose arrival
        (``_polled``): every mailbox is inline, fed under the tick lock by the tick that drains
        the ring channels and by the pose callback, which ticks right on the Zenoh thread that
        received the pose (:func:`agent.schedule.on_pose_sample`). Otherwise a callback stores
        on the loop and wakes the tick."""
        self._install_subscriber(k, cls, *self._make_subscriber(k, cls, self._mailbox(cls)))

    def _mailbox(self, cls: str) -> Mailbox:
        """The mailbox of class ``cls``, made on first use (inline when polled)."""
        box = self._boxes.get(cls)
        if box is None:
            box = self._boxes[cls] = Mailbox(None if self._polled else self._loop,
                                             _stamped(MEMOS[cls]), counter=self.counter,
                                             accept=self._acceptor(cls))
        return box

    def _make_subscriber(self, k: str, cls: str, box: Mailbox
                         ) -> tuple[Any, Callable[[zenoh.Sample], None] | None]:
        """Declare the subscriber of ``k`` into ``box``: (subscriber, the take of its ring
        channel, None when it has a callback). Touches no state a tick reads, so it may run
        outside the tick lock (:func:`agent.leader_step.relisten`)."""
        s, polled = self._session, self._polled
        assert s is not None and self._loop is not None  # set by open()
        if polled and cls != keys.POSE:
            cap = RING_CAPACITY
            if self.all_to_all and cls == keys.STATE:  # one wildcard for every robot's state
                cap *= max(1, len(self.foreign_keys) + len(self.neighbour_keys))
            if cls == keys.BEACON and self.role is not None:  # every formation's, one wildcard
                cap = max(cap, 2 * (len(self.role.other_keys) + 1))
            return (s.declare_subscriber(k, zenoh.handlers.RingChannel(cap)),
                    self._handler(cls, box, notify=False))
        if polled:  # the pose: tick right on the Zenoh thread that received it
            return s.declare_subscriber(
                k, zenoh.handlers.Callback(partial(on_pose_sample, self), indirect=False)), None
        return s.declare_subscriber(k, self._handler(cls, box)), None

    def _install_subscriber(self, k: str, cls: str, sub: Any,
                            take: Callable[[zenoh.Sample], None] | None) -> None:
        """Record a subscriber :meth:`_make_subscriber` declared (under the tick lock once
        ticks run: a ring channel joins the ones the tick drains)."""
        if take is not None:
            self._rings.append((sub, take))
        self._subs.append(sub)
        self._sub_by_key[k] = sub
        self.subscribed_keys[k] = cls

    def _forget_subscriber(self, k: str) -> Any:
        """Under the tick lock: stop draining and recording the subscriber of ``k``; it is
        returned for the caller to undeclare (outside the lock). Its mailbox keeps what came."""
        sub = self._sub_by_key.pop(k)
        self._rings = [r for r in self._rings if r[0] is not sub]
        self._subs.remove(sub)
        del self.subscribed_keys[k]
        return sub

    def _handler(self, cls: str, box: Mailbox, notify: bool = True
                 ) -> Callable[[zenoh.Sample], None]:
        """A subscriber's callback: the sample to ``box`` (through :class:`LinkFaults` for a
        faulted class) and, with ``notify``, a wake-up of the loop's tick."""
        loop = self._loop
        assert loop is not None  # set by open()
        decode = DECODERS[cls]
        faulty = self.options.faults.applies_to(cls)

        def on_sample(sample: zenoh.Sample) -> None:
            if faulty and sample.kind != zenoh.SampleKind.DELETE:
                faulty_sample(self, loop, cls, decode, str(sample.key_expr),
                              sample.payload.to_bytes())
            else:
                box.callback(sample)
            if not notify:
                return
            try:
                loop.call_soon_threadsafe(self._on_arrival, str(sample.key_expr))
            except RuntimeError:  # loop closed: shutting down
                pass

        return on_sample

    def _declare_succession(self, s: zenoh.Session, loop: asyncio.AbstractEventLoop) -> None:
        """The leader holds its formation's liveliness token; the successor watches it."""
        token_key = leader_token_key(self.cfg.prefix, self.cfg.formation)
        if self.role is not None:
            self._token = s.liveliness().declare_token(token_key)
            return
        if self.cfg.standby is None:
            return

        def on_token(sample: zenoh.Sample) -> None:
            alive = sample.kind == zenoh.SampleKind.PUT
            try:
                loop.call_soon_threadsafe(on_leader_token, self, alive)
            except RuntimeError:  # loop closed: shutting down
                pass

        self._subs.append(s.liveliness().declare_subscriber(token_key, on_token, history=True))

    def _open_session(self) -> zenoh.Session:
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

    def _close_session(self, session: zenoh.Session) -> None:
        """Close what :meth:`_open_session` opened."""
        session.close()

    def _on_arrival(self, key: str) -> None:
        """Loop thread: something arrived on ``key`` (its publisher is alive): wake the tick."""
        self._late.discard(key)
        if self._arrived is not None:
            self._arrived.set()

    def close(self, step_limit: float = STEP_LIMIT_S) -> None:
        """Zero command, undeclare, close the session (idempotent). Every step waits at most
        ``step_limit`` seconds (:func:`runtime.shutdown.within`): a step that hangs (a router that
        is gone) is logged and left behind, and closing goes on, zero command first."""
        rid = self.cfg.robot_id
        got = self._tick_lock.acquire(timeout=step_limit)  # a tick in progress ends first
        self._closing = True  # no tick starts after this
        if got:
            self._tick_lock.release()
        else:
            logger.warning("%s: a tick still runs after %.1f s: closing anyway", rid, step_limit)
        if self._session is None:
            return

        def zero() -> None:
            self._put_cmd(Cmd(0.0, 0.0, 0.0, 0.0, self.last_stamp))
            self.zero_sent = True

        within(step_limit, f"{rid}: zero command on exit", zero)
        token, self._token = self._token, None
        handles = [*([] if token is None else [token]), *self._subs, *self._pubs.values()]
        within(step_limit, f"{rid}: undeclaring {len(handles)} tokens, subscribers and publishers",
               lambda: undeclare_all(handles))
        self.nav.close(self.last_stamp)
        if self._base is not None:
            base = self._base  # zero velocity on the real base, then undeclare
            within(step_limit, f"{rid}: stopping the base", base.stop)
            self._base = None
        self._subs.clear()
        self._sub_by_key.clear()
        self._rings.clear()
        self._pubs.clear()
        session, self._session = self._session, None
        within(step_limit, f"{rid}: closing the Zenoh session", lambda: self._close_session(session))

    def emergency_zero(self) -> bool:
        """From any thread and without the tick lock (a shutdown that overran its time limit):
        publish the zero command unless :meth:`close` already did. True once it is sent."""
        if self.zero_sent:
            return True
        pub = self._pubs.get(self.cmd_key)
        if pub is None:
            return False
        try:
            pub.put_message(Cmd(0.0, 0.0, 0.0, 0.0, self.last_stamp))
            if self._base is not None:
                self._base.send(0.0, 0.0, self.last_stamp)
        except Exception:  # noqa: BLE001 - last resort: report, the caller exits anyway
            logger.exception("%s: emergency zero command failed", self.cfg.robot_id)
            return False
        self.zero_sent = True
        return True

    # --- life --------------------------------------------------------------------------------

    async def run(self, stop: asyncio.Event) -> None:
        """Open, tick until ``stop`` is set, close."""
        self._stop = stop
        loop = asyncio.get_running_loop()
        try:
            # inside the try: a session opened by an open() that fails half-way is closed too
            await loop.run_in_executor(None, self.open, loop)
            freeze_startup()  # no full collection of start-up's objects mid-run (runtime.heap)
            if self.options.lockstep:
                await lockstep_loop(self)
            elif self.options.tick_on_pose:
                await pose_loop(self)
            else:
                await realtime_loop(self)
        finally:
            self.close()

    # --- one tick ----------------------------------------------------------------------------

    def _latest(self, cls: str, key: str) -> tuple[Any, float] | None:
        box = self._boxes.get(cls)
        return None if box is None else box.latest(key)

    def _fresh(self, entry: tuple[Any, float] | None, t: float | None) -> TypeGuard[tuple[Any, float]]:
        """Whether a (message, receive time) entry is fresh for the tick at pose stamp ``t``
        (lock-step) or now (real time: by its stamp against the wall clock, not by when it
        arrived): the stale part of :func:`wire.stamps.check_stamp` (future stamps and older
        ones never reach a mailbox)."""
        if entry is None:
            return False
        now = time.time() if t is None else t
        return now - entry[0].stamp <= self.cfg.stale_after + 1e-9

    async def tick(self, t: float | None) -> StepResult | None:
        """One control tick; ``t`` is the pose stamp in lock-step, ``None`` in real time.

        Lock-step publishes ``state`` first (with the previous tick's velocity), because the
        neighbours and the leader wait for it; real time publishes it after the command, with
        the velocity just certified (zero after a stale tick), the freshest it can share."""
        self.ticks += 1
        self._tick_point = None
        try:
            res = await self._tick(t)
            if self._diag is not None:  # viewers' diagnostics: a few a second, not counted
                self._diag.tick(self, res)
            return res
        finally:
            if t is None and self._tick_point is not None:
                px, py, stamp, th = self._tick_point
                self._pubs[self.state_key].put_message(State(px, py, *self.last_u, stamp, th))

    async def _tick(self, t: float | None) -> StepResult | None:
        cfg = self.cfg
        if t is not None:
            if self._delay_line is not None:
                self._delay_line.advance(t)
                await asyncio.sleep(0)  # let the mailboxes store what was just released
            await wait_current(self, [(keys.POSE, self.pose_key)], t)
        pose_entry = self._latest(keys.POSE, self.pose_key)
        if pose_entry is None:  # not localised yet (start-up): zero, counted apart from stale
            self.waiting += 1
            self._put_cmd(Cmd(0.0, 0.0, 0.0, 0.0, self.last_stamp if t is None else t))
            return None
        if not self._fresh(pose_entry, t) or (t is not None and pose_entry[0].stamp < t - EPS):
            self._zero(t, "pose")  # lock-step: no pose in this frame (camera dropout)
            return None
        pose: Pose = pose_entry[0]
        if check_stamp(self._now() if t is None else t, pose.stamp, self._last_pose_used,
                       self._tolerance, cfg.stale_after) is not None:
            self._zero(t, "pose")  # (cannot happen: the mailbox keeps stamps in order)
            return None
        self._last_pose_used = pose.stamp
        if t is None:
            self.pose_age_us.append((time.monotonic() - pose_entry[1]) * 1e6)
            # pose stamp -> received, on this machine's wall clock (bench: one clock for all)
            self.pose_in_us.append((time.time() - (time.monotonic() - pose_entry[1])
                                    - pose.stamp) * 1e6)
        stamp = pose.stamp
        self.last_stamp = stamp
        ts = stamp if t is not None else None  # lock-step freshness reference
        off = cfg.control.offset
        px, py = control_point(pose.x, pose.y, pose.theta, off) if cfg.control.unicycle \
            else (pose.x, pose.y)
        self._tick_point = (px, py, stamp, pose.theta)
        if t is not None:  # lock-step: neighbours and the leader wait for this tick's state
            self._pubs[self.state_key].put_message(State(px, py, *self.last_u, stamp, pose.theta))

        state_keys = self._state_keys
        others_ready = True
        if self.role is not None:
            others_ready = await lead(self, px, py, stamp, ts)
        if t is not None:
            await wait_current(self, self._tick_inputs(state_keys), stamp)

        fresh = self._fresh_inputs(state_keys, ts, others_ready)
        if isinstance(fresh, str):
            self._zero(t, fresh)
            return None
        states, obstacles, others_msg = fresh
        obs = self._obstacles(obstacles, stamp if t is not None else time.time(), px, py)
        if self._implausible_pending:  # an input broke physics since the last tick
            self._implausible_pending.clear()
            self._zero(t, IMPLAUSIBLE)
            return None
        shapes = self.nav.update_shapes(obstacles.shapes)
        own = None if others_msg.own is None else msg_to_ellipse(others_msg.own)
        target, waypoint = self.nav.follower.goal, cfg.formation_goal
        if own is not None:  # walk the route (the leader takes new goals first)
            target, waypoint = self.nav.step(stamp, t is not None, own.cx, own.cy)
        states = self._at_stamp(states, stamp, t)
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
        res = control_step(cfg.control, (pose.x, pose.y, pose.theta), target, inputs.neighbours,
                           obs, inputs.others, inputs.view, self._solve, inputs.pairwise,
                           inputs.partners, self.last_u, inputs.hazards, shapes=shapes,
                           clock=time.perf_counter_ns, footprint=cfg.footprint)
        if t is None and time.time() - stamp > cfg.stale_after:
            self._zero(t, POSE_AT_SEND)  # never send a command from a pose gone stale
            return None
        if self.role is not None:
            stall = self._stall
            self.nav.report(stamp, stall.still >= STALLED_AFTER_S or stall.retreat > 0.0, False)
        self._put_cmd(Cmd(res.v, res.omega, res.ux, res.uy, stamp))
        self.last_u = (res.ux, res.uy)
        self._record(res, stamp)
        return res

    def _at_stamp(self, states: dict[str, State], stamp: float, t: float | None
                  ) -> dict[str, State]:
        """Real time (``t`` None): every neighbour's state carried from its stamp to ``stamp``
        (this tick's pose) under its certified command (:func:`agent.inputs.predict_state`),
        never further than the stale limit, never backwards. Lock-step: unchanged (every state
        is this frame's)."""
        if t is not None:
            return states
        out = {}
        for k, m in states.items():
            age = min(max(0.0, stamp - m.stamp), self.cfg.stale_after)
            if age > 0.0:
                x, y, th = predict_state(m.x, m.y, m.ux, m.uy, m.theta, age,
                                         self.cfg.control.offset)
                m = State(x, y, m.ux, m.uy, stamp, th)
            out[k] = m
        return out

    def _fresh_inputs(self, state_keys: tuple[str, ...], ts: float | None, others_ready: bool
                      ) -> tuple[dict[str, State], Obstacles, Others] | str:
        """Every input of the step if all are fresh (``ts``: lock-step reference stamp), else
        the name of the first stale one (the reason counted for the zero command)."""
        states: dict[str, State] = {}
        for k in state_keys:
            entry = self._latest(keys.STATE, k)
            if not self._fresh(entry, ts):
                return "state"
            states[k] = entry[0]
        obs_entry = self._latest(keys.OBSTACLES, self.obstacles_key)
        if not self._fresh(obs_entry, ts):
            return "obstacles"
        if self.role is not None:
            if not others_ready or self._own_others is None:
                return "ellipse"
            return states, obs_entry[0], self._own_others
        entry = self._latest(keys.OTHERS, self.others_key)
        if not self._fresh(entry, ts):
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
            self.obstacle_held_ticks += 1
            obs += [held_obstacle(o, age, px, py) for o, age in held]
        return obs

    def _record(self, res: StepResult, stamp: float) -> None:
        """Count a solved step: statuses, lowest barrier values, hard rows not met, solve time,
        trace row."""
        self.hard.add(res)
        self.solves += 1
        self.escape_ticks += res.escape
        self.solve_us.append(res.solve_us)
        if res.status in self.status_counts:
            self.status_counts[res.status] += 1
        self.min_h["formation"] = min(self.min_h["formation"], res.h_formation)
        self.min_h["obstacle"] = min(self.min_h["obstacle"], res.h_obstacle)
        self.min_h["formations"] = min(self.min_h["formations"], res.h_formations)
        if self.options.trace:
            self.trace.append((stamp, res.px, res.py, res.ux, res.uy, res.v, res.omega, res.status,
                               res.slack, res.h_formation, res.h_obstacle, res.h_formations,
                               res.solve_us))

    def _tick_inputs(self, state_keys: tuple[str, ...]) -> list[tuple[str, str]]:
        inputs = [(keys.STATE, k) for k in state_keys]
        inputs.append((keys.OBSTACLES, self.obstacles_key))
        if self.role is None:
            inputs.append((keys.OTHERS, self.others_key))
        return inputs

    def _zero(self, t: float | None, why: str) -> None:
        self.stale_why[why] = self.stale_why.get(why, 0) + 1
        self.stale += 1
        self.last_u = (0.0, 0.0)
        stamp = t if t is not None else self.last_stamp
        self._put_cmd(Cmd(0.0, 0.0, 0.0, 0.0, stamp))
        if self.role is not None:
            self.nav.report(stamp, False, True)
        logger.debug("%s: stale %s, zero command", self.cfg.robot_id, why)
        if self.options.trace:
            nan = math.nan
            self.trace.append((stamp, nan, nan, 0.0, 0.0, 0.0, 0.0, STATUS_STALE, 0.0,
                               nan, nan, nan, nan))
        return None

    def _put_cmd(self, cmd: Cmd) -> None:
        pub = self._pubs.get(self.cmd_key)
        if pub is not None:
            pub.put_message(cmd)
        if self._base is not None:
            self._base.send(cmd.v, cmd.omega, cmd.stamp)

    # --- counters ----------------------------------------------------------------------------

    def stats(self) -> dict[str, Any]:
        """Every counter, JSON-ready (non-finite numbers as None). The ``*_us_median`` figures
        are over the newest ``stats_window`` ticks (:data:`STATS_WINDOW`); the counts over all."""
        return {
            "robot": self.cfg.robot_id,
            "formation": self.cfg.formation,
            "leader": self.cfg.leader is not None,  # by configuration (see takeovers)
            "acting_leader": self.acting,  # a successor leading for a dead leader at the end
            "lockstep": self.options.lockstep,
            "ticks": self.ticks,
            "overruns": self.overruns,
            "deadline_ticks": self.deadline_ticks,
            "early_poses": self.early_poses,
            "stale": self.stale,
            "waiting": self.waiting,
            "lockstep_timeouts": self.lockstep_timeouts,
            "stale_why": dict(self.stale_why),
            "stamp_rejected": self.stamps.snapshot(),
            "lockstep_catch_ups": self.lockstep_catch_ups,
            "implausible": dict(self.implausible),
            "obstacles_missing": self.obstacle_memory.missing,
            "obstacles_dropped_after_hold": self.obstacle_memory.dropped,
            "obstacle_held_ticks": self.obstacle_held_ticks,
            "hard_row_unmet_ticks": self.hard.ticks,
            "hard_row_unmet": dict(self.hard.by_reason),
            "inflated": self.inflated,
            "listening": sorted(self.listening),  # leader.listen: formations heard every tick
            "listen_changes": self.listen_changes,
            "takeovers": self.takeovers,
            "acting_leader_ticks": self.acting_ticks,
            "nav": self.nav.stats(),
            "fault_dropped": dict(self.fault_dropped),
            "fault_delayed": self.fault_delayed,
            "solves": self.solves,
            "escape_ticks": self.escape_ticks,
            "relaxed": self.status_counts[STATUS_RELAXED],
            "fallback": self.status_counts[STATUS_FALLBACK],
            "failed": self.status_counts[STATUS_FAILED],
            "solve_us_median": statistics.median(self.solve_us) if self.solve_us else None,
            "tick_us_median": statistics.median(self.tick_us) if self.tick_us else None,
            "pose_age_us_median": statistics.median(self.pose_age_us) if self.pose_age_us else None,
            "pose_in_us_median": statistics.median(self.pose_in_us) if self.pose_in_us else None,
            "stats_window": STATS_WINDOW,  # the four medians above are over the newest ticks
            "min_h": {k: _finite_or_none(v) for k, v in self.min_h.items()},
            "dropped": {cls: box.dropped_malformed for cls, box in self._boxes.items()},
            "rejected": {cls: box.rejected for cls, box in self._boxes.items()},
            "received": {cls: box.received for cls, box in self._boxes.items()},
            "subscriptions": sorted(self.subscribed_keys),
            "traffic": self.counter.snapshot(),
            "cpu_s": time.process_time() - self._cpu0,
            "wall_s": time.monotonic() - self._wall0,
            "trace_columns": list(TRACE_COLUMNS),
            "trace": [[_finite_or_none(v) if isinstance(v, float) else v for v in row]
                      for row in self.trace],
            "ellipse_trace": [list(row) for row in self.ellipse_trace],
        }

