"""The per-robot quadratic program of eq. 4.1 / 4.12: min |u - u_hat|^2 s.t. rows a . u <= b.

The problem has two variables, so it is solved exactly in plain Python floats by default:
the incremental algorithm (Seidel's, for a strictly convex objective) keeps the optimum of the
rows seen so far; when a new row is violated the new optimum lies on that row's line, a 1-D
problem over an interval cut by the earlier rows. It is exact up to rounding and reports
infeasibility when an interval empties. qpsolvers backends (osqp, daqp, quadprog, clarabel, ...)
can be chosen by name instead; they are the oracle the tests compare against.

Infeasible ticks (docs/controller.md): formation rows ("soft") are relaxed by the
smallest common slack that restores feasibility; obstacle and inter-formation rows ("hard") and
the speed limits are never relaxed to reach a goal. If the hard rows and the limits alone are
infeasible (a barrier already violated, say), the least-risk command is returned: the hard rows
relaxed by their smallest common slack, inside the speed limits. Every row is normalised so that
|a| = 1, which makes every slack a velocity [m/s].
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

from geometry.slack import smallest_slack

Row = tuple[float, float, float]  # (ax, ay, b): ax * ux + ay * uy <= b


@dataclass(frozen=True, slots=True)
class QPTuning:
    """The per-robot QP's numerical tuning."""

    feas_tol: float = 1e-9  # [m/s] a row is met within this: looser accepts tiny misses, tighter fails
    bisect_steps: int = 60  # halvings of the slack search: a tighter slack, one exact solve each
    bisect_stop: tuple[float, float] = (1e-12, 1e-9)  # bracket (abs, rel) ending it: wider is cheaper, looser
    slack_pad: float = 4.0  # feas_tol added to the slack so the final solve finds it: more is looser


QP_TUNING = QPTuning()
FEAS_TOL = QP_TUNING.feas_tol

STATUS_OK = "ok"
STATUS_RELAXED = "relaxed"  # formation rows relaxed by `slack`
STATUS_FALLBACK = "fallback"  # hard rows infeasible: least-risk command
STATUS_FAILED = "failed"  # solver error: zero command
STATUS_NOMINAL = "nominal"  # safety off: the nominal command


class Rows(NamedTuple):
    """One tick's QP rows from a robot model's row builder (all normalised,
    ``ax * ux + ay * uy <= b``; u a velocity, or an acceleration for a double integrator)."""

    limits: list[Row]  # speed (turn-rate, acceleration) limits: never relaxed
    hard: list[Row]  # other formations' ellipses (or pairwise robots): never relaxed
    soft: list[Row]  # formation edges: relaxed by the smallest slack only if infeasible
    h_formation: float  # smallest barrier value of each kind (inf when there is none)
    h_obstacle: float
    h_formations: float
    h_separation: float = math.inf
    contact: Sequence[Row] = ()  # obstacles and body separation: hard, kept in a fallback
    # the QP's nominal where the robot's input is not its velocity (a double integrator's
    # acceleration); None: the nominal velocity itself
    target: tuple[float, float] | None = None


class QPResult(NamedTuple):
    ux: float
    uy: float
    status: str
    slack: float  # [m/s] relaxation used (0 when status is ok)
    solved: bool  # False: the command is a fallback, not the optimum of the stated problem


def normalized_row(ax: float, ay: float, b: float) -> Row:
    """Row scaled so that |a| = 1; a zero gradient is kept as (0, 0, b)."""
    n = math.hypot(ax, ay)
    if n < 1e-12:
        return (0.0, 0.0, b)
    return (ax / n, ay / n, b / n)


def solve_exact(ux: float, uy: float, rows: Sequence[Row], tol: float = FEAS_TOL):
    """Exact minimiser of |u - (ux, uy)|^2 subject to ``rows``; None when infeasible."""
    x, y = ux, uy
    for k in range(len(rows)):
        ax, ay, b = rows[k]
        if ax * x + ay * y <= b + tol:
            continue
        n2 = ax * ax + ay * ay
        if n2 < 1e-24:
            return None  # 0 <= b with b < -tol
        # The optimum now lies on the line a . u = b: u = p + t d with p the projection of
        # u_hat onto it and d along it; minimise t^2 over the interval the earlier rows allow.
        r = (ax * ux + ay * uy - b) / n2
        px, py = ux - r * ax, uy - r * ay
        dx, dy = -ay, ax
        span = _line_interval(rows, k, px, py, dx, dy, tol)
        if span is None:
            return None
        lo, hi = span
        if lo > hi:
            if lo - hi > tol * 10.0:
                return None
            t = 0.5 * (lo + hi)
        else:
            t = 0.0 if lo <= 0.0 <= hi else (lo if lo > 0.0 else hi)
        x, y = px + t * dx, py + t * dy
    return (x, y)


def _line_interval(rows: Sequence[Row], k: int, px: float, py: float, dx: float, dy: float,
                   tol: float) -> tuple[float, float] | None:
    """The interval (lo, hi) of t for which p + t d meets the rows before ``k`` (lo > hi when
    they leave none); None when one of them, parallel to the line, excludes it wholly."""
    lo, hi = -math.inf, math.inf
    for j in range(k):
        cx, cy, c = rows[j]
        den = cx * dx + cy * dy
        num = c - (cx * px + cy * py)
        if -1e-15 < den < 1e-15:
            if num < -10.0 * tol:
                return None
            continue
        t = num / den
        if den > 0.0:
            if t < hi:
                hi = t
        elif t > lo:
            lo = t
    return lo, hi


