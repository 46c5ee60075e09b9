"""The leader's part of an agent: its step in each tick (:func:`lead`: estimate and publish the
formation's ellipse from its members' ``state``, collect the other leaders' ellipses, a stale one
held inflated for up to ``ellipse_hold`` seconds, publish ``others``), and fault containment
(:mod:`leader.succession`): a successor takes the role when the leader's liveliness token goes
(:func:`take_over`; it then estimates the standing formation's ellipse) and gives it back when
the token returns (:func:`step_down`).

It lives in agent/, not leader/: it reads the node's mailboxes and, in lock-step, waits for the
tick's inputs (:func:`agent.schedule.wait_current`); the pure estimation is
:class:`leader.role.LeaderRole`'s, and leader/ imports nothing of agent/.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

from agent.schedule import wait_current
from leader.listen import QUIET_MAX_S, beacon_due, grown_gap, hears, quiet_until
from leader.role import VIEW_RANGE, LeaderRole, ellipse_to_msg
from runtime.shutdown import STEP_LIMIT_S, undeclare_all, within
from wire import keys
from wire.payloads import EllipseMsg, State
from wire.traffic import CountingPublisher

if TYPE_CHECKING:
    from agent.node import AgentNode
    from geometry.ellipse import Ellipse

logger = logging.getLogger(__name__)


def inflate(m: EllipseMsg, grow: float) -> EllipseMsg:
    """``m`` with both semi-axes grown by ``grow`` [m]: a stale ellipse covering everywhere its
    formation can have gone since (``grow = max_speed * age``); centre, velocities and stamp
    are kept."""
    return EllipseMsg(m.formation, m.cx, m.cy, m.alpha, m.a + grow, m.b + grow, m.vx, m.vy,
                      m.alpha_rate, m.stamp)


async def lead(node: AgentNode, px: float, py: float, stamp: float, ts: float | None) -> bool:
    """Leader role for this tick: estimate and publish the ellipse (and, in real time, the
    beacon when due), collect the other leaders' ellipses, publish ``others``. False when an
    ellipse that may be in view is missing or stale beyond ``ellipse_hold``.

    What the leader knows of each other formation is its newest ``ellipse`` or ``beacon``
    (:mod:`leader.listen`). A fresh one is used as it is; a stale one grown by
    ``max_speed * age`` (:func:`inflate`, counted ``inflated``) for up to ``ellipse_hold``
    seconds, but only if, so grown, it can be within :data:`leader.role.VIEW_RANGE`: one that
    cannot reaches no member's ``others`` whatever its age. One never heard of makes the tick
    incomplete. In real time the tick also asks for the formations to hear every tick
    (:func:`leader.listen.hears`; applied by :func:`relisten` on the loop)."""
    role = node.role
    assert role is not None  # only called on the leader
    member_keys = node._member_keys
    if ts is not None:
        await wait_current(node, [(keys.STATE, k) for k in member_keys.values()], stamp)
    own = role.estimate(members_now(node, px, py, ts))
    if own is None:
        node._own_others = None
        return False
    if node.options.trace:
        node.ellipse_trace.append((stamp, *own))
    # both topologies (all-to-all: for the tie-break and the jam rule, not for rows)
    msg = ellipse_to_msg(role.formation, own, stamp)
    node._pubs[role.ellipse_key].put_message(msg)
    if ts is None and beacon_due(stamp, node.beacon_stamp):
        node._pubs[role.beacon_key].put_message(msg)
        node.beacon_stamp = stamp
    if ts is not None:
        await wait_current(node, [(keys.ELLIPSE, k) for k in role.other_keys], stamp)
    now = time.time() if ts is None else ts
    received, want, complete, inflated = collect(node, role, own, now, ts)
    node.inflated += inflated
    if ts is None and want != node.listening and want != node._listen_want:
        node._listen_want = frozenset(want)
        if node._loop is not None:
            node._loop.call_soon_threadsafe(relisten, node)
    node._own_others = role.others(own, received, stamp)
    if complete:
        node._pubs[role.others_key].put_message(node._own_others)
    return complete


def collect(node: AgentNode, role: LeaderRole, own: Ellipse, now: float, ts: float | None
            ) -> tuple[dict[str, EllipseMsg], set[str], bool, bool]:
    """The leader's view of the other formations at ``now`` (see :func:`lead`): the ellipses
    for ``others`` by ellipse key, the formations to hear every tick, whether every formation
    that may be in view is known and fresh enough, whether a stale one was used inflated."""
    speed = node.cfg.control.max_speed
    received: dict[str, EllipseMsg] = {}
    want: set[str] = set()  # real time: the formations to hear every tick (leader.listen)
    listening, quiet = node.listening, node._quiet
    complete, inflated = True, False
    for k, fid in role.other_keys.items():
        q = quiet.get(fid)
        if q is not None and q - QUIET_MAX_S <= now < q:
            continue  # far, whatever it did since (leader.listen.quiet_until)
        entry = newest(fid, node._latest(keys.ELLIPSE, k),
                       node._latest(keys.BEACON, role.beacon_keys[fid]))
        if entry is None:  # never heard of: it may be anywhere (its beacon will say where)
            complete = False
            continue
        m = entry[0]
        age = max(0.0, now - m.stamp)
        gap = grown_gap(own, m, speed * age)
        if hears(gap, fid in listening):
            want.add(fid)
            quiet.pop(fid, None)
        else:
            quiet[fid] = quiet_until(now, gap, speed)
        if node._fresh(entry, ts):
            received[k] = m
        elif gap > VIEW_RANGE:
            pass  # out of view whatever it did since
        elif age <= node.options.ellipse_hold:
            received[k] = inflate(m, speed * age)
            inflated = True
        else:
            complete = False
    return received, want, complete, inflated


def newest(fid: str, *entries: tuple[EllipseMsg, float] | None
           ) -> tuple[EllipseMsg, float] | None:
    """The entry with the newest stamp of those that are of formation ``fid`` (a message that
    names another formation than its key is not trusted), or None."""
    best = None
    for e in entries:
        if e is not None and e[0].formation == fid and (best is None or e[0].stamp > best[0].stamp):
            best = e
    return best


def relisten(node: AgentNode) -> None:
    """Loop thread: subscribe to the ``ellipse`` of the formations the last tick asked to hear
    (:mod:`leader.listen`) and unsubscribe from the others'. Subscribers are
    declared and undeclared outside the tick lock, so a Zenoh thread waiting for it to tick is
    never waiting on a declaration."""
    with node._tick_lock:
        role, want = node.role, node._listen_want
        if node._closing or node._session is None or role is None or want is None:
            return
        add = [k for k, fid in role.other_keys.items()
               if fid in want and k not in node.subscribed_keys]
        drop = [node._forget_subscriber(k) for k, fid in role.other_keys.items()
                if fid not in want and k in node.subscribed_keys]
        box = node._mailbox(keys.ELLIPSE)
    made = [(k, *node._make_subscriber(k, keys.ELLIPSE, box)) for k in add]
    with node._tick_lock:
        undo = node._closing or node.role is not role
        if not undo:
            for k, sub, take in made:
                node._install_subscriber(k, keys.ELLIPSE, sub, take)
            node.listening = want
            node.listen_changes += len(add) + len(drop)
            if node._listen_want == want:
                node._listen_want = None
    gone = drop + ([sub for _, sub, _ in made] if undo else [])
    if gone:
        within(STEP_LIMIT_S, f"{node.cfg.robot_id}: undeclaring {len(gone)} ellipse subscribers",
               lambda: undeclare_all(gone))


def members_now(node: AgentNode, px: float, py: float,
                ts: float | None) -> dict[str, tuple[float, float, float, float]]:
    """Leader: every member's control point and velocity it has fresh (its own from
    itself). A successor leading for a dead leader (``acting``) also takes the dead robot's
    last state, and every velocity as zero: the formation stands still."""
    members: dict[str, tuple[float, float, float, float]] = {
        node.cfg.robot_id: (px, py, *node.last_u)}
    for m, k in node._member_keys.items():
        entry = node._latest(keys.STATE, k)
        if entry is not None and (node._fresh(entry, ts) or node.acting):
            s: State = entry[0]
            members[m] = (s.x, s.y, s.ux, s.uy)
    if node.acting:  # a standing formation: its ellipse at rest
        node.acting_ticks += 1
        if not node._acting_since_tick:
            node._acting_since_tick = True
            node.takeovers += 1
        members = {m: (x, y, 0.0, 0.0) for m, (x, y, _, _) in members.items()}
    return members


# --- fault containment (leader.succession) ------------------------------------------------


def on_leader_token(node: AgentNode, alive: bool) -> None:
    """Loop thread: the leader's liveliness token came (``alive``) or went."""
    with node._tick_lock:
        if node._closing or node._session is None:
            return
        if not alive and not node.acting:
            take_over(node)
        elif alive and node.acting:
            step_down(node)


