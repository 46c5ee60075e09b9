"""The leader role (thesis section 4.2): estimate the formation's ellipse, exchange it with the
other leaders, hand the others' ellipses (and its own) to the members.

The role runs inside the leader robot's agent (:mod:`agent.node`), which calls it each tick with
what it already has: the members' ``state`` (the leader is adjacent to all of them), its own
control point and velocity, and the other leaders' latest ``ellipse`` messages. The role holds
no network objects: it turns numbers into :class:`wire.payloads.EllipseMsg` and
:class:`wire.payloads.Others` and the node publishes them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from geometry.ellipse import Ellipse, Point, ReferenceShape, estimate, within_reach
from wire import keys
from wire.payloads import EllipseMsg, Others

from .settings import LeaderSettings

# control point x, y [m], velocity ux, uy [m/s] and body heading [rad]
Kinematic = tuple[float, float, float, float, float]

# [m] A formation hands its members only the other formations within this gap of its own
# ellipse (:func:`geometry.ellipse.within_reach`). Nothing farther can act on a member: every
# formation-level rule of agent.control looks at most TIEBREAK_RANGE (2 m) beyond contact, and
# an ellipse row that far out cannot bind (its class-K term grows with h squared; A.3). The
# margin covers two formations closing at top speed for several seconds, and the view is
# rebuilt every tick. Without it, each member of a fleet of F formations decoded F - 1 ellipses
# a tick (the tick's cost grew with the fleet, not with the neighbourhood).
VIEW_RANGE = 4.0


def ellipse_to_msg(formation: str, e: Ellipse, stamp: float, sigma: float | None = None,
                   parked: bool = False) -> EllipseMsg:
    """The wire form of ``e`` for ``formation`` (``sigma``: its members' largest confidence
    radius under ``controller.localisation: fused``; None: the camera's poses; ``parked``: the
    formation stands at its goal, :func:`leader.navigation.at_goal`)."""
    return EllipseMsg(formation, e.cx, e.cy, e.alpha, e.a, e.b, e.vx, e.vy, e.alpha_rate, stamp,
                      e.points, e.headings, sigma, parked)


def msg_to_ellipse(m: EllipseMsg) -> Ellipse:
    """The controller's form of a received ellipse."""
    return Ellipse(m.cx, m.cy, m.alpha, m.a, m.b, m.vx, m.vy, m.alpha_rate, m.points, m.headings)


class LeaderRole:
    """What the leader's agent does for its formation each tick (see the module docstring)."""

    def __init__(self, formation: str, settings: LeaderSettings, prefix: str = keys.DEFAULT_PREFIX):
        if len(settings.offsets) != len(settings.members):
            raise ValueError("settings: offsets and members differ in length")
        if not settings.members:
            raise ValueError("settings: members must not be empty")
        self.formation = keys.validate_id(formation, "formation")
        self.settings = settings
        self.shape = ReferenceShape(tuple(settings.offsets), settings.alpha0)
        self.axes = (float(settings.axes[0]), float(settings.axes[1]))
        self.ellipse_key = keys.ellipse_key(prefix, formation)
        self.beacon_key = keys.beacon_key(prefix, formation)
        self.others_key = keys.others_key(prefix, formation)
        # the other leaders' exact ellipse keys, formation id by key
        self.other_keys = {
            keys.ellipse_key(prefix, f): f for f in settings.other_formations
        }
        # and their beacon keys (leader.listen), by formation id
        self.beacon_keys = {f: keys.beacon_key(prefix, f) for f in settings.other_formations}
        # (ellipse key, formation id, beacon key) of each other formation, as a leader looks
        # them up every tick
        self.heard_keys = tuple((k, f, self.beacon_keys[f]) for k, f in self.other_keys.items())

    @property
    def members(self) -> tuple[str, ...]:
        return self.settings.members

    def estimate(self, members: Mapping[str, Kinematic]) -> Ellipse | None:
        """The ellipse from every member's control point and velocity; ``None`` if one is
        missing (the leader's own entry comes from its own state, not from the network)."""
        pts, vel, heads = [], [], []
        for m in self.members:
            k = members.get(m)
            if k is None:
                return None
            pts.append((k[0], k[1]))
            vel.append((k[2], k[3]))
            heads.append(k[4])
        return self.fit(pts, vel, heads)

    def fit(self, points: Sequence[Point], velocities: Sequence[Point],
            headings: Sequence[float]) -> Ellipse:
        """The ellipse from every member's control point, velocity and heading, in
        :attr:`members` order (:func:`geometry.ellipse.estimate`)."""
        return estimate(self.shape, self.axes, points, velocities, headings)

    def others(self, own: Ellipse, received: Mapping[str, EllipseMsg], stamp: float,
               own_msg: EllipseMsg | None = None) -> Others:
        """The ``others`` message: every other formation's latest ellipse within
        :data:`VIEW_RANGE` of ``own`` (``received`` is keyed by ellipse key, as the node's
        mailbox holds them) and the leader's own (``own_msg``: its wire form at ``stamp`` when
        the caller already built it, :func:`ellipse_to_msg`)."""
        ellipses = []
        for key, fid in self.other_keys.items():
            m = received.get(key)
            if m is not None and m.formation == fid and within_reach(own, m.cx, m.cy, m.a,
                                                                      VIEW_RANGE):
                ellipses.append(m)
        if own_msg is None:
            own_msg = ellipse_to_msg(self.formation, own, stamp)
        return Others(self.formation, stamp, tuple(ellipses), own_msg)