def qpsolvers_solver(name: str, **options) -> Callable[[float, float, Sequence[Row]], tuple]:
    """A solve function with the same contract as :func:`solve_exact`, backed by
    ``qpsolvers.solve_qp(..., solver=name)``; tight default tolerances for osqp/clarabel."""
    # Imported here, not at the top: qpsolvers and scipy load only when a backend is
    # asked for, so an agent on the exact solver (every robot by default) never loads them.
    import numpy as np
    import qpsolvers

    if name not in qpsolvers.available_solvers:
        raise ValueError(
            f"solver: {name!r} is not available (installed: "
            f"{', '.join(sorted(qpsolvers.available_solvers))}, or 'exact')"
        )
    opts = dict(options)
    if name == "osqp" and not opts:
        opts = {"eps_abs": 1e-10, "eps_rel": 1e-10, "max_iter": 100000,
                "verbose": False}
    if name == "clarabel" and not opts:
        opts = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10, "verbose": False}
    sparse = name in getattr(qpsolvers, "sparse_solvers", ())
    if sparse:
        from scipy import sparse as sp  # osqp and friends take CSC matrices without a warning

    p = sp.csc_matrix(2.0 * np.eye(2)) if sparse else 2.0 * np.eye(2)

    def solve(ux: float, uy: float, rows: Sequence[Row], tol: float = FEAS_TOL):
        q = np.array([-2.0 * ux, -2.0 * uy])
        if not rows:
            return (ux, uy)
        g = np.array([[r[0], r[1]] for r in rows])
        h = np.array([r[2] for r in rows])
        try:
            with warnings.catch_warnings():
                # osqp 1.x warns that a future default will change, and backends warn on an
                # infeasible problem: both are answered by the None this function returns.
                warnings.simplefilter("ignore", PendingDeprecationWarning)
                warnings.simplefilter("ignore", UserWarning)
                x = qpsolvers.solve_qp(p, q, sp.csc_matrix(g) if sparse else g, h, solver=name, **opts)
        except Exception:  # noqa: BLE001 - a backend failure is reported as "no solution"
            return None
        if x is None or not np.all(np.isfinite(x)):
            return None
        if np.max(g @ x - h) > 1e-6:
            return None
        return (float(x[0]), float(x[1]))

    solve.__name__ = f"qpsolvers_{name}"
    return solve


def make_solver(name: str | None):
    """``None`` or ``"exact"``: :func:`solve_exact`; else a qpsolvers backend by name."""
    if name in (None, "", "exact"):
        return solve_exact
    return qpsolvers_solver(name)


def _min_slack(rows_fixed: list[Row], rows_relaxed: Sequence[Row], start: tuple[float, float]):
    """Smallest s >= 0 with rows_fixed and (rows_relaxed + s) feasible; ``start`` satisfies
    rows_fixed. Returns (s, rows_relaxed shifted by s). Bisection (:mod:`geometry.slack`) on the
    exact solver."""
    t = QP_TUNING
    hi = max(0.0, max(ax * start[0] + ay * start[1] - b for ax, ay, b in rows_relaxed))
    hi += t.feas_tol

    def feasible(mid: float) -> bool:
        shifted = [(ax, ay, b + mid) for ax, ay, b in rows_relaxed]
        return solve_exact(start[0], start[1], rows_fixed + shifted) is not None

    hi = smallest_slack(feasible, hi, t.bisect_steps, t.bisect_stop)
    # A little extra so the final solve, started elsewhere, finds the same thin set non-empty.
    hi += t.slack_pad * t.feas_tol
    return hi, [(ax, ay, b + hi) for ax, ay, b in rows_relaxed]


def solve_cbf_qp(
    ux: float,
    uy: float,
    limits: Sequence[Row],
    hard: Sequence[Row],
    soft: Sequence[Row],
    solve=solve_exact,
    contact: Sequence[Row] = (),
) -> QPResult:
    """The QP of eq. 4.12 with the relaxation policy of this module's docstring.

    ``contact`` rows are hard rows whose violation is a contact (obstacle safe distances, body
    separation), as opposed to hard rows with a built-in margin (other formations' ellipses,
    eq. 3.5's D_Af): when the hard rows cannot all hold, the least-risk command keeps the
    contact rows exact if the limits allow and relaxes only the margin rows; only when the
    contact rows alone are infeasible are all hard rows relaxed together."""
    hard = list(contact) + list(hard)
    base = list(limits) + hard
    u = solve(ux, uy, base + list(soft))
    if u is not None:
        return QPResult(u[0], u[1], STATUS_OK, 0.0, True)
    u0 = solve_exact(ux, uy, base)
    if u0 is not None:
        slack, shifted = _min_slack(base, soft, u0)
        u = solve(ux, uy, base + shifted) or solve_exact(ux, uy, base + shifted)
        if u is not None:
            return QPResult(u[0], u[1], STATUS_RELAXED, slack, True)
    # The hard rows themselves cannot hold: least-risk command inside the speed limits.
    lim = list(limits)
    z = solve_exact(0.0, 0.0, lim)
    if z is None:
        return QPResult(0.0, 0.0, STATUS_FAILED, math.inf, False)
    margin = hard[len(contact):]
    zc = solve_exact(0.0, 0.0, lim + list(contact)) if contact and margin else None
    if zc is not None:
        lim, hard, z = lim + list(contact), margin, zc  # contacts stay exact
    t, hard_shifted = _min_slack(lim, hard, z)
    fixed = lim + hard_shifted
    u1 = solve_exact(ux, uy, fixed)
    if u1 is None:
        return QPResult(0.0, 0.0, STATUS_FAILED, math.inf, False)
    if soft:
        _, soft_shifted = _min_slack(fixed, soft, u1)
        u1 = solve_exact(ux, uy, fixed + soft_shifted) or u1
    return QPResult(u1[0], u1[1], STATUS_FALLBACK, t, False)

