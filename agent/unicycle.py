"""Single integrator to unicycle through the near-identity diffeomorphism (thesis section 6.2).

The controller moves the look-ahead point s = p + l (cos theta, sin theta); eq. 6.2 maps its
velocity u to (v, omega). Both are linear in u, so the robot's speed and turn-rate limits become
four QP rows (:func:`drive_limit_rows`) and the certified command is never clipped afterwards.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from geometry.angles import wrap_half_turn, wrap_left
from geometry.unicycle import control_point  # noqa: F401  (re-exported)

from .qp import Row

MEMBER_GAMMA_FLOOR = 1.0  # [1/s] the thesis's unicycle gamma (Tables 6.2-6.4)


def member_gamma(gamma_formation: float) -> float:
    """The class-K rate of a unicycle member's rows shared with its own formation: its band rows
    (eq. 4.3 and 4.4, appendix A.2) and its separation rows (eq. 4.5 on two bodies), the
    formation's gamma, and its share of its carried load's rows (:mod:`agent.load_rows`, the
    obstacle gamma), each at least :data:`MEMBER_GAMMA_FLOOR`.

    A unicycle's control point moves as asked only inside its drive polygon
    (:func:`drive_limit_rows`: sideways at most ``lookahead * max_turn_rate``), and a member turns
    before it drives. At a small gamma a row inside the band or the separation lets two members
    close on each other no faster than gamma h beyond the other's last velocity: near the edge
    each row is all but an equality on that velocity. Members that turn, brake for a door's jamb
    or start one tick apart cannot all match each other's last velocities, and the QP meets the
    rows by relaxing the band; outside it a row asks the band back at only gamma |h|, so what
    one relaxation opens stays open (a line of three turning through a door at gamma 0.05:
    tests/scenarios/door-gamma005-line-unicycle.yaml). Any positive rate keeps each row's set invariant (with
    ``gamma dt <= 1`` for the sampled rows), so the floor changes how fast members may move
    within the band, not what the band is; the obstacle and other formations' rows keep the
    scenario's gamma."""
    return max(gamma_formation, MEMBER_GAMMA_FLOOR)


#: [m] the most clearance beyond a thing's Ds that a unicycle's look-ahead point keeps for
#: sampled control (:func:`sampling_margin`): where the full turn rate would need more, the
#: turn rate is capped near things instead (:func:`near_turn_cap`)
NEAR_MARGIN = 0.03


def point_error(lookahead: float, omega: float, dt: float) -> float:
    """[m] How far the look-ahead point of a unicycle turning at ``omega`` ends off the
    straight line ``u dt`` that its rows assumed, over one period ``dt`` with u held (eq. 6.1's
    arc under eq. 6.2's (v, omega)): the point turns with the body at radius l, which moves
    it sideways by at most l (omega dt)^2 / 2."""
    return 0.5 * lookahead * (omega * dt) ** 2


def full_sampling_margin(lookahead: float, max_turn_rate: float, dt: float, gamma: float
                         ) -> float:
    """[m] Where the point rows at rate ``gamma`` settle at the full turn rate: a row holds
    h' >= -gamma h over a period only on the straight line, so each period may end
    :func:`point_error` lower, h+ >= (1 - gamma dt) h - e, whose fixed point is h = -e /
    (gamma dt) (the sampled-data barrier of Agrawal and Sreenath, RSS 2017, with the model
    error of Taylor et al., "Safety of sampled-data systems with control barrier functions via
    approximate discrete time models", CDC 2022: the safe set holds up to the error's margin).
    Written as l omega^2 dt / (2 gamma), the same number in the same operations as before."""
    return 0.5 * lookahead * max_turn_rate ** 2 * dt / gamma


def sampling_margin(lookahead: float, max_turn_rate: float, dt: float, gamma: float) -> float:
    """[m] The clearance beyond Ds that a unicycle's obstacle, wall and shelf rows keep for
    sampled control: :func:`full_sampling_margin`, at most :data:`NEAR_MARGIN` (a turn rate
    capped near things holds that: :func:`near_turn_cap`). At gamma 0.05 and dt 0.1 the full
    margin of a TurtleBot is 0.40 m, more than a door's jamb leaves."""
    return min(full_sampling_margin(lookahead, max_turn_rate, dt, gamma), NEAR_MARGIN)


