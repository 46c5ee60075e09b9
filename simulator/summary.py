"""``summary.json`` of a run, built in one place for the in-process simulator
(:mod:`simulator.inprocess`) and the multi-process run (:mod:`simulator.launch`).

The key order is the file's: scenario, mode, steps, sim_time_s, the safety monitor's fields,
min_h, hard_row_unmet_ticks (also in qp), qp, motion (:mod:`simulator.motion`, when given),
comm, safety, solver, then what only one kind of run has, then collision_log.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from typing import Any

from scenario import Scenario

from .metrics import SafetyMonitor

COLLISION_LOG_MAX = 100  # collision_log entries kept in summary.json


def qp_fields(solves: int, solve_us: Sequence[float], relaxed: int, fallback: int,
              failed: int, hard_unmet: int = 0, hard_reasons: dict[str, int] | None = None,
              **extra: int) -> dict[str, Any]:
    """``qp`` of the summary: solves, the ticks whose QP was not solved as posed (relaxed,
    fallback or failed), the median solve time [us], the ticks on which a hard row was not met
    (agent.hard_rows; relaxed formation rows are by design and not among them); ``extra``
    counts (e.g. ``escape``: ticks on which the formation stepped out of a hazard's way)
    follow."""
    return {
        "solves": solves,
        "infeasible": relaxed + fallback + failed,
        "solve_us_median": statistics.median(solve_us) if solve_us else None,
        "relaxed": relaxed,
        "fallback": fallback,
        "failed": failed,
        "hard_row_unmet_ticks": hard_unmet,
        "hard_row_unmet": dict(hard_reasons or {}),
        **extra,
    }


def run_summary(scenario: Scenario, mode: str, steps: int, sim_time: float, monitor: SafetyMonitor,
                min_h: dict[str, float | None], qp: dict[str, Any], comm: dict[str, Any],
                safety: bool, solver: str, motion: dict[str, Any] | None = None,
                **extra: Any) -> dict[str, Any]:
    """The summary of a run of ``scenario`` (see the module docstring); ``extra`` goes after
    ``solver`` in the order given."""
    return {
        "scenario": scenario.name,
        "mode": mode,
        "steps": steps,
        "sim_time_s": round(sim_time, 6),
        **monitor.summary_fields(),
        "min_h": min_h,
        "hard_row_unmet_ticks": qp.get("hard_row_unmet_ticks", 0),
        "qp": qp,
        **({"motion": motion} if motion is not None else {}),
        "comm": comm,
        "safety": safety,
        "solver": solver,
        **extra,
        "collision_log": monitor.collision_log[:COLLISION_LOG_MAX],
    }
