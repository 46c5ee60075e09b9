"""Commands a robot can follow: reversals of the certified command, per robot.

A **reversal** is a tick whose certified control-point velocity (ux, uy) and the previous tick's
are both at least :data:`REVERSAL_SPEED` and more than :data:`REVERSAL_ANGLE` apart: on a
TurtleBot, a robot vibrating in place when it happens tick after tick.

A reversal is **forced** when, on its tick, a hard row of the robot first became one that can
bind. The series does not say which rows bound the QP; what it has is the smallest barrier
value of each hard kind (``h_obstacle``: circles, walls and shelves; ``h_formations``: other
formations' ellipses). A row ``-dh/dp . u <= gamma h`` with a unit gradient can only bind
when gamma h is below the largest speed the limits allow (:func:`agent.control.build_rows`
leaves the others out), so a kind "first became active" on the tick where gamma h drops below
the robot's top speed, having been at or above it on the robot's previous tick. That is exact for
walls and shelves (h in metres, unit gradient, no motion term) and an approximation for circles
(h in m^2) and ellipses (h without unit) and for moving obstacles, whose rows carry a velocity
term the series does not hold. Ticks without those values (NaN) never count as an onset.

Pure functions over the rows of a run's series (:data:`simulator.inprocess.ROBOT_COLUMNS`);
the in-process and the multi-process summaries both call :func:`motion_fields`.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from typing import NamedTuple

from scenario import Scenario

REVERSAL_SPEED = 0.05  # [m/s] both commands at least this fast
REVERSAL_ANGLE = math.radians(120.0)  # more than this between them
_HARD_KINDS = ("h_obstacle", "h_formations")


class Tick(NamedTuple):
    """One robot's row of a tick, as :func:`robot_ticks` reads it."""

    t: float
    ux: float
    uy: float
    onset: bool  # a hard row first became one that can bind on this tick (module docstring)


def turn_angle(a: tuple[float, float], b: tuple[float, float]) -> float:
    """The angle [rad] between two velocities (0 when either is zero)."""
    na, nb = math.hypot(*a), math.hypot(*b)
    if na == 0.0 or nb == 0.0:
        return 0.0
    c = (a[0] * b[0] + a[1] * b[1]) / (na * nb)
    return math.acos(max(-1.0, min(1.0, c)))


def is_reversal(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Two consecutive commands, both at least REVERSAL_SPEED, more than REVERSAL_ANGLE apart."""
    return (math.hypot(*a) >= REVERSAL_SPEED and math.hypot(*b) >= REVERSAL_SPEED
            and turn_angle(a, b) > REVERSAL_ANGLE)


def robot_ticks(rows: Iterable[Sequence], columns: Sequence[str],
                scenario: Scenario) -> dict[str, list[Tick]]:
    """Each robot's ticks in time order, with the onset flag (see the module docstring)."""
    col = {name: k for k, name in enumerate(columns)}
    gammas = {"h_obstacle": scenario.controller.gamma.obstacle,
              "h_formations": scenario.controller.gamma.formations}
    vmax = scenario.robot.max_speed
    raw: dict[str, list[Sequence]] = defaultdict(list)
    for row in rows:
        raw[row[col["robot"]]].append(row)
    out: dict[str, list[Tick]] = {}
    for rid, seq in raw.items():
        seq.sort(key=lambda r: r[col["t"]])
        ticks: list[Tick] = []
        before = dict.fromkeys(_HARD_KINDS, False)
        for row in seq:
            onset = False
            for kind in _HARD_KINDS:
                now = _can_bind(row[col[kind]], gammas[kind], vmax)
                onset = onset or (now and not before[kind])
                before[kind] = now
            ticks.append(Tick(row[col["t"]], row[col["ux"]], row[col["uy"]], onset and len(ticks) > 0))
        out[rid] = ticks
    return out


def _can_bind(h: float | None, gamma: float, vmax: float) -> bool:
    return h is not None and not (isinstance(h, float) and math.isnan(h)) and gamma * h < vmax


def reversal_ticks(ticks: Sequence[Tick]) -> list[tuple[float, bool]]:
    """(t, forced) of each reversal in one robot's ticks."""
    return [(b.t, b.onset) for a, b in zip(ticks, ticks[1:], strict=False)
            if is_reversal((a.ux, a.uy), (b.ux, b.uy))]


def motion_fields(rows: Iterable[Sequence], columns: Sequence[str],
                  scenario: Scenario) -> dict:
    """``motion`` of summary.json: reversals per robot (all, and those forced), the worst
    robot, and when the first and the last reversal happened."""
    per = {rid: reversal_ticks(ticks) for rid, ticks in robot_ticks(rows, columns, scenario).items()}
    counts = {rid: len(rs) for rid, rs in per.items()}
    forced = {rid: sum(f for _, f in rs) for rid, rs in per.items()}
    times = sorted(t for rs in per.values() for t, _ in rs)
    worst = min(counts, key=lambda r: (-counts[r], r), default=None)
    return {
        "reversals": counts,
        "reversals_total": sum(counts.values()),
        "reversals_forced": forced,
        "reversals_forced_total": sum(forced.values()),
        "worst_robot": None if worst is None or counts[worst] == 0 else worst,
        "worst_reversals": counts[worst] if worst is not None else 0,
        "first_reversal_s": round(times[0], 6) if times else None,
        "last_reversal_s": round(times[-1], 6) if times else None,
    }
