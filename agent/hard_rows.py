"""Which hard rows a control tick did not meet, and a counter of such ticks.

Hard rows (docs/controller.md, agent.qp) are never relaxed to reach a goal: obstacles (eq. 4.5), other
formations' ellipses (eq. 4.6), the separation between robots where the control step has it, and
the speed limits. A tick did not meet them when

* the QP fell back (``fallback``: the hard rows alone were infeasible, the least-risk command
  relaxes them by their smallest common slack) or failed (``failed``: zero command), or
* a hard barrier was already below zero at the tick (``obstacle``, ``formations``,
  ``separation``): the robot was outside the safe set even if this tick's row was satisfied
  (the ellipse barrier dipping to -0.005 in a jam is such a tick).

Formation rows are soft: relaxing them minimally (``relaxed``) is by design and is *not* an
unmet hard row; it is counted apart (``qp.relaxed``). The same function serves the agent, the
in-process simulator and the figures.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from .qp import STATUS_FAILED, STATUS_FALLBACK

H_TOL = 1e-9  # a barrier counts as below zero under -H_TOL (rounding)
HARD_BARRIERS = ("h_obstacle", "h_formations", "h_separation")  # the result fields, if present
REASONS = (STATUS_FALLBACK, STATUS_FAILED, "obstacle", "formations", "separation")


def unmet_hard_rows(status: str | None, barriers: Mapping[str, float | None]) -> tuple[str, ...]:
    """The reasons (in :data:`REASONS` order) a tick with QP ``status`` and the hard barrier
    values ``barriers`` (``{"h_obstacle": ..., ...}``; None or NaN: none of that kind) did not
    meet its hard rows; empty when it met them all."""
    out: list[str] = []
    if status in (STATUS_FALLBACK, STATUS_FAILED):
        out.append(status)
    for name in HARD_BARRIERS:
        v = barriers.get(name)
        if v is not None and not math.isnan(v) and v < -H_TOL:
            out.append(name[2:])
    return tuple(out)


def unmet_of_result(res: Any) -> tuple[str, ...]:
    """:func:`unmet_hard_rows` of an :class:`agent.control.StepResult` (any object with
    ``status`` and the ``h_*`` fields it has). The common tick, whose QP did not fall back and
    whose hard barriers are none below -H_TOL (NaN counts as none), is answered without the
    mapping."""
    status = res.status
    if status not in (STATUS_FALLBACK, STATUS_FAILED):
        for name in HARD_BARRIERS:
            v = getattr(res, name, None)
            if v is not None and v < -H_TOL:
                break
        else:
            return ()
    return unmet_hard_rows(status, {n: getattr(res, n, None) for n in HARD_BARRIERS})


@dataclass
class HardRowCounter:
    """Ticks on which a hard row was not met, in all and per reason."""

    ticks: int = 0
    by_reason: dict[str, int] = field(default_factory=dict)

    def add(self, res: Any) -> tuple[str, ...]:
        reasons = unmet_of_result(res)
        if reasons:
            self.ticks += 1
            for r in reasons:
                self.by_reason[r] = self.by_reason.get(r, 0) + 1
        return reasons
