"""Angle wraps: one copy of each, shared by the formation's rigid motion, the unicycle's steering
and the routes.

Each wrap keeps its caller's order of floating-point operations, so a caller that inlined the
formula before gets the same float from the function.
"""

from __future__ import annotations

import math

#: [rad] a turn within this of half a turn goes left: robots (and formations) that all see a
#: turn of nearly 180 degrees pick the same way round instead of splitting by rounding.
LEFT_BIAS = math.radians(20.0)


def wrap_angle(angle: float) -> float:
    """Angle wrapped into [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def wrap_left(angle: float, bias: float = LEFT_BIAS) -> float:
    """Angle wrapped into [-pi + bias, pi + bias): the short way round, except that a turn
    within ``bias`` of half a turn goes left (positive).

    Why (left-turn bias): members that each see a turn of about half a turn must all turn the
    same way, and rounding alone would split them. Pinned by
    tests/scenarios/rigid-turn-180-dt005.yaml (a formation turning by 180 degrees)."""
    return (angle + math.pi - bias) % (2.0 * math.pi) - math.pi + bias


def wrap_half_turn(angle: float) -> float:
    """Angle wrapped into [-pi/2, pi/2): the nearest of facing ``angle`` and facing away from
    it (a robot that may drive backwards turns at most a quarter turn)."""
    return (angle + 0.5 * math.pi) % math.pi - 0.5 * math.pi
