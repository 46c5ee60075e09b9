"""One robot's agent process: Zenoh inputs -> a control tick (:mod:`agent.tick`) -> Zenoh outputs.

The node is thin: it keeps the latest decoded message per key (a :class:`wire.traffic.Mailbox`
per key class, fed from Zenoh's threads through ``loop.call_soon_threadsafe``) and, each tick,
hands the controller the same inputs the in-process simulator builds
(:mod:`simulator.inprocess`): the neighbours' control points and last certified velocities from
their ``state``, the obstacles, the other formations' ellipses and a
:class:`agent.control.FormationView` of its own formation's ellipse, both from its leader's
``others`` message. The leader robot's node also runs :class:`leader.role.LeaderRole`.

Subscriptions are exact keys only: its own ``pose``, its neighbours' ``state``, its leader's
``others`` (members only), the other leaders' ``ellipse`` (leader only, reduced topology) and
``obstacles``. The all-to-all baseline subscribes to every robot's ``state`` with one wildcard.
What one tick does is :class:`agent.tick.Ticker`'s (its module docstring).

Two clocks drive ticks. *Real time* (default): a tick runs as soon as a new pose arrives, on the
Zenoh thread that received it (the pose subscriber's callback is direct, ``indirect=False``), so
the command leaves one solve after the pose with no thread hand-over (each hand-over, Zenoh
thread -> Python callback thread -> event loop, costs CPU and as much latency). Every other input
waits in a Zenoh ring channel and is drained at the start of the tick, so its local reception
time is when the tick drained it. A pose stamped less than ``MIN_SPACING_PERIODS`` after the
camera's schedule is stored but not ticked on (the next one is; counted ``early_poses``), so a
camera faster than 1/period does not raise the tick rate; the spacing goes by the camera's
stamps, not arrival times, so transport jitter never holds a tick back, and the schedule moves
on by a period, so one pose stamped late does not make the next one too soon
(:func:`agent.schedule.pose_due`). When no tick has run for ``DEADLINE_PERIODS`` periods, the
event loop ticks on its deadline anyway (on the pose it has: a silent camera still ends in stale
zero commands; counted ``deadline_ticks``). The loop looks every ``stale_after`` less a deadline
span while ticks come (at least a span), every span after a deadline tick: the longest wait that
still starts the deadline ticks before the last pose is stale, so the zero command comes as early
as if it looked every period, for a fraction of the looks. A lock keeps ticks one at a time
whichever thread runs them, and once :meth:`AgentNode.close` starts no tick runs. A tick longer
than one period counts as an overrun. The tick itself is the same coroutine as in lock-step; in
real time it never suspends (its waits are lock-step only), so :func:`agent.schedule.run_now`
drives it to the end on the calling thread.

The node is wiring; each part owns its state: the inbox (:class:`agent.inbox.Inbox`: mailboxes,
subscribers, stamp and plausibility checks, link faults) over the transport
(:class:`agent.transport.Transport`: the session and what is declared on it), the clock
(:mod:`agent.clock`: what differs between lock-step and real time, so the tick is written
once), the scheduler (:mod:`agent.schedule`: its lock, stamps and timing counters), the tick
(:class:`agent.tick.Ticker`: the tick's memory and counters), the command output
(:class:`agent.transport.CommandOut`) and the leader's part
(:class:`agent.leader_step.LeaderPart`: ellipse, listening, succession).
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

The formation is a value (:class:`agent.config.Membership`: the formation's name, graph,
leader, successor, goals, route and footprint), fixed by the configuration at the start and
replaced at run time by :meth:`AgentNode.regroup` (lifelong operation: a formation of one, a
team, one again). The keys, the subscriptions, the leader part and the navigation are derived
from it by the same code at the start and at each change; a change lands between two ticks (in
lock-step at the start of the next tick), and only the subscriptions that differ are declared
and undeclared.

Malformed or non-finite payloads are dropped and counted per key class. On stop (SIGINT/SIGTERM
in ``python -m agent``) the node publishes a zero command, undeclares everything and closes the
session; :meth:`AgentNode.stats` holds every counter for the launcher.
"""

from __future__ import annotations

import asyncio
import logging
import math
import statistics
import time
from dataclasses import dataclass
from typing import Any

import zenoh

