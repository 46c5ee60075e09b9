"""A unicycle's acceleration limit: rows on the change of its certified command.

A unicycle with ``robot.max_accel`` a_max is commanded through its look-ahead point's velocity u
(chapter 6.2), which the robot follows exactly under eq. 6.2. Its certified u may change by at
most a_max dt per control period,

    |u - u_prev| <= a_max dt,

as the rows of the polygon (:mod:`geometry.speed_polygon`) inscribed in that disk about u_prev
(the last certified command, one vertex towards the nominal), so the command the QP certifies is
one the robot can follow. The rows join the limit rows; the barrier rows stay hard. Where the
barrier rows cannot hold together with them (the QP falls back or fails), the barrier rows win:
the tick is solved again without the acceleration rows, and its status is :data:`STATUS_ACCEL`
(counted: ``qp.accel_yielded`` in the summary). Without ``max_accel`` there are no such rows and
the QP is the plain one. Double integrators have their own rows
(:mod:`agent.double_integrator`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .barriers import speed_rows
from .qp import STATUS_FAILED, STATUS_FALLBACK, QPResult, Row, solve_cbf_qp, solve_exact

STATUS_ACCEL = "accel"  # the acceleration rows gave way to the barrier rows this tick


def accel_rows(last_u: tuple[float, float], nominal: tuple[float, float], max_accel: float | None,
               dt: float) -> list[Row]:
    """The rows of the module docstring (none without ``max_accel``)."""
    if max_accel is None:
        return []
    heading = math.atan2(nominal[1] - last_u[1], nominal[0] - last_u[0])
    return [(nx, ny, b + nx * last_u[0] + ny * last_u[1])
            for nx, ny, b in speed_rows(max_accel * dt, heading)]


def solve(ux: float, uy: float, limits: Sequence[Row], hard: Sequence[Row], soft: Sequence[Row],
          contact: Sequence[Row], accel: Sequence[Row], solver=solve_exact) -> QPResult:
    """:func:`agent.qp.solve_cbf_qp` with the acceleration rows among the limits; where the hard
    rows cannot hold with them, the same QP without them, marked :data:`STATUS_ACCEL`."""
    res = solve_cbf_qp(ux, uy, [*limits, *accel], hard, soft, solver, contact)
    if not accel or res.status not in (STATUS_FALLBACK, STATUS_FAILED):
        return res
    free = solve_cbf_qp(ux, uy, limits, hard, soft, solver, contact)
    if free.status in (STATUS_FALLBACK, STATUS_FAILED):
        return free  # the barrier rows cannot hold even so: the least-risk command, counted
    return free._replace(status=STATUS_ACCEL)


def summary_fields(max_accel: float | None, double_integrator: bool, yielded: int) -> dict[str, int]:
    """``qp.accel_yielded`` for a run of unicycles with ``max_accel`` (else nothing: every
    other summary stays as it was)."""
    return {"accel_yielded": yielded} if max_accel is not None and not double_integrator else {}
