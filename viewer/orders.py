"""A lifelong run's loads and orders in its frames: what rests where, and how far each order got.

A frame (:mod:`viewer.frame`) of a lifelong run carries

* ``cargo``: ``[{"name", "type", "state", "station", "order", "outline": [[x, y], ...]}]``, every
  load on the floor at that instant, ``resting`` (a body among the obstacles, at a station or
  where a team set it down) or ``carried`` (its team's), placed from the run's ``loads.csv`` rows
  (:func:`scenario.lifelong.outline_at`); a load that left through a sink is gone;
* ``orders``: ``[{"id", "state", "since", "type", "load", "from", "to", "robots", "reason"}]``,
  each open order and each order that ended within the last :data:`RECENT_S` seconds, by
  precedence of posting; ``state`` as the contract reports it (``waiting``, ``assigned``,
  ``gathering``, ``carrying``, ``delivered``, ``cancelled``, ``failed``), ``since`` when it
  entered that state;
* ``order_counts``: ``{state: count}`` over every order posted so far.

:class:`OrderTimeline` records the orders' states while a run goes (one look per tick: only the
orders that are not done are compared); :class:`OrderBoard` replays it, with the load rows, into
each frame's fields. The page lists the orders; ``run.mcap`` logs them on ``/orders`` whenever
one changes (:mod:`viewer.record`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from scenario.lifelong import Lifelong, outline_at
from wire.orders import ORDER_STATES

RECENT_S = 30.0  # [s] an order that ended is listed this long after
GONE = "gone"
WAITING = "waiting"
FINAL = ("delivered", "cancelled", "failed")  # the states after which nothing happens


@dataclass(frozen=True)
class Change:
    """Order ``oid`` entered ``state`` (reported) at ``t``, with ``robots`` and ``reason``."""

    t: float
    oid: str
    state: str
    robots: tuple[str, ...] = ()
    reason: str = ""


@dataclass
class OrderTimeline:
    """Every order's reported state as the run went (see the module docstring)."""

    changes: list[Change] = field(default_factory=list)
    specs: dict[str, Any] = field(default_factory=dict)  # oid -> the order as first posted
    _open: dict[str, str] = field(default_factory=dict)  # oid -> last state seen, not done

    def look(self, t: float, orders: Mapping[str, Any]) -> None:
        """Note the orders (:class:`leader.orders.Order`) whose reported state changed since
        the last look (at ``t``)."""
        if len(orders) != len(self.specs):
            for oid, o in orders.items():
                if oid not in self.specs and o.t_posted is not None:
                    self.specs[oid] = o
                    self._open[oid] = ""
        for oid in list(self._open):
            o = orders[oid]
            state = o.reported
            if state != self._open[oid]:
                first = not self._open[oid]
                self.changes.append(Change(entered(o, t, first), oid, state, o.robots, o.reason))
                self._open[oid] = state
            if o.done:
                del self._open[oid]


#: the order's own record of when it entered each reported state
ENTERED = {"assigned": "t_assigned", "gathering": "t_assigned", "carrying": "t_lifted",
           "delivered": "t_delivered", "cancelled": "t_done", "failed": "t_done"}


def entered(o: Any, t: float, first: bool) -> float:
    """When order ``o``, seen at ``t`` in its reported state, entered it: its own stamp of it;
    waiting: its posting when ``first`` seen, else (a lost member sent it back) ``t``."""
    name = "t_posted" if o.reported == WAITING and first else ENTERED.get(o.reported, "")
    stamp = getattr(o, name, None) if name else None
    return t if stamp is None else min(stamp, t)


class OrderBoard:
    """The ``cargo``, ``orders`` and ``order_counts`` of a lifelong run's frames, in time order:
    call :meth:`fields` with non-decreasing times (see the module docstring)."""

    def __init__(self, life: Lifelong, load_rows: Sequence[tuple], timeline: OrderTimeline) -> None:
        self.life = life
        self._rows = sorted(load_rows, key=lambda r: r[0])
        self._changes = sorted(timeline.changes, key=lambda c: c.t)
        self._specs = timeline.specs
        self._k = self._c = 0
        self._loads: dict[str, tuple] = {}  # name -> its newest row
        self._now: dict[str, Change] = {}  # oid -> its newest change
        self._rank = {oid: k for k, oid in enumerate(sorted(
            timeline.specs, key=lambda o: (timeline.specs[o].t_posted or 0.0, o)))}

    def fields(self, t: float) -> dict[str, Any]:
        """The frame fields at ``t`` (after every row and change up to ``t``)."""
        while self._k < len(self._rows) and self._rows[self._k][0] <= t:
            row = self._rows[self._k]
            self._loads[row[1]] = row
            self._k += 1
        while self._c < len(self._changes) and self._changes[self._c].t <= t:
            ch = self._changes[self._c]
            self._now[ch.oid] = ch
            self._c += 1
        counts: dict[str, int] = {}
        listed = []
        for oid in sorted(self._now, key=self._rank.__getitem__):
            ch = self._now[oid]
            counts[ch.state] = counts.get(ch.state, 0) + 1
            if ch.state not in FINAL or t - ch.t <= RECENT_S:
                listed.append(self._entry(ch))
        return {"cargo": [self._cargo(r) for r in self._loads.values() if r[6] != GONE],
                "orders": listed, "order_counts": ordered_counts(counts)}

    def _cargo(self, row: tuple) -> dict[str, Any]:
        _t, name, kind, x, y, yaw, state, station, order = row[:9]
        outline = outline_at(self.life.load_type(kind), (x, y, yaw))
        return {"name": name, "type": kind, "state": state, "station": station, "order": order,
                "outline": [[px, py] for px, py in outline]}

    def _entry(self, ch: Change) -> dict[str, Any]:
        o = self._specs[ch.oid]
        return {"id": ch.oid, "state": ch.state, "since": ch.t, "type": o.type, "load": o.load,
                "from": o.src, "to": o.dst, "robots": list(ch.robots), "reason": ch.reason}


def ordered_counts(counts: Mapping[str, int]) -> dict[str, int]:
    """``counts`` in the contract's order of states (``waiting`` first), as the page lists them."""
    return {s: counts[s] for s in ORDER_STATES if counts.get(s)}
