"""The robot's hardware limits: the TurtleBot3 burger (thesis chapter 6, ROBOTIS e-manual)."""

from __future__ import annotations

BURGER_MAX_SPEED = 0.22  # [m/s] TurtleBot3 burger
BURGER_MAX_TURN_RATE = 2.84  # [rad/s] TurtleBot3 burger
BURGER_RADIUS = 0.105  # [m] footprint radius the scenarios use for the burger
