"""The range of every number and count a scenario may hold (docs/scenarios.md lists the same
table, :func:`describe`; a test keeps the two equal).

Ranges come from physics where physics gives one (a control period of a real robot, the speed of
a warehouse robot or vehicle, warehouse-sized distances) and from what the rest of the system
accepts (a payload carries at most ``wire.payloads.MAX_ITEMS`` ellipses or obstacles). They are
wide: every shipped and generated scenario sits well inside them. What they exclude are values
that overflow or stall a run: ``dt: 1.0e+300`` (one step of the simulated world overflows) or
``dt: 1e-9`` (a billion ticks per simulated second).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .reader import excerpt


@dataclass(frozen=True)
class Range:
    """``lo <= x <= hi``, or ``lo < x`` when ``lo_open``; ``unit`` for messages."""

    lo: float
    hi: float
    unit: str = ""
    lo_open: bool = False

    def contains(self, x: float) -> bool:
        return (self.lo < x if self.lo_open else self.lo <= x) and x <= self.hi

    def text(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        if self.lo_open:
            return f"greater than {_num(self.lo)} and at most {_num(self.hi)}{unit}"
        return f"from {_num(self.lo)} to {_num(self.hi)}{unit}"


def _num(x: float) -> str:
    if x == math.pi * round(x / math.pi) and x != 0 and abs(x) < 100:
        k = round(x / math.pi)
        return f"{'-' if k < 0 else ''}{abs(k) if abs(k) != 1 else ''}pi"
    return f"{x:g}"


def positive(hi: float, unit: str) -> Range:
    return Range(0.0, hi, unit, lo_open=True)


def number(raw: object, where: str, error: type[ValueError] = ValueError) -> float:
    """``raw`` as a float when it is a finite number (not a bool); else a one-line ``error``
    naming ``where``. The one copy of this check: scenarios (:mod:`scenario.fields`, raising
    ScenarioError), their ``world:`` section and a robot's own configuration use it."""
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        raise error(f"{where}: must be a number, got {excerpt(raw)}")
    v = float(raw)
    if not math.isfinite(v):
        raise error(f"{where}: must be finite, got {excerpt(raw)}")
    return v


def check(raw: object, where: str, allowed: Range, error: type[ValueError] = ValueError) -> float:
    """:func:`number` in ``allowed``; else a one-line ``error`` naming ``where`` (a
    non-positive value where only positive ones make sense is reported as such, with the
    range)."""
    v = number(raw, where, error)
    if not allowed.contains(v):
        what = "must be positive" if v <= 0.0 <= allowed.lo else "out of range"
        raise error(f"{where}: {what}, got {excerpt(raw)} (allowed: {allowed.text()})")
    return v


DT = Range(0.001, 1.0, "s")  # control period: 1 kHz .. 1 Hz
MAX_TICKS = 1_000_000  # duration / dt: a run of at most a million control periods
GOAL_TOLERANCE = positive(10.0, "m")
MAX_SPEED = positive(5.0, "m/s")  # a fast warehouse robot moves 2 m/s
MAX_TURN_RATE = positive(20.0, "rad/s")
MAX_ACCEL = positive(50.0, "m/s^2")  # a warehouse robot brakes at a few m/s^2
LOOKAHEAD = positive(1.0, "m")
RADIUS = positive(5.0, "m")
GAIN = positive(100.0, "1/s")  # kp
GAMMA = positive(1000.0, "1/s")  # class-K gains
EPSILON = positive(10.0, "m")
DISTANCE = positive(1000.0, "m")  # Df, d_af, ellipse semi-axes, safe distances
COORDINATE = Range(-10_000.0, 10_000.0, "m")  # starts, goals, obstacle centres: a 20 km square
HEADING = Range(-4.0 * math.pi, 4.0 * math.pi, "rad")
OBSTACLE_SPEED = Range(-20.0, 20.0, "m/s")  # per axis: a vehicle at 72 km/h

# A robot's own configuration (agent.config) adds these; the ones above apply to it too.
POSE_PERIOD = DT  # how often poses really come (a camera's frame period)
STALE_AFTER = positive(10.0, "s")  # inputs older than this are stale (5 pose periods by default)
CLOCK_TOLERANCE = positive(10.0, "s")  # a stamp this far ahead of the robot's clock is accepted

# controller.bounds (scenario.model.Bounds): what a robot's controller assumes of its sensing and
# motors; the same ranges as the world's numbers they stand for (scenario.world.RANGES)
BOUNDS: dict[str, Range] = {
    "pose_noise": Range(0.0, 1.0, "m"),
    "heading_noise": Range(0.0, math.pi, "rad"),
    "latency": Range(0.0, 10.0, "s"),
    "motor_lag": Range(0.0, 10.0, "s"),
}

MAX_FORMATIONS = 256  # a leader's payload holds at most 256 other ellipses (wire.payloads)
MAX_OBSTACLES = 256  # an obstacles payload holds at most 256 (wire.payloads.MAX_ITEMS)
MAX_FORMATION_ROBOTS = 64  # members of one formation (its leader relays to each of them)
MAX_WAYPOINTS = 63  # a formation's waypoints: the route with its goal fits a plan (wire.payloads, 64)

#: (setting, range) for the documentation table; counts are listed as text.
TABLE: tuple[tuple[str, str], ...] = (
    ("dt", f"{DT.text()}"),
    ("duration", f"from dt to {MAX_TICKS:,} * dt s (at most {MAX_TICKS:,} control periods)"),
    ("goal_tolerance", GOAL_TOLERANCE.text()),
    ("robot.max_speed", MAX_SPEED.text()),
    ("robot.max_turn_rate", MAX_TURN_RATE.text()),
    ("robot.max_accel", MAX_ACCEL.text()),
    ("robot.lookahead", LOOKAHEAD.text()),
    ("robot.radius", RADIUS.text()),
    ("controller.kp", GAIN.text()),
    ("controller.gamma (each)", GAMMA.text()),
    ("controller.epsilon", EPSILON.text()),
    *((f"controller.bounds.{k}", r.text()) for k, r in BOUNDS.items()),
    ("controller.d_af, edge Df, ellipse a and b, safe_distance", DISTANCE.text()),
    ("start and goal x, y; obstacle center", COORDINATE.text()),
    ("start heading", HEADING.text()),
    ("obstacle velocity (each axis)", OBSTACLE_SPEED.text()),
    ("formations", f"1 to {MAX_FORMATIONS}"),
    ("robots per formation", f"1 to {MAX_FORMATION_ROBOTS}"),
    ("obstacles", f"0 to {MAX_OBSTACLES}"),
)


def describe() -> str:
    """The table above as Markdown rows."""
    return "\n".join(f"| {k} | {v} |" for k, v in TABLE)