from agent.base import Base, base_limits, base_odom_key, make_base
from agent.clock import STATS_WINDOW, Clock, LockstepClock, RealtimeClock
from agent.config import AgentConfig, Membership, joined, membership_of
from agent.errand import standing_circles
from agent.faults import EPS, LinkFaults
from agent.inbox import RING_CAPACITY, Inbox, Receiver
from agent.leader_step import LeaderPart
from agent.lifepart import LifePart, static_shapes
from agent.navigation import NavPart
from agent.odom_in import FusedFeed, OdomIn
from agent.plausibility import speed_bound
from agent.qp import STATUS_FAILED, STATUS_FALLBACK, STATUS_RELAXED
from agent.replan import plan_pool
from agent.schedule import ClockLoop, LockstepLoop, PoseScheduler, TickGate
from agent.stats import AgentStats
from agent.tick import TRACE_COLUMNS, NodeKeys, Ticker, TickParts, node_keys
from agent.transport import CommandOut, Transport, formation_scope
from leader.succession import leader_token_key
from runtime.heap import freeze_startup
from runtime.shutdown import STEP_LIMIT_S, undeclare_all, within
from wire import keys
from wire.diag import DiagPublisher
from wire.payloads import Cmd
from wire.stamps import LOCKSTEP_AHEAD_PERIODS, LOCKSTEP_WAIT_S, validate_window
from wire.traffic import TrafficCounter, in_order
from wire.zconf import UsrPwdAuth, ZenohSettings, explain_open_failure, read_auth_file

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class NodeOptions:
    lockstep: bool = False  # tick on pose arrival (simulated world) instead of the own clock
    lockstep_timeout: float = LOCKSTEP_WAIT_S  # [s] longest wait for one phase's inputs in lock-step
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