def take_over(node: AgentNode) -> None:
    """Under the tick lock: lead this formation for its dead leader (leader.succession).
    The formation stands still (its members' neighbour, the dead robot, is stale, so they
    command zero); this agent publishes its ellipse, at rest, and relays the others."""
    settings = node.cfg.standby
    assert settings is not None and node._session is not None
    role = LeaderRole(node.cfg.formation, settings, node.cfg.prefix)
    member_keys = {m: keys.state_key(node.cfg.prefix, m) for m in role.members
                   if m != node.cfg.robot_id}
    missing = [m for m, k in member_keys.items() if k not in node.neighbour_keys]
    if missing:
        logger.error("%s: cannot lead %s: not adjacent to %s", node.cfg.robot_id,
                     node.cfg.formation, ", ".join(missing))
        return
    realtime = not node.options.lockstep
    for k in [role.others_key, role.ellipse_key] + ([role.beacon_key] if realtime else []):
        if k not in node._pubs:
            node._pubs[k] = CountingPublisher(node._session.declare_publisher(k), node.counter)
    if realtime:  # every beacon; the ellipses of the formations near (leader.listen)
        beacons = keys.all_formations_key(node.cfg.prefix, keys.BEACON)
        if beacons not in node.subscribed_keys:
            node._declare_subscriber(beacons, keys.BEACON)
    else:  # lock-step: every ellipse
        for k in role.other_keys:
            if k not in node.subscribed_keys:
                node._declare_subscriber(k, keys.ELLIPSE)
    node.listening = frozenset(fid for k, fid in role.other_keys.items()
                               if k in node.subscribed_keys)
    node._listen_want = None
    node.beacon_stamp = None
    node.role = role
    node._member_keys = member_keys
    node.acting = True
    node._acting_since_tick = False  # counted as a takeover once it leads a tick (not when
    # the leader merely closed first at the end of a run)
    logger.warning("%s: leader %s of %s is gone: leading the standing formation",
                   node.cfg.robot_id, node.cfg.leader_id, node.cfg.formation)


def step_down(node: AgentNode) -> None:
    """Under the tick lock: the leader is back; be a member again."""
    node.role = None
    node._member_keys = {}
    node._own_others = None
    node.acting = False
    logger.warning("%s: leader %s of %s is back: member again", node.cfg.robot_id,
                   node.cfg.leader_id, node.cfg.formation)
