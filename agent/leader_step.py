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
from leader.role import LeaderRole, ellipse_to_msg
from wire import keys
from wire.payloads import EllipseMsg, State
from wire.traffic import CountingPublisher

if TYPE_CHECKING:
    from agent.node import AgentNode

logger = logging.getLogger(__name__)


def inflate(m: EllipseMsg, grow: float) -> EllipseMsg:
    """``m`` with both semi-axes grown by ``grow`` [m]: a stale ellipse covering everywhere its
    formation can have gone since (``grow = max_speed * age``); centre, velocities and stamp
    are kept."""
    return EllipseMsg(m.formation, m.cx, m.cy, m.alpha, m.a + grow, m.b + grow, m.vx, m.vy,
                      m.alpha_rate, m.stamp)


async def lead(node: AgentNode, px: float, py: float, stamp: float, ts: float | None) -> bool:
    """Leader role for this tick: estimate and publish the ellipse, collect the other
    leaders' ellipses, publish ``others``. False when an ellipse is missing or stale."""
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
    received: dict[str, EllipseMsg] = {}
    complete = True
    # both topologies (all-to-all: for the tie-break and the jam rule, not for rows)
    node._pubs[role.ellipse_key].put_message(ellipse_to_msg(role.formation, own, stamp))
    if ts is not None:
        await wait_current(node, [(keys.ELLIPSE, k) for k in role.other_keys], stamp)
    inflated = False
    for k in role.other_keys:
        entry = node._latest(keys.ELLIPSE, k)
        if entry is None:
            continue
        if node._fresh(entry, ts):
            received[k] = entry[0]
            continue
        age = (ts - entry[0].stamp) if ts is not None else time.monotonic() - entry[1]
        if age <= node.options.ellipse_hold:
            received[k] = inflate(entry[0], node.cfg.control.max_speed * age)
            inflated = True
    node.inflated += inflated
    complete = len(received) == len(role.other_keys)
    node._own_others = role.others(own, received, stamp)
    if complete:
        node._pubs[role.others_key].put_message(node._own_others)
    return complete


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
    for k in [role.others_key] + ([] if node.all_to_all else [role.ellipse_key]):
        if k not in node._pubs:
            node._pubs[k] = CountingPublisher(node._session.declare_publisher(k), node.counter)
    if not node.all_to_all:
        for k in role.other_keys:
            if k not in node.subscribed_keys:
                node._declare_subscriber(k, keys.ELLIPSE)
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