class AgentNode:
    """The agent of one robot; ``await node.run(stop)`` until ``stop`` is set."""

    def __init__(self, cfg: AgentConfig, options: NodeOptions = NodeOptions()) -> None:
        self.cfg = cfg
        self.options = options
        self.counter = TrafficCounter(cfg.prefix)
        self.keys = node_keys(cfg)
        # controller.localisation fused: the agent's own filter (agent.odom_in) feeds its pose
        self.odom_in = (OdomIn(cfg.robot_id, cfg.prefix, cfg.start, cfg.period, options.lockstep)
                        if cfg.localisation == "fused" else None)
        if self.odom_in is not None and cfg.base != "world":  # a ROS 2 base's own odom topic
            self.odom_in.use_ros_base(base_odom_key(cfg), *base_limits(cfg))
        self.gate = TickGate()  # ticks one at a time whichever thread runs them
        tolerance = (LOCKSTEP_AHEAD_PERIODS * cfg.period if options.lockstep
                     else cfg.clock_tolerance)
        validate_window(tolerance, cfg.stale_after)
        self.clock: Clock = (
            LockstepClock(cfg.stale_after, options.lockstep_timeout, options.sim_start,
                          cfg.robot_id, EPS) if options.lockstep
            else RealtimeClock(cfg.stale_after, cfg.control.offset))
        receiver = Receiver(self.clock.now, self.clock.starved, tolerance, cfg.stale_after,
                            speed_bound(cfg.control))
        self.inbox = Inbox(cfg.robot_id, receiver, self.counter, options.faults,
                           (cfg.period, options.lockstep), self.gate.lock,
                           polled=not options.lockstep and options.tick_on_pose)
        self.leader = LeaderPart(cfg, options.lockstep, options.ellipse_hold, options.trace,
                                 self.inbox, self.clock, self.keys.neighbours)
        self.inbox.subscribed_keys.update(self._subscription_keys())
        self.nav = NavPart(cfg, leader=self.leader.leading)  # routes, goals, plan, status
        if self.nav.routes is not None and not options.lockstep:
            plan_pool()  # started before the ticks (agent.replan.plan_pool)
        self.out = CommandOut(cfg.robot_id, self.keys.cmd, self.inbox.note_command)
        self.ticker = Ticker(cfg, self.keys, TickParts(self.clock, self.inbox, self.leader,
                                                       self.nav, self.out),
                             tolerance, options.trace)
        self.ticker.loc = self.leader.loc = self.odom_in
        self.scheduler = self._scheduler()
        self._cpu0 = time.process_time()
        self._wall0 = time.monotonic()
        self._stop: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._pending: AgentConfig | None = None  # a formation to change to (regroup)
        self._staged: AgentConfig | None = None  # lock-step, a fleet robot: subscribed ahead
        self.regroups = 0  # formation changes made
        # a fleet robot: bidding, its errand and the formations they ask for (agent.lifepart)
        self.life = (LifePart(cfg, self.regroup, self._walls, options.faults, self._still)
                     if cfg.lifelong is not None else None)
        self._walls_of: tuple[Any, tuple] = (None, ())
        if self.life is not None:
            self.ticker.before = self._life_tick
            self.ticker.extra_shapes = self.life.load_msgs

    def _scheduler(self) -> LockstepLoop | PoseScheduler | ClockLoop:
        cfg, tick, times = self.cfg, self._tick, self.ticker.times
        if isinstance(self.clock, LockstepClock):
            return LockstepLoop(tick, self.clock, self.inbox, (self.keys.pose, self.keys.obstacles),
                                times)
        if self.options.tick_on_pose:
            return PoseScheduler(tick, self.gate, self.inbox, self.keys.pose, cfg.period,
                                 cfg.pose_period or cfg.period, cfg.stale_after, times)
        return ClockLoop(tick, cfg.period, times)

    # --- read-only views ------------------------------------------------------------------------

    @property
    def subscribed_keys(self) -> dict[str, str]:
        """Every key subscribed to -> the mailbox class that holds it."""
        return self.inbox.subscribed_keys

    @property
    def ticks(self) -> int:
        return self.ticker.counts.ticks

    @property
    def stale(self) -> int:
        return self.ticker.counts.stale

    @property
    def stale_why(self) -> dict[str, int]:
        return self.ticker.counts.stale_why

    @property
    def status_counts(self) -> dict[str, int]:
        return self.ticker.counts.status_counts

    @property
    def dropped_malformed(self) -> int:
        return self.inbox.dropped_malformed

    @property
    def last_stamp(self) -> float:
        """The stamp of the last pose a tick ran on."""
        return self.ticker.last_stamp

    @property
    def transport(self) -> Transport | None:
        """The session and what is declared on it, while open."""
        return self.out.transport

    @transport.setter
    def transport(self, t: Transport | None) -> None:
        self.out.transport = t

    @property
    def base(self) -> Base | None:
        """The real robot base this agent drives (agent.base), when ``cfg.base`` is not "world"."""
        return self.out.base

    def send_command(self, cmd: Cmd) -> None:
        """Publish a command (:meth:`agent.transport.CommandOut.send_command`)."""
        self.out.send_command(cmd)

    # --- wiring ---------------------------------------------------------------------------------

    def _subscription_keys(self, k: NodeKeys | None = None, role: Any = ...) -> dict[str, str]:
        """Every key this node subscribes to -> the mailbox class that holds it (of the keys
        ``k`` and leader role ``role`` given, else this node's own)."""
        k = self.keys if k is None else k
        role = self.leader.role if role is ... else role
        subs: dict[str, str] = {}
        if k.all_to_all:
            subs[keys.all_robots_key(self.cfg.prefix, keys.STATE)] = keys.STATE
        else:
            for n in k.neighbours:
                subs[n] = keys.STATE
            for n in k.partners:  # members that are not graph neighbours (separation)
                subs[n] = keys.STATE
        if role is None:
            subs[k.others] = keys.OTHERS
        elif self.options.lockstep:  # both topologies: the tie-break and the jam rule read them
            for n in role.other_keys:
                subs[n] = keys.ELLIPSE
        else:  # real time: every beacon; an ellipse once its formation is near (leader.listen)
            subs[keys.all_formations_key(self.cfg.prefix, keys.BEACON)] = keys.BEACON
        subs[k.obstacles] = keys.OBSTACLES
        if self.odom_in is None:  # fused: the odometry and the camera's pose feed the filter
            subs[k.pose] = keys.POSE  # last: once the pose is matched, all else is declared
        return subs

    def _ring_caps(self) -> dict[str, int]:
        """Real time: ring channels that hold more than one key's samples (wildcards)."""
        caps = {}
        if self.keys.all_to_all:  # one wildcard for every robot's state
            caps[keys.STATE] = RING_CAPACITY * max(1, len(self.keys.foreign)
                                                   + len(self.keys.neighbours))
        if self.leader.role is not None:  # every formation's beacon, one wildcard
            caps[keys.BEACON] = 2 * (len(self.leader.role.other_keys) + 1)
        return caps

    def open(self, loop: asyncio.AbstractEventLoop) -> None:
        """Open the session, declare publishers and the exact subscriptions."""
        self._stop = self._stop or asyncio.Event()
        self._loop = loop
        if isinstance(self.clock, LockstepClock):
            self.clock.stop = self._stop
        session = self.open_session()
        t = self.out.transport = Transport(session, self.counter)
        for k in [self.keys.state, self.keys.cmd, *self.leader.publish_keys()]:
            t.publisher(k)
        diag = DiagPublisher(session, self.cfg.prefix, self.cfg.robot_id)
        self.ticker.after = lambda res: diag.tick(self, res)  # viewers' diagnostics
        self.nav.open(session, self.counter)
        if self.cfg.base != "world":
            # A real robot base (TurtleBot3 behind zenoh-bridge-ros2dds): every command also goes
            # to its cmd_vel key as CDR; the cmd key stays for monitoring.
            self.out.base = make_base(self.cfg, session)
        sched = self.scheduler
        on_pose = sched.on_sample if isinstance(sched, PoseScheduler) else None
        self.inbox.open(t, loop, on_pose or self.inbox.mailbox(keys.POSE).callback,
                        self._ring_caps())
        for k, cls in list(self.subscribed_keys.items()):
            self.inbox.declare(k, cls)
        if self.odom_in is not None:  # odometry, then the camera's pose last
            feed = FusedFeed(self.odom_in, self.inbox, loop,
                             sched.feed if isinstance(sched, PoseScheduler) else None,
                             self.gate.lock)
            # both called right on the Zenoh thread that received them (indirect=False): one
            # thread per link, so a frame's pose reaches the filter before the odometry after it
            for key, take in ((self.odom_in.odom_key, feed.odom),
                              (self.odom_in.pose_key, feed.camera)):
                t.keep(key, t.declare(key, in_order(take)))
        self.leader.open(t, loop, self.gate)
        if self.life is not None:
            self.life.open(session)
        logger.info("%s: subscribed to %s", self.cfg.robot_id, ", ".join(self.subscribed_keys))

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
        rid, out = self.cfg.robot_id, self.out
        if not self.gate.close(step_limit):  # a tick in progress ends first
            logger.warning("%s: a tick still runs after %.1f s: closing anyway", rid, step_limit)
        t = out.transport
        if t is None:
            return
        within(step_limit, f"{rid}: zero command on exit", lambda: out.zero_on_exit(self.last_stamp))
        if self.life is not None:
            within(step_limit, f"{rid}: closing the order link", self.life.close)
        token = self.leader.take_token()
        handles = [*([] if token is None else [token]), *t.handles()]
        within(step_limit, f"{rid}: undeclaring {len(handles)} tokens, subscribers and publishers",
               lambda: undeclare_all(handles))
        self.nav.close(self.last_stamp)
        if out.base is not None:
            base = out.base  # zero velocity on the real base, then undeclare
            within(step_limit, f"{rid}: stopping the base", base.stop)
            out.base = None
        t.clear()
        self.inbox.close()
        out.transport = None
        within(step_limit, f"{rid}: closing the Zenoh session",
               lambda: self.close_session(t.session))

    def emergency_zero(self) -> bool:
        """From any thread and without the tick lock (a shutdown that overran its time limit):
        publish the zero command unless :meth:`close` already did. True once it is sent
        (:meth:`agent.transport.CommandOut.emergency_zero`)."""
        return self.out.emergency_zero(self.last_stamp)

    # --- the formation, a value replaced at run time -------------------------------------------

    @property
    def membership(self) -> Membership:
        """The formation this agent is in now (:class:`agent.config.Membership`)."""
        return membership_of(self.cfg)

    def regroup(self, membership: Membership) -> None:
        """Change to the formation ``membership`` (a formation of one, a team, one again): the
        keys, the subscriptions, the leader role, the successor's watch and the navigation are
        derived from it the same way as at the start. Refused (ValueError) before anything
        changes when the record is invalid. Not yet open: at once. Lock-step: at the start of
        the next tick (a lock-step tick waits for its inputs midway, so nothing changes under
        it). Real time: on the event loop, between ticks (:meth:`apply_regroup`)."""
        self._pending = joined(self.cfg, membership)
        if self.out.transport is None:
            self.apply_regroup()
        elif not self.options.lockstep and self._loop is not None:
            self._loop.call_soon_threadsafe(self.apply_regroup)

    def _life_tick(self, pose: Any) -> bool:
        """A fleet robot's lifelong part at this tick's pose (:mod:`agent.lifepart`): True to
        stand still."""
        assert self.life is not None
        k = round(pose.stamp / self.cfg.period)
        return self.life.tick(k, (pose.x, pose.y, pose.theta))

    def _walls(self) -> tuple:
        """The walls and shelves of the newest ``obstacles`` message (converted once each)."""
        entry = self.inbox.latest(keys.OBSTACLES, self.keys.obstacles)
        msgs = () if entry is None else entry[0].shapes
        if msgs is not self._walls_of[0]:
            self._walls_of = (msgs, static_shapes(msgs))
        return self._walls_of[1]

    def _still(self) -> tuple[tuple[float, float, float], ...]:
        """The circles of the newest ``obstacles`` message that stand still (centre and Ds)."""
        entry = self.inbox.latest(keys.OBSTACLES, self.keys.obstacles)
        return () if entry is None else standing_circles(entry[0].obstacles)

    async def _tick(self, t: float | None) -> Any:
        """The tick, after a formation change asked for in lock-step (:meth:`regroup`). A fleet
        robot's change takes two ticks: the first declares the new formation's subscriptions,
        the second changes (so that no input of its first tick in the formation was put before
        it was subscribed to: a teammate's state, its leader's ``others``)."""
        if self.options.lockstep:
            if self.life is not None:
                staged, self._staged = self._staged, None
                if staged is not None and self._pending is None:
                    self._pending = staged
                    self.apply_regroup()
                if self._pending is not None:
                    self._staged, self._pending = self._pending, None
                    self._subscribe_ahead(self._staged)
            elif self._pending is not None:
                self.apply_regroup()
        return await self.ticker.tick(t)

    def _subscribe_ahead(self, cfg: AgentConfig) -> None:
        """Lock-step, a fleet robot: declare the subscriptions the formation of ``cfg`` adds, a
        tick before it changes to it (what the old one does not read stays unread till then)."""
        inbox = self.inbox
        if self.out.transport is None:
            return
        role = LeaderPart(cfg, True, self.options.ellipse_hold, False, inbox, self.clock,
                          node_keys(cfg).neighbours).role
        for k, cls in self._subscription_keys(node_keys(cfg), role).items():
            if k not in inbox.subscribed_keys:
                inbox.declare(k, cls)

    def apply_regroup(self) -> None:
        """Apply the formation asked for by :meth:`regroup`, on the loop's thread, as
        :meth:`agent.leader_step.LeaderPart.relisten` changes subscriptions: what a tick reads is
        swapped under the tick lock, subscribers and tokens are declared and undeclared outside
        it (a Zenoh thread waiting to tick never waits on a declaration)."""
        gate, inbox, t = self.gate, self.inbox, self.out.transport
        with gate.lock:
            cfg, self._pending = self._pending, None
            if cfg is None or gate.closing:
                return
            old_cfg, old_leader, old_nav = self.cfg, self.leader, self.nav
            self.cfg, self.keys = cfg, node_keys(cfg)
            self.leader = LeaderPart(cfg, self.options.lockstep, self.options.ellipse_hold,
                                     self.options.trace, inbox, self.clock, self.keys.neighbours)
            self.leader.carry(old_leader)  # counters, trace, deaths known
            self.nav = NavPart(cfg, leader=self.leader.leading)
            want = self._subscription_keys()
            if t is None:  # not open: nothing declared yet
                self._swap_parts()
                inbox.subscribed_keys.clear()
                inbox.subscribed_keys.update(want)
                return
            gone = [inbox.forget(k) for k in list(inbox.subscribed_keys) if k not in want]
            add = [(k, cls) for k, cls in want.items() if k not in inbox.subscribed_keys]
            if old_cfg.leader is None and old_cfg.standby is not None:  # the old watch
                gone.append(t.forget(leader_token_key(old_cfg.prefix, old_cfg.formation)))
            gone += t.forget_publishers(formation_scope(old_cfg.prefix, old_cfg.formation),
                                        self.leader.publish_keys())  # the old formation's puts
            token = old_leader.take_token()
            old_leader.role = None  # leads no more: a relisten it asked for changes nothing
        self._declare(t, old_nav, token, gone, add)

    def _declare(self, t: Transport, old_nav: NavPart, token: Any, gone: list[Any],
                 add: list[tuple[str, str]]) -> None:
        """Outside the tick lock: undeclare the old formation's subscribers, token and
        navigation, declare the new one's; then, under the lock, the ticks use them."""
        rid, inbox, loop = self.cfg.robot_id, self.inbox, self._loop
        assert loop is not None  # set by open()
        within(STEP_LIMIT_S, f"{rid}: undeclaring {len(gone)} subscribers of the old formation",
               lambda: undeclare_all([*([] if token is None else [token]), *gone]))
        old_nav.close(self.last_stamp)
        made = [(k, cls, *inbox.make(k, cls)) for k, cls in add]
        for k in self.leader.publish_keys():
            t.publisher(k)
        self.nav.open(t.session, self.counter)
        if self.nav.routes is not None and not self.options.lockstep:
            plan_pool()
        self.leader.open(t, loop, self.gate)
        with self.gate.lock:
            for k, cls, sub, take in made:
                inbox.install(k, cls, sub, take)
            self._swap_parts()
        logger.info("%s: now in formation %s, subscribed to %s", rid, self.cfg.formation,
                    ", ".join(self.subscribed_keys))

    def _swap_parts(self) -> None:
        """The ticks use this node's keys, leader part and navigation from now on."""
        self.ticker.parts.leader, self.ticker.parts.nav = self.leader, self.nav
        self.ticker.regroup(self.cfg, self.keys)
        self.regroups += 1

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

    # --- counters -------------------------------------------------------------------------------

    def stats(self) -> AgentStats:
        """Every counter, JSON-ready (non-finite numbers as None). The ``*_us_median`` figures
        are over the newest ``stats_window`` ticks (:data:`agent.clock.STATS_WINDOW`); the
        counts over all."""
        tk, sc, ld, inbox = self.ticker, self.scheduler.counts, self.leader, self.inbox
        c = tk.counts
        boxes = inbox.counts()
        return AgentStats(
            robot=self.cfg.robot_id, formation=self.cfg.formation,
            leader=self.cfg.leader is not None,  # by configuration (see takeovers)
            acting_leader=ld.succession.acting,  # a successor leading for a dead leader at the end
            lockstep=self.options.lockstep, ticks=c.ticks, overruns=sc.overruns,
            deadline_ticks=sc.deadline_ticks, early_poses=sc.early_poses, stale=c.stale,
            waiting=c.waiting, lockstep_timeouts=self.clock.timeouts,
            stale_why=dict(c.stale_why), stamp_rejected=inbox.stamps.snapshot(),
            lockstep_catch_ups=inbox.catch_ups, implausible=dict(inbox.implausible),
            obstacles_missing=tk.obstacle_memory.missing,
            obstacles_dropped_after_hold=tk.obstacle_memory.dropped,
            obstacle_held_ticks=c.obstacle_held_ticks, hard_row_unmet_ticks=tk.hard.ticks,
            hard_row_unmet=dict(tk.hard.by_reason), inflated=ld.inflated,
            standing=ld.standing,
            listening=sorted(ld.listen.heard),  # leader.listen: formations heard every tick
            listen_changes=ld.listen.changes, takeovers=ld.succession.takeovers,
            acting_leader_ticks=ld.succession.ticks, nav=self.nav.stats(), goal_refusal=self.nav.refusal,
            fault_dropped=dict(inbox.faults.dropped), fault_delayed=inbox.faults.delayed,
            solves=c.solves, escape_ticks=c.escape_ticks, tick_errors=c.tick_errors,
            reacquired=inbox.reacquired,
            relaxed=c.status_counts[STATUS_RELAXED], fallback=c.status_counts[STATUS_FALLBACK],
            failed=c.status_counts[STATUS_FAILED], solve_us_median=_median(c.solve_us),
            tick_us_median=_median(sc.tick_us), tick_parts_us_median=tk.times.medians(),
            pose_age_us_median=_median(self.clock.pose_age_us),
            pose_in_us_median=_median(self.clock.pose_in_us), stats_window=STATS_WINDOW,
            min_h={k: _finite_or_none(v) for k, v in c.min_h.items()},
            dropped=boxes["dropped"], rejected=boxes["rejected"], received=boxes["received"],
            subscriptions=sorted(self.subscribed_keys), traffic=self.counter.snapshot(),
            cpu_s=time.process_time() - self._cpu0, wall_s=time.monotonic() - self._wall0,
            trace_columns=list(TRACE_COLUMNS),
            trace=[[_finite_or_none(v) if isinstance(v, float) else v for v in row]
                   for row in c.trace],
            ellipse_trace=[list(row) for row in ld.ellipse_trace],
            localisation=None if self.odom_in is None else self.odom_in.stats(),
            lifelong=None if self.life is None else self.life.stats(),
        )
