"""``formation order`` and ``formation orders``: a client of the fleet manager's order book
(lifelong operation; :mod:`simulator.manager`).

``formation order TYPE FROM TO [--id ID] [--priority P]`` posts a new load of TYPE at the source
FROM for TO; ``formation order --load NAME TO`` moves a resting load; ``formation order
--cancel ID`` withdraws an order; ``formation order --id ID --priority P`` changes an order's
priority. Each puts an :class:`wire.orders.OrderMsg` on ``{prefix}/order/{oid}`` (again every
:data:`RESEND_S`, which the book takes once) and watches the order's status, published by its
team's leader and answered by the fleet manager's queryable:

* exit 0 once a team has taken the order (a status ``assigned`` or later), once it is
  cancelled (``--cancel``), or once the book holds the new priority;
* exit 2 with one line when the order is invalid for the run's scenario (the fleet manager
  keeps it as ``failed``, ``refused: ...``: an unknown type, station or load), an id is taken,
  or an order to cancel or change is not in the book;
* exit 1 otherwise: no answer within ``--timeout``, or the order ended another way.

An order without ``--id`` is named ``m1, m2, ...``: the first free one after the book's.
``formation orders`` prints one line per order of the book (id, state, robots, what it moves).
Both connect as ``formation goal`` does (:func:`formation.commands.goal.session_for`): the
``--run DIR`` folder's endpoint and fleet manager's credentials, or ``--connect EP --auth FILE``.
"""

from __future__ import annotations

import argparse
import math
import queue
import sys
import time
from collections.abc import Sequence

import zenoh

from formation.commands.goal import client_args, session_for
from leader import orders as lo
from simulator.manager import REFUSED
from wire import keys
from wire.orders import (
    MAX_PRIORITY,
    OrderMsg,
    OrderStatusMsg,
    ask_orders,
    decode_order,
    decode_order_status,
    encode_order,
    order_book,
    order_key,
    order_status_key,
)
from wire.reader import DecodeError

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2
RESEND_S = 1.0  # [s] the order is put again this often until its status answers
ID_PREFIX = "m"  # orders from the command line are m1, m2, ... unless --id
TAKEN = (lo.ASSIGNED, lo.GATHERING, lo.CARRYING, lo.DELIVERED)  # a team has taken it


def add_parsers(sub) -> None:
    """The ``order`` and ``orders`` subcommands, on the ``formation`` command's subparsers."""
    p = sub.add_parser("order", help="post a transport order, cancel one or change its priority; "
                                     "exit 0 once a team has taken it (or it is cancelled)")
    p.add_argument("spec", nargs="*", metavar="ARG",
                   help="TYPE FROM TO: a new load of TYPE at the source FROM goes to TO; with "
                        "--load, only TO")
    p.add_argument("--load", default=None, metavar="NAME",
                   help="move the resting load NAME (an earlier order's load is named by its id)")
    p.add_argument("--cancel", default=None, metavar="ID", help="cancel the order ID")
    p.add_argument("--id", default=None, metavar="ID",
                   help="the order's id (default: the next free m1, m2, ...); with --priority "
                        "alone, the order whose priority changes")
    p.add_argument("--priority", type=float, default=None, metavar="P",
                   help="higher first (default 0)")
    p.add_argument("--timeout", type=float, default=60.0, metavar="S",
                   help="give up after this many seconds (default 60)")
    client_args(p)
    p = sub.add_parser("orders", help="one line per order of the fleet manager's book")
    p.add_argument("--timeout", type=float, default=3.0, metavar="S",
                   help="wait this long for the fleet manager's answer (default 3)")
    client_args(p)


def next_id(taken: Sequence[str]) -> str:
    """The first ``m{k}`` after every ``m{k}`` in ``taken``."""
    used = [int(t[len(ID_PREFIX):]) for t in taken
            if t.startswith(ID_PREFIX) and t[len(ID_PREFIX):].isdigit()]
    return f"{ID_PREFIX}{max(used, default=0) + 1}"


def request(ns: argparse.Namespace, taken: Sequence[str], stamp: float) -> OrderMsg:
    """The message the options ask for (ValueError, one line, when they do not make one)."""
    if ns.priority is not None and not (math.isfinite(ns.priority)
                                        and abs(ns.priority) <= MAX_PRIORITY):
        raise ValueError(f"--priority must be a finite number in [-{MAX_PRIORITY:g}, "
                         f"{MAX_PRIORITY:g}]")
    priority = 0.0 if ns.priority is None else ns.priority
    spec = list(ns.spec)
    if ns.cancel is not None:
        if spec or ns.load is not None:
            raise ValueError("--cancel ID takes no other order")
        return OrderMsg(keys.validate_id(ns.cancel, "--cancel"), "cancel", stamp=stamp)
    if not spec and ns.load is None and ns.id is not None and ns.priority is not None:
        return OrderMsg(keys.validate_id(ns.id, "--id"), "priority", priority=priority, stamp=stamp)
    oid = next_id(taken) if ns.id is None else keys.validate_id(ns.id, "--id")
    if ns.id is not None and ns.id in taken:
        raise ValueError(f"--id {ns.id}: the fleet has an order so named")
    if ns.load is not None and len(spec) == 1:
        return OrderMsg(oid, "load", load=keys.validate_id(ns.load, "--load"),
                        to=keys.validate_id(spec[0], "TO"), priority=priority, stamp=stamp)
    if ns.load is None and len(spec) == 3:
        names = ("TYPE", "FROM", "TO")
        type_, source, to = (keys.validate_id(v, n) for v, n in zip(spec, names, strict=True))
        return OrderMsg(oid, "new", type=type_, source=source, to=to, priority=priority,
                        stamp=stamp)
    raise ValueError("expected TYPE FROM TO, --load NAME TO, --cancel ID or --id ID --priority P")


