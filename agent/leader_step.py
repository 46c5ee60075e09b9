"""The leader's part of an agent (:class:`LeaderPart`): its step in each tick (:meth:`lead`:
estimate and publish the formation's ellipse from its members' ``state``, collect the other
leaders' ellipses, a stale one held inflated for up to ``ellipse_hold`` seconds, publish
``others``), which formations it listens to (:mod:`leader.listen`, real time), and fault
containment (:mod:`leader.succession`): a successor takes the role when the leader's liveliness
token goes (:meth:`take_over`; it then estimates the standing formation's ellipse) and gives it
back when the token returns (:meth:`step_down`). A fleet robot (a formation of one) holds the
token of its own formation for as long as its agent runs and watches every other fleet robot's
(:class:`Deaths`): a robot whose token went is a standing body at its last ellipse, or at the
camera's newer pose of it as a formation of one (a robot that died in a team, once the team
dissolved), grown by :func:`leader.succession.standing_grow`, never dropped and never stopped
for (counted ``standing``); a lock-step leader does not wait for its ellipse.

It lives in agent/, not leader/: it reads the agent's inbox and, in lock-step, waits for the
tick's inputs through the clock (:mod:`agent.clock`); the pure estimation is
:class:`leader.role.LeaderRole`'s, and leader/ imports nothing of agent/.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import zenoh

from agent.clock import Clock
from agent.config import AgentConfig
from agent.inbox import Entry, Inbox
from agent.odom_in import OdomIn
from agent.transport import Transport
from geometry.ellipse import Ellipse, Point
from leader.listen import QUIET_MAX_S, beacon_due, grown_gap, hears, quiet_until
from leader.navigation import Follower, at_goal
from leader.role import VIEW_RANGE, LeaderRole, ellipse_to_msg
from leader.succession import (
    LEADER_TOKEN,
    leader_token_key,
    standing_grow,
    stopping_distance,
    token_formation,
)
from runtime.shutdown import STEP_LIMIT_S, undeclare_all, within
from wire import keys
from wire.payloads import EllipseMsg, Others, Pose, State, decode_pose
from wire.reader import DecodeError

logger = logging.getLogger(__name__)

def inflate(m: EllipseMsg, grow: float) -> EllipseMsg:
    """``m`` with both semi-axes grown by ``grow`` [m]: a stale ellipse covering everywhere its
    formation can have gone since (``grow = max_speed * age``); centre, velocities and stamp
    are kept, its member points dropped (they are as old: the members' rows then take the
    ellipse's motion into account as from a formation that sends none, :mod:`agent.body`)."""
    return EllipseMsg(m.formation, m.cx, m.cy, m.alpha, m.a + grow, m.b + grow, m.vx, m.vy,
                      m.alpha_rate, m.stamp)


def standing_body(m: EllipseMsg, grow: float) -> EllipseMsg:
    """A dead formation's last ellipse ``m`` as the body it now is: both semi-axes grown by
    ``grow`` (:func:`leader.succession.standing_grow`), at rest (its base stopped)."""
    return EllipseMsg(m.formation, m.cx, m.cy, m.alpha, m.a + grow, m.b + grow, 0.0, 0.0, 0.0,
                      m.stamp)


def newest(fid: str, *entries: tuple[EllipseMsg, float] | None
           ) -> tuple[EllipseMsg, float] | None:
    """The entry with the newest stamp of those that are of formation ``fid`` (a message that
    names another formation than its key is not trusted), or None."""
    best = None
    for e in entries:
        if e is not None and e[0].formation == fid and (best is None or e[0].stamp > best[0].stamp):
            best = e
    return best


def solo_axes(cfg: AgentConfig) -> tuple[float, float, float] | None:
    """The ellipse (a, b, alpha0) of the formation of one that ``cfg`` leads (None: ``cfg`` is
    not a robot alone): a fleet's robots are of one model, so every other's is the same."""
    s = cfg.leader
    if s is None or cfg.formation != cfg.robot_id or len(s.members) != 1:
        return None
    return (s.axes[0], s.axes[1], s.alpha0)


@dataclass
class Listening:
    """Real time: which other formations the leader hears every tick (:mod:`leader.listen`)."""

    heard: frozenset[str]  # the formations whose ellipse is subscribed to
    want: frozenset[str] | None = None  # the set the last tick asked for, not yet subscribed
    beacon_stamp: float | None = None  # the stamp of the last beacon put
    changes: int = 0  # subscription changes made for leader.listen
    quiet: dict[str, float] = field(default_factory=dict)  # formation -> leader.listen.quiet_until


class Deaths:
    """A fleet robot's knowledge of which other fleet robots' agents are gone (module
    docstring): each fleet robot's agent holds the liveliness token of the formation named by it
    from :meth:`open` to its close, whatever formation it is in; a token that goes is a robot
    known dead until it comes back (a restarted agent). Fed on Zenoh's threads, read by the
    ticks.

    Where a dead robot stands: its last ellipse as a formation of one, or, newer, the camera's
    pose of it (subscribed to from the death's news to its return, on the event loop,
    :meth:`follow`): a robot that died in a team, whose formation of one nobody has heard since
    the team formed, is a standing body too once the team dissolves (:meth:`body`, the ellipse
    of a formation of one, ``axes``, at rest at that pose)."""

    def __init__(self, robot_id: str, robots: tuple[str, ...], prefix: str,
                 axes: tuple[float, float, float] | None = None, offset: float = 0.0) -> None:
        self.robot_id, self.prefix = robot_id, prefix
        self.robots = frozenset(robots) - {robot_id}
        self.axes = axes  # a formation of one's (a, b, alpha0); None: no bodies from poses
        self.offset = offset  # [m] the control point ahead of the body centre
        self._lock = threading.Lock()
        self._gone: dict[str, float | None] = {}  # robot -> clock at its first use dead
        self._poses: dict[str, Pose] = {}  # robot known dead -> the newest pose of it
        self._watch: set[str] = set()  # robots whose pose is subscribed to (on the loop thread)
        self._transport: Transport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._gate: Any = None  # the tick lock and closing flag (agent.schedule.TickGate)
        self.opened = False
        self.heard = 0  # deaths heard (tokens gone)

    def open(self, transport: Transport, loop: asyncio.AbstractEventLoop | None = None,
             gate: Any = None) -> None:
        """Hold this robot's token and watch the others' (once, for the agent's life); with
        ``loop`` and ``gate`` (the tick lock and closing flag), also the poses of the robots
        known dead (:meth:`follow`)."""
        if self.opened:
            return
        self.opened = True
        self._transport, self._loop, self._gate = transport, loop, gate
        live = transport.session.liveliness()
        transport.keep(None, live.declare_token(leader_token_key(self.prefix, self.robot_id)))
        transport.keep(None, self.watch(transport.session))

    def watch(self, session: zenoh.Session) -> Any:
        """Watch the other fleet robots' tokens on ``session`` (their present tokens first):
        the liveliness subscriber, for the caller to undeclare."""
        every = f"{keys.validate_prefix(self.prefix)}/formation/*/{LEADER_TOKEN}"
        return session.liveliness().declare_subscriber(every, self.on_token, history=True)

    def on_token(self, sample: zenoh.Sample) -> None:  # Zenoh thread
        fid = token_formation(self.prefix, str(sample.key_expr))
        if fid is not None and fid in self.robots:
            self.hear(fid, sample.kind == zenoh.SampleKind.PUT)

    def hear(self, robot: str, alive: bool) -> None:
        """The token of ``robot`` came (``alive``) or went."""
        with self._lock:
            if alive:
                self._gone.pop(robot, None)
                self._poses.pop(robot, None)
            elif robot not in self._gone:
                self._gone[robot] = None
                self.heard += 1
        if self._gate is not None and self.axes is not None and (not alive
                                                                  or robot in self._watch):
            try:
                self._loop.call_soon_threadsafe(self.follow, robot)  # type: ignore[union-attr]
            except RuntimeError:  # loop closed: shutting down
                pass

    def follow(self, robot: str) -> None:
        """Loop thread: hear the camera's poses of ``robot`` while it is known dead, and no
        longer once it is back (declared outside any tick, as :meth:`LeaderPart.relisten`)."""
        t, gate = self._transport, self._gate
        with self._lock:
            dead = robot in self._gone
        if t is None or gate is None or gate.closing:
            return
        key = keys.pose_key(self.prefix, robot)
        if dead and robot not in self._watch:
            self._watch.add(robot)
            sub = t.declare(key, lambda sample: self.on_pose(robot, sample))
            with gate.lock:
                if not gate.closing:
                    t.keep(key, sub)
                    return
            within(STEP_LIMIT_S, f"{self.robot_id}: undeclaring the pose of {robot}",
                   lambda: undeclare_all([sub]))
        elif not dead and robot in self._watch:
            self._watch.discard(robot)
            with gate.lock:
                if gate.closing:
                    return
                gone = t.forget(key)
            within(STEP_LIMIT_S, f"{self.robot_id}: undeclaring the pose of {robot}",
                   lambda: undeclare_all([gone]))

    def on_pose(self, robot: str, sample: zenoh.Sample) -> None:  # Zenoh thread
        try:
            pose = decode_pose(sample.payload.to_bytes())
        except DecodeError:
            return
        self.see_pose(robot, pose)

    def see_pose(self, robot: str, pose: Pose) -> None:
        """A pose of ``robot``: kept while it is known dead and newer than the one kept."""
        with self._lock:
            old = self._poses.get(robot)
            if robot in self._gone and (old is None or pose.stamp > old.stamp):
                self._poses[robot] = pose

    def body(self, robot: str) -> EllipseMsg | None:
        """``robot`` known dead as a formation of one at rest at the newest pose of it (None:
        no pose heard, or no formation-of-one axes known); stamped with the pose."""
        if self.axes is None or not self._poses:
            return None
        with self._lock:
            p = self._poses.get(robot)
        if p is None:
            return None
        a, b, alpha = self.axes
        off = self.offset
        return EllipseMsg(robot, p.x + off * math.cos(p.theta), p.y + off * math.sin(p.theta),
                          alpha, a, b, 0.0, 0.0, 0.0, p.stamp)

    def gone(self, robot: str) -> bool:
        """Whether ``robot`` is known dead (its token went and has not come back)."""
        if not self._gone:  # nobody gone: no lock taken
            return False
        with self._lock:
            return robot in self._gone

    def known_at(self, robot: str, now: float) -> float | None:
        """When (the receiver's clock) ``robot`` was first used as known dead, ``now`` the
        first time; None while it is not known dead."""
        if not self._gone:  # nobody gone: no lock taken
            return None
        with self._lock:
            if robot not in self._gone:
                return None
            at = self._gone[robot]
            if at is None:
                self._gone[robot] = at = now
            return at


@dataclass
class Succession:
    """A successor leading for a dead leader (:mod:`leader.succession`)."""

    acting: bool = False  # this successor leads now, for a dead leader
    takeovers: int = 0  # times this successor led at least one tick for a dead leader
    ticks: int = 0  # ticks it led for a dead leader
    counted: bool = False  # this takeover is counted (once it led a tick)


class LeaderPart:
    """The leader's state and step (module docstring); leads nothing unless :attr:`role` is set
    (the configured leader from the start, a successor after :meth:`take_over`)."""

    def __init__(self, cfg: AgentConfig, lockstep: bool, ellipse_hold: float, trace: bool,
                 inbox: Inbox, clock: Clock, neighbour_keys: Mapping[str, Any]) -> None:
        self.cfg = cfg
        self.realtime = not lockstep
        self.ellipse_hold = ellipse_hold
        self.trace = trace
        self._inbox = inbox
        self._clock = clock
        self._neighbour_keys = neighbour_keys
        self.role = LeaderRole(cfg.formation, cfg.leader, cfg.prefix) if cfg.leader is not None \
            else None
        # [m] the goal tolerance of the leader's status (agent.navigation's Navigator): parked
        self.goal_tolerance = cfg.goal_tolerance + cfg.control.offset
        self._member_keys: dict[str, str] = {}  # member -> its state key
        if self.role is not None:
            member_keys = self._adjacent(self.role)
            if member_keys is None:
                raise ValueError(f"leader: {cfg.robot_id} is not adjacent to member "
                                 f"{self._not_adjacent(self.role)[0]}")
            self._member_keys = member_keys
        self.own_others: Others | None = None
        self.loc: OdomIn | None = None  # controller.localisation fused (set by the node)
        self.ellipse_trace: list[tuple] = []  # (stamp, *Ellipse) per tick
        self.inflated = 0  # ticks that used another formation's stale ellipse, inflated
        # leader.listen: the other formations whose ellipse is subscribed to (all in lock-step;
        # in real time none at the start, then those near)
        self.listen = Listening(frozenset(self.role.other_keys.values())
                                if self.role is not None and lockstep else frozenset())
        self.succession = Succession()  # fault containment (leader.succession)
        # a fleet robot: the other fleet robots known dead (carried over a regroup, :meth:`carry`)
        self.deaths = (Deaths(cfg.robot_id, cfg.lifelong.fleet.robot_ids, cfg.prefix,
                              solo_axes(cfg), cfg.control.offset)
                       if cfg.lifelong is not None else None)
        self.standing = 0  # ticks that used a dead formation's standing body
        self._standing_now: set[str] = set()  # this tick: the formations used as standing bodies
        self._token: Any = None
        self._transport: Transport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._gate: Any = None

    @property
    def leading(self) -> bool:
        return self.role is not None

    def carry(self, old: LeaderPart) -> None:
        """A regroup: keep the counters, the trace and the deaths known of ``old``."""
        self.ellipse_trace, self.inflated, self.standing = (old.ellipse_trace, old.inflated,
                                                            old.standing)
        if old.deaths is not None:
            self.deaths = old.deaths

    def _not_adjacent(self, role: LeaderRole) -> list[str]:
        p, rid = self.cfg.prefix, self.cfg.robot_id
        return [m for m in role.members
                if m != rid and keys.state_key(p, m) not in self._neighbour_keys]

    def _adjacent(self, role: LeaderRole) -> dict[str, str] | None:
        """Every member's state key (None if one is not this robot's neighbour)."""
        if self._not_adjacent(role):
            return None
        return {m: keys.state_key(self.cfg.prefix, m) for m in role.members
                if m != self.cfg.robot_id}

    # --- wiring ---------------------------------------------------------------------------------

    def publish_keys(self) -> list[str]:
        """The keys the leader publishes on (none for a member)."""
        if self.role is None:
            return []
        out = [self.role.others_key, self.role.ellipse_key]
        return out + [self.role.beacon_key] if self.realtime else out  # leader.listen's beacon

    def open(self, transport: Transport, loop: asyncio.AbstractEventLoop, gate: Any) -> None:
        """The leader holds its formation's liveliness token; the successor watches it.
        ``gate``: the tick lock and closing flag (:class:`agent.schedule.TickGate`)."""
        self._transport, self._loop, self._gate = transport, loop, gate
        s = transport.session
        token_key = leader_token_key(self.cfg.prefix, self.cfg.formation)
        if self.deaths is not None:  # holds this robot's own formation's token for good
            self.deaths.open(transport, loop, gate)
        if self.role is not None:
            if self.deaths is None or self.cfg.formation != self.cfg.robot_id:
                self._token = s.liveliness().declare_token(token_key)
            return
        if self.cfg.standby is None:
            return

        def on_token(sample: zenoh.Sample) -> None:
            alive = sample.kind == zenoh.SampleKind.PUT
            try:
                loop.call_soon_threadsafe(self.on_leader_token, alive)
            except RuntimeError:  # loop closed: shutting down
                pass

        transport.keep(token_key, s.liveliness().declare_subscriber(token_key, on_token, history=True))

    def take_token(self) -> Any:
        """The liveliness token, to undeclare first on the way out (None if none)."""
        token, self._token = self._token, None
        return token

    # --- the step -------------------------------------------------------------------------------

    async def lead(self, px: float, py: float, stamp: float, ts: float | None,
                   last_u: tuple[float, float], theta: float = 0.0,
                   follower: Follower | None = None) -> bool:
        """Leader role for this tick: estimate and publish the ellipse (and, in real time, the
        beacon when due), collect the other leaders' ellipses, publish ``others``. False when an
        ellipse that may be in view is missing or stale beyond ``ellipse_hold``. The ellipse
        says whether the formation is parked at its goal (:func:`leader.navigation.at_goal` on
        ``follower``, the leader's walk of the route before this tick's step; None: not parked).

        What the leader knows of each other formation is its newest ``ellipse`` or ``beacon``
        (:mod:`leader.listen`). A fresh one is used as it is; a stale one grown by
        ``max_speed * age`` (:func:`inflate`, counted ``inflated``) for up to ``ellipse_hold``
        seconds, but only if, so grown, it can be within :data:`leader.role.VIEW_RANGE`: one
        that cannot reaches no member's ``others`` whatever its age. One never heard of makes
        the tick incomplete. In real time the tick also asks for the formations to hear every
        tick (:func:`leader.listen.hears`; applied by :meth:`relisten` on the loop).
        ``ts``: the lock-step reference stamp (None in real time; only the clock reads it)."""
        role, clock, t = self.role, self._clock, self._transport
        assert role is not None and t is not None  # only called on the leader, once open
        if clock.lockstep:  # a real-time clock never waits (agent.clock)
            await clock.wait(self._inbox, [(keys.STATE, k) for k in self._member_keys.values()],
                             stamp)
            if self.role is not role:  # the leader came back (step_down) while this tick waited
                self.own_others = None
                return False
        fit = self.kinematics(px, py, ts, last_u, theta)
        own = None if fit is None else role.fit(*fit)
        if own is None:
            self.own_others = None
            return False
        if self.trace:
            self.ellipse_trace.append((stamp, *own[:8]))  # not its points
        # both topologies (all-to-all: for the tie-break and the jam rule, not for rows)
        loc, latest = self.loc, self._inbox.latest  # fused: the formation's radius on it
        msg = ellipse_to_msg(role.formation, own, stamp, None if loc is None else
                             loc.formation_radius(latest(keys.STATE, k)
                                                  for k in self._member_keys.values()),
                             follower is not None and at_goal(follower, (own.cx, own.cy),
                                                              self.goal_tolerance))
        t.publish(role.ellipse_key, msg)
        if self.realtime and beacon_due(stamp, self.listen.beacon_stamp):
            t.publish(role.beacon_key, msg)
            self.listen.beacon_stamp = stamp
        if clock.lockstep:
            deaths = self.deaths  # a robot known dead puts no ellipse: not waited for
            await clock.wait(self._inbox, [(keys.ELLIPSE, k) for k, fid in role.other_keys.items()
                                           if deaths is None or not deaths.gone(fid)], stamp)
            if self.role is not role:  # stepped down while this tick waited: relays nothing
                self.own_others = None
                return False
        self._standing_now.clear()
        received, want, complete, inflated = self.collect(role, own, clock.at(ts), ts)
        self.inflated += inflated
        self.standing += bool(self._standing_now)
        if self.realtime:
            self._ask(frozenset(want))
        self.own_others = role.others(own, received, stamp, msg)  # the message published above
        if complete:
            t.publish(role.others_key, self.own_others)
        return complete

    def _ask(self, want: frozenset[str]) -> None:
        """Real time: have the loop listen to ``want`` (:meth:`relisten`) if that is news."""
        if want != self.listen.heard and want != self.listen.want:
            self.listen.want = want
            if self._loop is not None:
                self._loop.call_soon_threadsafe(self.relisten)

    def collect(self, role: LeaderRole, own: Ellipse, now: float, ts: float | None
                ) -> tuple[dict[str, EllipseMsg], set[str], bool, bool]:
        """The leader's view of the other formations at ``now`` (see :meth:`lead`): the ellipses
        for ``others`` by ellipse key, the formations to hear every tick, whether every
        formation that may be in view is known and fresh enough, whether a stale one was used
        inflated."""
        received: dict[str, EllipseMsg] = {}
        want: set[str] = set()  # real time: the formations to hear every tick (leader.listen)
        complete, inflated = True, False
        quiet, latest = self.listen.quiet, self._inbox.latest
        for k, fid, beacon in role.heard_keys:
            q = quiet.get(fid)
            if q is not None and q - QUIET_MAX_S <= now < q:
                continue  # far, whatever it did since (leader.listen.quiet_until)
            entry = newest(fid, latest(keys.ELLIPSE, k), latest(keys.BEACON, beacon)) \
                or self._seen_dead(fid, now)
            if entry is None:  # never heard of: it may be anywhere (its beacon will say where)
                complete = False
                continue
            use, known = self._judge(fid, entry, own, now, ts, want)
            complete = complete and known
            if use is not None:
                received[k] = use
                inflated = inflated or (use is not entry[0] and fid not in self._standing_now)
        return received, want, complete, inflated

    def _judge(self, fid: str, entry: Entry, own: Ellipse, now: float, ts: float | None,
               want: set[str]) -> tuple[EllipseMsg | None, bool]:
        """One other formation's ellipse for ``others`` and whether it is known well enough:
        as it is (fresh), grown (stale, held), none (out of view whatever it did since) or none
        and not known (stale beyond the hold: incomplete); a formation known dead: its standing
        body (:meth:`_standing`), always known; records whether to hear it every tick."""
        speed = self.cfg.control.max_speed
        m = entry[0]
        dead_at = None if self.deaths is None else self.deaths.known_at(fid, now)
        if dead_at is not None:  # the newer of its last ellipse and the camera's pose of it
            seen = self._seen_dead(fid, now)
            m = seen[0] if seen is not None and seen[0].stamp > m.stamp else m
        age = max(0.0, now - m.stamp)
        grow = speed * age if dead_at is None else self._standing(dead_at - m.stamp)
        gap = grown_gap(own, m, grow)
        if hears(gap, fid in self.listen.heard):
            want.add(fid)
            self.listen.quiet.pop(fid, None)
        else:
            self.listen.quiet[fid] = quiet_until(now, gap, speed)
        if dead_at is not None:
            if gap > VIEW_RANGE:
                return None, True
            self._standing_now.add(fid)
            return standing_body(m, grow), True
        if self._clock.fresh(entry, ts):
            return m, True
        if gap > VIEW_RANGE:
            return None, True
        if age <= self.ellipse_hold:
            return inflate(m, speed * age), True
        return None, False

    def _seen_dead(self, fid: str, now: float) -> tuple[EllipseMsg, float] | None:
        """A robot known dead as the camera last saw it, alone at rest (:meth:`Deaths.body`),
        as an inbox entry (None: not known dead, or not seen)."""
        deaths = self.deaths
        if deaths is None or deaths.known_at(fid, now) is None:
            return None
        body = deaths.body(fid)
        return None if body is None else (body, body.stamp)

    def _standing(self, known_age: float) -> float:
        """The growth of a dead formation's last ellipse, ``known_age`` old when its death was
        known (:func:`leader.succession.standing_grow`): its base stops a period after its last
        command in lock-step (the world), by the command's stale limit in real time (the
        world's; a real base's watchdog is to be no longer)."""
        cfg, c = self.cfg, self.cfg.control
        lag = cfg.period if self._clock.lockstep else cfg.stale_after + cfg.period
        return standing_grow(c.max_speed, known_age, lag,
                             stopping_distance(c.max_speed, c.max_accel if c.double_integrator
                                               else None, cfg.period))

    def kinematics(self, px: float, py: float, ts: float | None, last_u: tuple[float, float],
                   theta: float = 0.0) -> tuple[list[Point], list[Point], list[float]] | None:
        """Every member's control point, velocity and heading, in the role's member order, as
        :meth:`leader.role.LeaderRole.fit` takes them (its own from itself, ``theta`` its body
        heading; the others' from their fresh ``state``); None when one is missing or stale. A
        successor leading for a dead leader (``acting``) also takes the dead robot's last state,
        and every velocity as zero: the formation stands still."""
        role = self.role
        assert role is not None
        acting = self.succession.acting
        if acting:
            self.succession.ticks += 1
            if not self.succession.counted:
                self.succession.counted = True
                self.succession.takeovers += 1
        rid, member_keys, inbox, clock = self.cfg.robot_id, self._member_keys, self._inbox, \
            self._clock
        pts: list[Point] = []
        vel: list[Point] = []
        heads: list[float] = []
        for m in role.members:
            if m == rid:
                pts.append((px, py))
                vel.append((0.0, 0.0) if acting else (last_u[0], last_u[1]))
                heads.append(theta)
                continue
            entry = inbox.latest(keys.STATE, member_keys[m])
            if entry is None or not (acting or clock.fresh(entry, ts)):
                return None
            s: State = entry[0]
            pts.append((s.x, s.y))
            vel.append((0.0, 0.0) if acting else (s.ux, s.uy))
            heads.append(s.theta)
        return pts, vel, heads

    # --- listening (leader.listen, real time) ---------------------------------------------------

    def relisten(self) -> None:
        """Loop thread: subscribe to the ``ellipse`` of the formations the last tick asked to
        hear (:mod:`leader.listen`) and unsubscribe from the others'. Subscribers are declared
        and undeclared outside the tick lock, so a Zenoh thread waiting for it to tick is never
        waiting on a declaration."""
        gate, inbox = self._gate, self._inbox
        with gate.lock:
            role, want = self.role, self.listen.want
            if gate.closing or self._transport is None or role is None or want is None:
                return
            subscribed = inbox.subscribed_keys
            add = [k for k, fid in role.other_keys.items() if fid in want and k not in subscribed]
            drop = [inbox.forget(k) for k, fid in role.other_keys.items()
                    if fid not in want and k in subscribed]
        made = [(k, *inbox.make(k, keys.ELLIPSE)) for k in add]
        with gate.lock:
            undo = gate.closing or self.role is not role
            if not undo:
                for k, sub, take in made:
                    inbox.install(k, keys.ELLIPSE, sub, take)
                self.listen.heard = want
                self.listen.changes += len(add) + len(drop)
                if self.listen.want == want:
                    self.listen.want = None
        gone = drop + ([sub for _, sub, _ in made] if undo else [])
        if gone:
            within(STEP_LIMIT_S, f"{self.cfg.robot_id}: undeclaring {len(gone)} ellipse "
                   "subscribers", lambda: undeclare_all(gone))

    # --- fault containment (leader.succession) --------------------------------------------------

    def on_leader_token(self, alive: bool) -> None:
        """Loop thread: the leader's liveliness token came (``alive``) or went."""
        with self._gate.lock:
            if self._gate.closing or self._transport is None:
                return
            if not alive and not self.succession.acting:
                self.take_over()
            elif alive and self.succession.acting:
                self.step_down()

    def take_over(self) -> None:
        """Under the tick lock: lead this formation for its dead leader (leader.succession).
        The formation stands still (its members' neighbour, the dead robot, is stale, so they
        command zero); this agent publishes its ellipse, at rest, and relays the others."""
        cfg, t, inbox = self.cfg, self._transport, self._inbox
        settings = cfg.standby
        assert settings is not None and t is not None
        role = LeaderRole(cfg.formation, settings, cfg.prefix)
        member_keys = self._adjacent(role)
        if member_keys is None:
            logger.error("%s: cannot lead %s: not adjacent to %s", cfg.robot_id,
                         cfg.formation, ", ".join(self._not_adjacent(role)))
            return
        for k in [role.others_key, role.ellipse_key] + ([role.beacon_key] if self.realtime
                                                        else []):
            t.publisher(k)
        self._subscribe_others(role)
        self.listen.heard = frozenset(fid for k, fid in role.other_keys.items()
                                   if k in inbox.subscribed_keys)
        self.listen.want = None
        self.listen.beacon_stamp = None
        self.role = role
        self._member_keys = member_keys
        self.succession.acting = True
        self.succession.counted = False  # counted as a takeover once it leads a tick (not when
        # the leader merely closed first at the end of a run)
        logger.warning("%s: leader %s of %s is gone: leading the standing formation",
                       cfg.robot_id, cfg.leader_id, cfg.formation)

    def _subscribe_others(self, role: LeaderRole) -> None:
        """Real time: every beacon (the ellipses of the formations near follow, leader.listen);
        lock-step: every ellipse."""
        inbox = self._inbox
        if self.realtime:
            beacons = keys.all_formations_key(self.cfg.prefix, keys.BEACON)
            if beacons not in inbox.subscribed_keys:
                inbox.declare(beacons, keys.BEACON)
            return
        for k in role.other_keys:
            if k not in inbox.subscribed_keys:
                inbox.declare(k, keys.ELLIPSE)

    def step_down(self) -> None:
        """Under the tick lock: the leader is back; be a member again."""
        self.role = None
        self._member_keys = {}
        self.own_others = None
        self.succession.acting = False
        logger.warning("%s: leader %s of %s is back: member again", self.cfg.robot_id,
                       self.cfg.leader_id, self.cfg.formation)
