"""Which other formations a leader hears at full rate (were every leader to take every other
leader's ellipse every tick, a fleet's intake would grow with the square of the fleet).

A leader needs another formation's ellipse each tick only while that formation may come within
:data:`leader.role.VIEW_RANGE` of its own ellipse (nothing farther reaches its members'
``others``). So, in real time, each leader also puts its ellipse once every
:data:`BEACON_PERIOD` on ``{prefix}/formation/{fid}/beacon``, hears every formation's beacon
through one subscription, and subscribes to another formation's ``ellipse`` (every tick) only
while that formation is within :data:`LISTEN_MARGIN` beyond the view range (:func:`hears`;
it lets go :data:`LISTEN_HYSTERESIS` farther out, so a formation on the edge does not make it
subscribe and unsubscribe each tick). Lock-step runs (the simulated world) keep every ellipse.

What a leader knows of another formation is its newest message, ``ellipse`` or ``beacon``; the
formation may have moved since at up to ``max_speed``, so every decision takes its ellipse grown
by ``max_speed * age`` (:func:`grown_gap`, the same growth a stale ellipse gets in
:func:`agent.leader_step.inflate`). It is safe whatever the timing:

* a formation not listened to is more than ``VIEW_RANGE + LISTEN_MARGIN`` away, grown for its
  age, each time the leader looks at it: every tick, or at the latest by :func:`quiet_until`,
  before which it cannot have come nearer. The gap closes at most ``2 * max_speed`` (both
  move), so it needs
  ``LISTEN_MARGIN / (2 * max_speed)`` seconds (4.5 s at a TurtleBot3's 0.22 m/s, 1 s at 1 m/s)
  to come into view, and its beacon growing with its age brings it into the listening range
  first even if its beacons stop;
* until the first ``ellipse`` after the subscription arrives, the leader uses the newest beacon
  grown for its age (an inflated ellipse, counted), and stops its formation once that is older
  than ``ellipse_hold``, exactly as for any stale ellipse.

A leader subscribes to no ``ellipse`` at the start: the first beacons (each leader puts one on
its first tick) tell it which formations are near. Until it has heard of every formation, its
tick is incomplete (no ``others``, its members command zero), as it was when it waited for
every ellipse: a formation never heard of may be anywhere. Subscribing to every ellipse first
and letting go of most of them a tick later would declare and undeclare F x (F - 1)
subscriptions at once across a fleet of F formations.
"""

from __future__ import annotations

import math

from geometry.ellipse import Ellipse
from wire.payloads import EllipseMsg

from .role import VIEW_RANGE

BEACON_PERIOD = 1.0  # [s] a leader's beacon: its ellipse this often, for the leaders farther out
LISTEN_MARGIN = 2.0  # [m] beyond VIEW_RANGE: a formation this near is heard every tick
LISTEN_HYSTERESIS = 1.0  # [m] farther still before a formation listened to is let go
QUIET_MAX_S = 0.5  # [s] the longest a leader goes without looking at a formation far away


def grown_gap(own: Ellipse, m: EllipseMsg, grow: float) -> float:
    """Lower bound on the gap [m] between ``own`` and the ellipse of ``m`` grown by ``grow``
    (both semi-axes): the centres' distance less both semi-major axes (as
    :func:`geometry.ellipse.within_reach` measures it)."""
    return math.hypot(m.cx - own.cx, m.cy - own.cy) - own.a - (m.a + grow)


def hears(gap: float, listening: bool) -> bool:
    """Whether to hear a formation every tick, given the gap to its ellipse grown for its age
    (:func:`grown_gap`) and whether it is heard every tick already."""
    return gap <= VIEW_RANGE + LISTEN_MARGIN + (LISTEN_HYSTERESIS if listening else 0.0)


def quiet_until(now: float, gap: float, max_speed: float) -> float:
    """Until when a leader need not look at a formation it does not hear every tick, at grown
    gap ``gap`` (beyond ``VIEW_RANGE + LISTEN_MARGIN``) at time ``now``: the gap closes at most
    ``2 * max_speed`` (the other's growth and this formation's own motion; a newer message puts
    the other within its growth of the older one), so it stays beyond that limit until then.
    At most :data:`QUIET_MAX_S` ahead, so a leader looks at every formation twice a second
    even if its own ellipse jumps (a member's state replaced after a restart)."""
    return now + min(QUIET_MAX_S, (gap - (VIEW_RANGE + LISTEN_MARGIN)) / (2.0 * max_speed))


def beacon_due(stamp: float, last: float | None) -> bool:
    """Whether a leader whose last beacon was stamped ``last`` (None: none yet) puts one with
    the tick stamped ``stamp``: every :data:`BEACON_PERIOD`, or when the clock went back."""
    return last is None or stamp - last >= BEACON_PERIOD or stamp < last