def near_turn_cap(clearance: float, margin: float, lookahead: float, dt: float, gamma: float,
                  max_turn_rate: float) -> float:
    """[rad/s] The fastest turn that keeps a look-ahead point, ``clearance`` [m] beyond its
    rows' boundary (Ds grown by the offset and ``margin``; negative: inside the margin), within
    ``margin`` of that boundary after one period: h+ >= (1 - gamma dt) h - e >= -margin holds
    for a :func:`point_error` e up to margin + (1 - gamma dt) h (distances to circles, walls
    and shelves are convex in the point, so the row's straight-line step ends at least
    (1 - gamma dt) h beyond, and the point's error moves it by e at most). The room never
    drops below gamma dt margin, its value at the margin's edge, whose fixed point is the
    margin itself: a point pushed deeper still turns, and its rows take it back. Far from
    things the cap is ``max_turn_rate``: it binds only within a few millimetres of the
    margin's edge (input-to-state safety of the rows, Kolathaya and Ames, IEEE L-CSS 2019:
    the point's error is a bounded disturbance, and its bound is what the turn rate sets)."""
    room = max(gamma * dt * margin, margin + (1.0 - gamma * dt) * clearance)
    return min(max_turn_rate, math.sqrt(2.0 * room / lookahead) / dt)


def load_sampling_margin(max_speed: float, max_turn_rate: float, dt: float, gamma: float
                         ) -> float:
    """[m] The clearance beyond :data:`agent.load_rows.LOAD_CLEAR` that a unicycle member's load
    rows keep where its turn rate is capped near things (:func:`near_turn_cap`): at least
    :data:`NEAR_MARGIN`, and what the rows need at the full turn rate. They hold the members'
    bodies, which move along their headings (eq. 6.1): a body at speed v turning at omega ends
    v omega dt^2 / 2 off its straight step, and the rows at :func:`member_gamma` settle that
    divided by gamma dt further in."""
    body = 0.5 * max_speed * max_turn_rate * dt * dt
    return max(NEAR_MARGIN, body / (member_gamma(gamma) * dt))


def to_unicycle(ux: float, uy: float, theta: float, lookahead: float) -> tuple[float, float]:
    """eq. 6.2: v = (cos, sin) . u, omega = (-sin, cos) . u / l."""
    c, s = math.cos(theta), math.sin(theta)
    return (c * ux + s * uy, (-s * ux + c * uy) / lookahead)


def from_unicycle(v: float, omega: float, theta: float, lookahead: float) -> tuple[float, float]:
    """Inverse of eq. 6.2: the look-ahead point's velocity for (v, omega)."""
    c, s = math.cos(theta), math.sin(theta)
    w = omega * lookahead
    return (c * v - s * w, s * v + c * w)


def drive_limit_rows(theta: float, lookahead: float, max_speed: float, max_turn_rate: float) -> list[Row]:
    """|v| <= max_speed and |omega| <= max_turn_rate as rows on u (already |a| = 1)."""
    c, s = math.cos(theta), math.sin(theta)
    w = lookahead * max_turn_rate
    return [(c, s, max_speed), (-c, -s, max_speed), (-s, c, w), (s, -c, w)]


@dataclass(frozen=True, slots=True)
class SteerTuning:
    """The unicycle's turn-then-drive nominal (:func:`steer`)."""

    gain: float = 2.0  # [1/s] turn rate per radian of error: higher faces sooner, lower turns smoother
    keep: float = math.radians(45.0)  # [rad] a turning robot keeps its way this far past behind: fewer flips
    keep_rate: float = 0.3  # [rad/s] turning this fast counts for keep: lower also holds slowed turns
    reverse_range: float = 0.1  # [m] this near its goal a robot backs up rather than turning round
    small_turn: float = 1e-7  # [rad] smaller steps integrate as the chord: the arc's sines lose digits below


STEER = SteerTuning()


