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


def integrate(x: float, y: float, theta: float, v: float, omega: float, dt: float):
    """Exact unicycle motion (eq. 6.1) over dt with constant (v, omega): an arc or a line."""
    if abs(omega) < 1e-9:
        return (x + v * dt * math.cos(theta), y + v * dt * math.sin(theta), theta + omega * dt)
    th1 = theta + omega * dt
    r = v / omega
    return (x + r * (math.sin(th1) - math.sin(theta)), y - r * (math.cos(th1) - math.cos(theta)), th1)