def verdict(msg: OrderMsg, status: OrderStatusMsg | None, order: OrderMsg | None) -> int | None:
    """What the order's status (and the book's copy of it) says about ``msg``: EXIT_OK when done,
    EXIT_USAGE when refused as invalid, EXIT_FAIL when it ended another way, None while open."""
    if status is None:
        return None
    if status.state == lo.FAILED and status.reason.startswith(REFUSED):
        return EXIT_USAGE
    if msg.kind == "cancel":
        return EXIT_OK if status.state == lo.CANCELLED else (
            EXIT_FAIL if status.state in (lo.DELIVERED, lo.FAILED) else None)
    if msg.kind == "priority":
        if order is not None and order.priority == msg.priority:
            return EXIT_OK
        return EXIT_FAIL if status.state in (lo.DELIVERED, lo.CANCELLED, lo.FAILED) else None
    if status.state in TAKEN:
        return EXIT_OK
    return EXIT_FAIL if status.state in (lo.CANCELLED, lo.FAILED) else None


def order_line(order: OrderMsg | None, status: OrderStatusMsg) -> str:
    """One order as ``formation orders`` prints it."""
    robots = ",".join(status.roster) or "-"
    why = f" ({status.reason})" if status.reason else ""
    what = ""
    if order is not None:
        moves = f"new {order.type} at {order.source}" if order.kind == "new" else f"load {order.load}"
        what = f", {moves} -> {order.to}, priority {order.priority:g}"
    return f"{status.oid}: {status.state}{why} robots {robots}{what}"


def order_command(ns: argparse.Namespace) -> int:
    if not (math.isfinite(ns.timeout) and ns.timeout > 0):
        print("formation order: --timeout must be a positive number", file=sys.stderr)
        return EXIT_USAGE
    session = session_for(ns, "order")
    if isinstance(session, int):
        return session
    try:
        orders, statuses = order_book(session, ns.prefix, min(ns.timeout, 2.0))
        try:
            msg = request(ns, sorted(set(orders) | set(statuses)), time.time())
        except ValueError as exc:
            print(f"formation order: {exc}", file=sys.stderr)
            return EXIT_USAGE
        if msg.kind in ("cancel", "priority") and msg.oid not in statuses:
            known = ", ".join(sorted(statuses)) or "none, or no fleet manager answered"
            print(f"formation order: no order {msg.oid!r} in the fleet's book (known: {known})",
                  file=sys.stderr)
            return EXIT_USAGE if statuses else EXIT_FAIL
        return _send_and_wait(session, ns, msg)
    finally:
        session.close()


def _send_and_wait(session: zenoh.Session, ns: argparse.Namespace, msg: OrderMsg) -> int:
    seen: queue.SimpleQueue[OrderStatusMsg] = queue.SimpleQueue()

    def on_status(sample: zenoh.Sample) -> None:
        try:
            seen.put(decode_order_status(sample.payload.to_bytes()))
        except DecodeError:
            pass

    sub = session.declare_subscriber(order_status_key(ns.prefix, msg.oid), on_status)
    payload = encode_order(msg)
    deadline = time.monotonic() + ns.timeout
    status: OrderStatusMsg | None = None
    try:
        while time.monotonic() < deadline:
            session.put(order_key(ns.prefix, msg.oid), payload)
            wait = max(0.05, min(RESEND_S, deadline - time.monotonic()))
            asked = ask_orders(session, order_status_key(ns.prefix, msg.oid), decode_order_status,
                               wait)
            order = ask_orders(session, order_key(ns.prefix, msg.oid), decode_order, wait).get(msg.oid)
            found = [asked[msg.oid]] if msg.oid in asked else []
            while not seen.empty():
                found.append(seen.get_nowait())
            for status in found:
                code = verdict(msg, status, order)
                if code is not None:
                    return _said(code, msg, status, order)
    finally:
        sub.undeclare()
    said = order_line(None, status) if status is not None else "no status from the fleet"
    print(f"formation order: order {msg.oid!r} not done within {ns.timeout:g} s ({said})",
          file=sys.stderr)
    return EXIT_FAIL


def _said(code: int, msg: OrderMsg, status: OrderStatusMsg, order: OrderMsg | None) -> int:
    """Print what the verdict ``code`` says, one line; return it."""
    if code == EXIT_OK:
        print(order_line(order, status))
    elif code == EXIT_USAGE:
        print(f"formation order: order {msg.oid!r} {status.reason}", file=sys.stderr)
    else:
        print(f"formation order: order {msg.oid!r} ended {order_line(order, status)}",
              file=sys.stderr)
    return code


def orders_command(ns: argparse.Namespace) -> int:
    session = session_for(ns, "orders")
    if isinstance(session, int):
        return session
    try:
        orders, statuses = order_book(session, ns.prefix, ns.timeout)
    finally:
        session.close()
    if not statuses:
        print("formation orders: no order in the book (or no fleet manager answered)",
              file=sys.stderr)
        return EXIT_FAIL
    for oid in sorted(statuses):
        print(order_line(orders.get(oid), statuses[oid]))
    return EXIT_OK
