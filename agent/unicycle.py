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
