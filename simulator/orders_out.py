"""A lifelong run's own outputs: ``orders.csv``, ``loads.csv``, the ``orders`` block of
``summary.json`` and ``orders.png`` (the contract's "Lifelong operation", DESIGN.md).

- ``orders.csv``: one row per order, sorted by ``t_posted`` then id; an empty cell for a time not
  reached; the robots ``;``-separated.
- ``loads.csv``: one row per load per tick while carried and one at each change (t = 0
  included).
- ``orders``: counts, rates, ``latency_s`` (posting to delivery), ``gather_s`` (assignment to
  the team under its load), ``service_efficiency`` and ``idle_fraction``, each distribution as
  ``{median, p95, max}``; ``stuck``, the orders whose team did not move 0.05 m in 120 s; and
  the measures of the acceptance checks (``checks``).

Service efficiency of a delivered order: the straight-line bound of its service, the farthest
member's distance to its slot at the assignment plus the carry distance, at the top speed, over
the time from the assignment to the delivery (1: no robot could have done it faster).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from leader import orders as lo

from .output import write_csv_rows

ORDER_COLUMNS = ("id", "type", "load", "from", "to", "priority", "t_posted", "t_assigned",
                 "t_gathered", "t_lifted", "t_delivered", "state", "reason", "robots")
LOAD_COLUMNS = ("t", "load", "type", "x", "y", "yaw", "state", "station", "order")
ORDER_FILES = ("orders.csv", "loads.csv", "orders.png")


def order_rows(orders: Iterable[lo.Order]) -> list[tuple]:
    """orders.csv's rows, sorted by ``t_posted`` then id (a time not reached: NaN, an empty
    cell)."""
    def cell(v: float | None) -> float:
        return math.nan if v is None else v

    rows = []
    for o in sorted(orders, key=lambda o: (cell(o.t_posted), o.oid)):
        rows.append((o.oid, o.type, o.load, o.src, o.dst, o.priority, cell(o.t_posted),
                     cell(o.t_assigned), cell(o.t_gathered), cell(o.t_lifted),
                     cell(o.t_delivered), o.reported, o.reason, ";".join(o.robots)))
    return rows


def spread(values: Sequence[float]) -> dict[str, float] | None:
    """``{median, p95, max}`` of ``values`` (None when there are none)."""
    if not values:
        return None
    arr = np.asarray(values, dtype=float)
    return {"median": round(float(np.median(arr)), 6),
            "p95": round(float(np.percentile(arr, 95)), 6), "max": round(float(arr.max()), 6)}


def service_efficiency(bound_s: float, order: lo.Order) -> float | None:
    """The straight-line bound [s] over the time from assignment to delivery."""
    if order.t_delivered is None or order.t_assigned is None:
        return None
    took = order.t_delivered - order.t_assigned
    return bound_s / took if took > 0.0 else None


def orders_block(orders: Sequence[lo.Order], bounds: dict[str, float], fleet: int,
                 sim_time: float, busy_s: float) -> dict:
    """summary.json's ``orders`` (module docstring) without the checks. ``bounds``: each
    assigned order's straight-line bound [s]; ``busy_s``: robot-seconds spent in teams."""
    done = [o for o in orders if o.state == lo.DELIVERED]
    hours = sim_time / 3600.0
    eff = [e for o in done if (e := service_efficiency(bounds.get(o.oid, 0.0), o)) is not None]
    return {
        "posted": sum(1 for o in orders if o.t_posted is not None),
        "delivered": len(done),
        "failed": sum(1 for o in orders if o.state == lo.FAILED),
        "cancelled": sum(1 for o in orders if o.state == lo.CANCELLED),
        "open": sum(1 for o in orders if not o.done),
        "delivered_per_hour": round(len(done) / hours, 6) if hours > 0 else None,
        "delivered_per_robot_hour": round(len(done) / hours / fleet, 6)
        if hours > 0 and fleet else None,
        "latency_s": spread([o.t_delivered - o.t_posted for o in done
                             if o.t_delivered is not None and o.t_posted is not None]),
        "gather_s": spread([o.t_gathered - o.t_assigned for o in orders
                            if o.t_gathered is not None and o.t_assigned is not None]),
        "service_efficiency": spread(eff),
        "idle_fraction": round(1.0 - busy_s / (fleet * sim_time), 6)
        if fleet and sim_time > 0 else None,
    }


def write_order_files(out: Path, orders: Sequence[lo.Order], load_rows: Sequence[tuple],
                      plots: bool = True, end: float | None = None) -> None:
    """orders.csv, loads.csv and (``plots``) orders.png into ``out``; ``end``: when the run
    ended [s]."""
    write_csv_rows(out / "orders.csv", ORDER_COLUMNS, order_rows(orders))
    write_csv_rows(out / "loads.csv", LOAD_COLUMNS, load_rows)
    if plots:
        plot_orders(orders, out / "orders.png", end)


# the shades of an order's bar: waiting, gathering (with the lift), carrying (with the set-down)
PHASE_COLOURS = ("#c6dbef", "#6baed6", "#08519c")


def phases(o: lo.Order, end: float) -> list[tuple[float, float, int]]:
    """(start, length, shade) of each phase the order went through, up to its end (``end``
    for an order still open)."""
    end = end if o.t_done is None else o.t_done
    marks = [o.t_posted, o.t_assigned, o.t_lifted, o.t_done]
    out = []
    for k in range(3):
        a = marks[k]
        if a is None:
            break
        b = marks[k + 1]
        out.append((a, (end if b is None else b) - a, k))
        if b is None:
            break
    return out


def plot_orders(orders: Sequence[lo.Order], path: Path, end: float | None = None) -> None:
    """orders.png: deliveries over time above, one bar per order below (waiting, gathering,
    carrying in three shades; a red cross where it failed); ``end``: when the run ended [s]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted(orders, key=lambda o: (o.t_posted or 0.0, o.oid))
    times = sorted(o.t_delivered for o in rows if o.t_delivered is not None)
    if end is None:
        end = max([t for o in rows for t in (o.t_posted, o.t_lifted, o.t_done) if t is not None],
                  default=1.0)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 3 + 0.25 * len(rows)), sharex=True,
                                      gridspec_kw={"height_ratios": [1, max(1, len(rows) / 6)]})
    top.step([0.0, *times, end], [0, *range(1, len(times) + 1), len(times)], where="post")
    top.set_ylabel("delivered")
    for y, o in enumerate(rows):
        for start, length, shade in phases(o, end):
            bottom.barh(y, length, left=start, color=PHASE_COLOURS[shade], height=0.6)
        if o.state == lo.FAILED:
            bottom.plot([o.t_done], [y], "x", color="red", ms=8)
    bottom.set_yticks(range(len(rows)), [o.oid for o in rows])
    bottom.invert_yaxis()
    bottom.set_xlabel("t [s]")
    from matplotlib.patches import Patch

    top.legend(handles=[Patch(color=c, label=n) for c, n in zip(
        PHASE_COLOURS, ("waiting", "gathering and lifting", "carrying and setting down"),
        strict=True)], loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
