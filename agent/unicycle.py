"""Single integrator to unicycle through the near-identity diffeomorphism (thesis section 6.2).

The controller moves the look-ahead point s = p + l (cos theta, sin theta); eq. 6.2 maps its
velocity u to (v, omega). Both are linear in u, so the robot's speed and turn-rate limits become
four QP rows (:func:`limit_rows`) and the certified command is never clipped afterwards.
"""

from __future__ import annotations

import math

from geometry.unicycle import control_point  # noqa: F401  (re-exported)

from .qp import Row


def to_unicycle(ux: float, uy: float, theta: float, lookahead: float) -> tuple[float, float]:
    """eq. 6.2: v = (cos, sin) . u, omega = (-sin, cos) . u / l."""
    c, s = math.cos(theta), math.sin(theta)
    return (c * ux + s * uy, (-s * ux + c * uy) / lookahead)


def from_unicycle(v: float, omega: float, theta: float, lookahead: float) -> tuple[float, float]:
    """Inverse of eq. 6.2: the look-ahead point's velocity for (v, omega)."""
    c, s = math.cos(theta), math.sin(theta)
    w = omega * lookahead
    return (c * v - s * w, s * v + c * w)


def limit_rows(theta: float, lookahead: float, max_speed: float, max_turn_rate: float) -> list[Row]:
    """|v| <= max_speed and |omega| <= max_turn_rate as rows on u (already |a| = 1)."""
    c, s = math.cos(theta), math.sin(theta)
    w = lookahead * max_turn_rate
    return [(c, s, max_speed), (-c, -s, max_speed), (-s, c, w), (s, -c, w)]


STEER_GAIN = 2.0  # [1/s] turn rate per radian of heading error in the steered nominal
STEER_LEFT_BIAS = math.radians(20.0)  # headings this close to opposite the motion turn left
STEER_REVERSE_RANGE = 0.1  # [m] this close to its goal a robot may back up instead of turning


def steer(wx: float, wy: float, theta: float, lookahead: float, max_turn_rate: float,
          reverse: bool = False) -> tuple[float, float]:
    """The look-ahead point's nominal velocity for an intended body velocity w: turn first,
    then drive (the unicycle's own nominal; eq. 4.2 stays the intended motion).

    Fed w directly, the look-ahead point drags the body round it whenever w points away from
    the heading: the robot turns at |w| sin(err) / l (4.4 rad/s for a TurtleBot) while its body
    swings on a circle of radius l, and two members turning opposite ways move their bodies up
    to 2 l apart. Here the robot turns in place about its body at STEER_GAIN x the heading
    error (the body stays where it is) and drives at the part of |w| along its heading, none
    beyond 90 degrees: v = |w| max(cos err, 0), omega = STEER_GAIN err (clamped), and u is the
    look-ahead velocity of that (v, omega) (eq. 6.2 inverted). Members of a formation turn the
    same way: an error within STEER_LEFT_BIAS of opposite turns left. With ``reverse`` (close
    to the goal) the robot backs up rather than turning round when w points behind it."""
    speed = math.hypot(wx, wy)
    if speed < 1e-9:
        return (0.0, 0.0)
    err = math.atan2(wy, wx) - theta
    if reverse:
        err = (err + 0.5 * math.pi) % math.pi - 0.5 * math.pi  # nearest of forwards and back
        v = speed * math.cos(err) if _ahead(wx, wy, theta) else -speed * math.cos(err)
    else:
        err = (err + math.pi - STEER_LEFT_BIAS) % (2.0 * math.pi) - math.pi + STEER_LEFT_BIAS
        v = speed * max(math.cos(err), 0.0)
    omega = max(-max_turn_rate, min(max_turn_rate, STEER_GAIN * err))
    return from_unicycle(v, omega, theta, lookahead)


def no_faster(u: tuple[float, float], speed: float) -> tuple[float, float]:
    """The steered command ``u`` scaled down to at most ``speed`` (its intent's), direction kept.

    :func:`steer` turns at STEER_GAIN x the heading error whatever the intent's speed, so an
    intent of a few mm/s that points behind the robot gives a look-ahead command up to
    l x max_turn_rate (14 cm/s on a TurtleBot); the turn moves the look-ahead point, which moves
    an intent measured there, and the command flips from tick to tick. Scaled, the turn is as
    slow as what it serves (a full-speed intent keeps its full turn: l x max_turn_rate is below
    the top speed)."""
    n = math.hypot(u[0], u[1])
    if n <= speed or n < 1e-12:
        return u
    return (u[0] * speed / n, u[1] * speed / n)


def _ahead(wx: float, wy: float, theta: float) -> bool:
    return wx * math.cos(theta) + wy * math.sin(theta) >= 0.0


def integrate(x: float, y: float, theta: float, v: float, omega: float, dt: float):
    """Exact unicycle motion (eq. 6.1) over dt with constant (v, omega): an arc or a line."""
    if abs(omega) < 1e-9:
        return (x + v * dt * math.cos(theta), y + v * dt * math.sin(theta), theta + omega * dt)
    th1 = theta + omega * dt
    r = v / omega
    return (x + r * (math.sin(th1) - math.sin(theta)), y - r * (math.cos(th1) - math.cos(theta)), th1)
