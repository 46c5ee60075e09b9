"""A robot's own check of a posted order against the warehouse it serves.

A client's order on ``order/{oid}`` reaches the robots as soon as the fleet manager, so a robot
does not wait for the manager's verdict: before it bids it applies the manager's own rule
(:func:`scenario.servable.order_problem`) to the warehouse of its configuration. ``resting`` is
what the robot knows of the loads an order may move: the scenario's resting loads and the new
loads of the ``new`` orders it accepted (:func:`scenario.servable.movable_loads`); a robot that
missed an order knows fewer loads than the manager, so it refuses every order the manager
refuses.

:func:`open_in_book` is what a robot that starts late or restarts keeps of the manager's
answer (which names every order, finished ones too): the orders still open, by their status.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping

from leader.orders import FINAL
from scenario.lifelong import Lifelong
from scenario.servable import order_problem
from wire.orders import OrderMsg, OrderStatusMsg


def acceptable(life: Lifelong, msg: OrderMsg, resting: Collection[str]) -> str | None:
    """Why this robot refuses the order ``msg`` (one line naming the culprit), or None when the
    warehouse ``life`` can serve it; ``resting``: the loads the robot knows an order may move."""
    return order_problem(life, msg, resting)


def open_in_book(orders: Mapping[str, OrderMsg], statuses: Mapping[str, OrderStatusMsg]
                 ) -> dict[str, OrderMsg]:
    """The orders of the fleet manager's book that are still open: every order whose status is
    not final (an order with no status yet is open)."""
    return {oid: msg for oid, msg in orders.items()
            if oid not in statuses or statuses[oid].state not in FINAL}
