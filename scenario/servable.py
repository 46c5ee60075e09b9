"""Whether a warehouse can serve a posted order: one pure rule that the fleet manager's book
(:mod:`simulator.manager`) and every robot's agent (:mod:`agent.order_check`) apply alike.

A client's order reaches the robots on ``order/{oid}`` at the same time as the fleet manager,
so the robots cannot wait for the manager to refuse it: each side checks the order against
the same scenario with :func:`order_problem`. The only knowledge that differs between them is
which loads exist besides the scenario's resting ones (a ``new`` order brings a load named by
its id): :func:`movable_loads` builds that set the same way from the ``new`` orders each side
took. A robot that missed an order knows fewer loads than the manager, never more, so every
order the manager refuses the robots refuse too.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable

from wire.orders import OrderMsg

from .lifelong import SINK, SOURCE, STORE, Lifelong

#: the order kinds that bring work (the others change an order already posted)
WORK_KINDS = ("new", "load")


def order_problem(life: Lifelong, msg: OrderMsg, loads: Collection[str]) -> str | None:
    """Why the warehouse ``life`` cannot serve ``msg`` (a ``new`` or ``load`` order), in one
    line naming the culprit field, or None. ``loads``: the loads an order may move
    (:func:`movable_loads`). A ``cancel`` or ``priority`` message is no work of its own: None."""
    if msg.kind not in WORK_KINDS:
        return None
    stations = life.station_by_name
    if msg.to not in stations or stations[msg.to].kind not in (STORE, SINK):
        return f"to: {msg.to!r} is no store or sink of the scenario"
    if msg.kind == "new":
        if msg.type not in life.type_by_name:
            return f"type: unknown load type {msg.type!r}"
        if msg.source not in stations or stations[msg.source].kind != SOURCE:
            return f"from: {msg.source!r} is no source of the scenario"
        return None
    if msg.load not in loads:
        return f"load: unknown load {msg.load!r}"
    if msg.source and msg.source not in stations:
        return f"from: unknown station {msg.source!r}"
    return None


def movable_loads(life: Lifelong, new_orders: Iterable[str]) -> frozenset[str]:
    """The loads an order may move: the scenario's resting loads and the new load of each
    ``new`` order in ``new_orders`` (the ids of those taken without a problem)."""
    return frozenset(ld.name for ld in life.loads) | frozenset(new_orders)