def steer(wx: float, wy: float, theta: float, lookahead: float, max_turn_rate: float,
          reverse: bool = False, *, lead: float, turning: float = 0.0,
          aim: tuple[float, float] | None = None) -> tuple[float, float]:
    """The look-ahead point's nominal velocity for an intended point velocity w: turn first,
    then drive (the unicycle's own nominal; eq. 4.2 stays the intended motion).

    Fed w directly, the look-ahead point drags the body round it whenever w points away from
    the heading: the robot turns at |w| sin(err) / l (4.4 rad/s for a TurtleBot) while its body
    swings on a circle of radius l, and two members turning opposite ways move their bodies up
    to 2 l apart. Here the robot turns in place about its body at ``gain`` (:class:`SteerTuning`)
    x the heading error (the body stays where it is) and drives at the part of w along its
    heading, none backwards: v = max(w . e(theta), 0), omega = gain err (clamped), and u is the
    look-ahead velocity of that (v, omega) (eq. 6.2 inverted).

    The heading aimed at is that of the point where w asks the look-ahead point to be ``lead``
    seconds from now, seen from the BODY: s + w lead - b = l e(theta) + w lead. Far from it
    (|w| lead >> l) that is w's own direction; for a point pulled a few millimetres towards a
    slot (w = k (slot - s), lead = 1 / k) it is the heading that puts the point on the slot. It
    does not move as the robot turns, since the body does not: aimed at w's direction instead,
    a robot whose slot lay behind its look-ahead point saw w swing round as fast as it turned and
    turned back and forth in place (a reversal every tick, measured in
    tests/scenarios/shelf-pushed-unicycle.yaml). Members of a formation turn the same way: an
    error within :data:`geometry.angles.LEFT_BIAS` of opposite turns left. A robot already ``turning`` [rad/s,
    its last turn rate] at least ``keep_rate`` keeps its way round while the error that way
    is at most half a turn plus ``keep`` (:func:`turn_error`). With ``reverse`` (close to
    the goal) the robot backs up rather than turning round when the aim lies behind it. ``aim``
    [m/s]: the motion its formation waits for it to face (:func:`agent.body.pace`); it then
    turns towards that direction, and drives only by w."""
    if aim is not None and math.hypot(*aim) < 1e-9:
        aim = None
    if math.hypot(wx, wy) < 1e-9 and aim is None:
        return (0.0, 0.0)
    c, s = math.cos(theta), math.sin(theta)
    if aim is not None:  # the formation waits for this member to face its slot's motion
        err = math.atan2(aim[1], aim[0]) - theta
    else:
        err = math.atan2(lookahead * s + wy * lead, lookahead * c + wx * lead) - theta
    along = wx * c + wy * s
    if reverse:
        err = wrap_half_turn(err)  # nearest of forwards and back
        v = along
    else:
        err = turn_error(err, turning)
        v = max(along, 0.0)
    omega = max(-max_turn_rate, min(max_turn_rate, STEER.gain * err))
    return from_unicycle(v, omega, theta, lookahead)


def turn_error(err: float, turning: float = 0.0) -> float:
    """The heading error ``err`` [rad] as the turn to make: the short way round, left where
    the aim lies within :data:`geometry.angles.LEFT_BIAS` of behind (:func:`geometry.angles.wrap_left`);
    for a robot ``turning`` [rad/s] at least ``keep_rate``, its own way round while that is at
    most pi + ``keep``."""
    short = wrap_left(err)
    if abs(turning) < STEER.keep_rate or short * turning >= 0.0:
        return short
    other = short - math.copysign(2.0 * math.pi, short)  # the same aim, the robot's own way
    return other if abs(other) <= math.pi + STEER.keep else short


def integrate(x: float, y: float, theta: float, v: float, omega: float, dt: float):
    """Exact unicycle motion (eq. 6.1) over dt with constant (v, omega): an arc or a line.

    The arc ``(v / omega) (sin th1 - sin th)`` subtracts two nearly equal sines when the turn
    ``omega dt`` is tiny, and lost up to 2e-8 m a step at ``omega = 1.1e-8``; below ``small_turn``
    (:class:`SteerTuning`) the same arc is its chord, ``v dt (1 - a^2 / 6)`` along the mid
    heading ``theta + a`` (``a = omega dt / 2``: the series of ``sin(a) / a``, exact in floating point
    there). Above it the arc, whose rounding is then under 1e-9 of the step."""
    half = 0.5 * omega * dt
    if abs(half) < 0.5 * STEER.small_turn:
        chord = v * dt * (1.0 - half * half / 6.0)
        return (x + chord * math.cos(theta + half), y + chord * math.sin(theta + half),
                theta + omega * dt)
    th1 = theta + omega * dt
    r = v / omega
    return (x + r * (math.sin(th1) - math.sin(theta)), y - r * (math.cos(th1) - math.cos(theta)), th1)
