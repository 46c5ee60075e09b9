"""The fleet manager of lifelong operation: it posts orders and keeps the order book; it decides
nothing about who serves them (the robots' agents do, docs/lifelong-design.md).

Two parts, the math apart from the wire:

* the **order book** (:class:`Book`, pure functions): every order the fleet was given (the
  scenario's ``orders`` as they fall due, the seeded ``order_stream``, orders clients put on
  ``order/{oid}``), each with its message as posted (priority kept current) and its last status
  (``waiting`` at posting, then what the team's leader reports on ``order/{oid}/status``; a
  final state is never replaced). :func:`take_order`, :func:`take_status` and :func:`due` are
  the only ways it changes. An order the run's scenario cannot serve (an unknown type, station
  or load, a destination that is no store or sink) is kept as ``failed`` with the reason
  ``refused: ...``, so a client learns it from the book. The stream's yard
  (:class:`scenario.stream.Yard`) follows the book: an order holds its stations until it is
  delivered, cancelled or failed.
* the **Zenoh part** (:class:`FleetManager`): puts due orders on ``order/{oid}``, listens to
  ``order/*`` (clients' orders, cancels, priority changes) and ``order/*/status``, and answers
  the queries ``order/*`` (one reply per order: its message) and ``order/*/status`` (one per
  order: its last status). Malformed and forged samples (:func:`wire.orders.read_order_message`)
  are dropped and counted. ``formation run`` of a scenario with a fleet runs one in the
  launcher's process, ticked by the world (:func:`run_manager`); ``python -m simulator.manager
  SCENARIO --run DIR --connect EP [--auth FILE]`` runs one alone on the wall clock
  (:func:`main`: a fleet of real robots, or a restart).

The **journal** (``orders.journal`` in the run's folder) holds one JSON line per order message
taken, per status seen and per advance of the stream (and, in real time, the clock's start); a
manager started on the same folder replays it through the same functions, so a restarted
manager loses no order and answers as before (docs/lifelong-design.md, "The fleet manager
restarts").
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import zenoh

from leader import orders as lo
from scenario import ScenarioError, load_scenario, servable, stream
from scenario.lifelong import Lifelong, Order
from scenario.servable import movable_loads
from wire import keys
from wire.orders import (
    OrderMsg,
    OrderStatusMsg,
    all_orders_key,
    encode_order,
    order_key,
    order_status_key,
    read_order_message,
)
from wire.reader import DecodeError
from wire.zconf import ZenohSettings, open_session, read_auth_file

logger = logging.getLogger(__name__)

JOURNAL = "orders.journal"  # in the run's folder
REFUSED = "refused: "  # the reason of an order the scenario cannot serve starts so
FINAL = (lo.DELIVERED, lo.CANCELLED, lo.FAILED)


@dataclass(frozen=True)
class Entry:
    """One order in the book: its message as posted (priority current), its last status and
    when the book took it [s]."""

    order: OrderMsg
    status: OrderStatusMsg
    t: float


@dataclass(frozen=True)
class Book:
    """The fleet manager's state: the orders by id, the stream's yard, and the time of the
    last thing it took [s]."""

    entries: Mapping[str, Entry] = field(default_factory=dict)
    yard: stream.Yard = field(default_factory=stream.Yard)
    t: float = 0.0
    start: float | None = None  # [s since the epoch] a real-time manager's t = 0


def new_book(life: Lifelong) -> Book:
    """The book at t = 0: no order, the scenario's resting loads in the yard."""
    return Book(yard=stream.initial_yard(life))


def order_msg(order: Order, stamp: float) -> OrderMsg:
    """The message that posts a scenario (or stream) order."""
    if order.type is not None:
        return OrderMsg(order.id, "new", type=order.type, source=order.from_ or "", to=order.to,
                        priority=order.priority, stamp=stamp)
    return OrderMsg(order.id, "load", load=order.load_name, source=order.from_ or "",
                    to=order.to, priority=order.priority, stamp=stamp)


def scenario_order(msg: OrderMsg, t: float) -> Order:
    """The scenario's form of a ``new`` or ``load`` message (what the stream's yard takes)."""
    return Order(msg.oid, t, msg.to, type=msg.type or None, load=msg.load or None,
                 from_=msg.source or None, priority=msg.priority)


def known_loads(life: Lifelong, book: Book) -> frozenset[str]:
    """The loads an order may move: the scenario's resting loads and every new load an order
    of the book brings (named by its order; :func:`scenario.servable.movable_loads`)."""
    return movable_loads(life, (oid for oid, e in book.entries.items()
                                if e.order.kind == "new" and not e.status.reason.startswith(REFUSED)))


def order_problem(life: Lifelong, book: Book, msg: OrderMsg) -> str | None:
    """Why the run's scenario cannot serve ``msg`` (a ``new`` or ``load`` order), or None: the
    rule every robot applies too (:func:`scenario.servable.order_problem`), over the loads the
    book knows."""
    return servable.order_problem(life, msg, known_loads(life, book))


def _same(a: OrderMsg, b: OrderMsg) -> bool:
    return (a.kind, a.type, a.load, a.source, a.to) == (b.kind, b.type, b.load, b.source, b.to)


def _with(book: Book, oid: str, entry: Entry, yard: stream.Yard | None = None) -> Book:
    return replace(book, entries={**book.entries, oid: entry},
                   yard=book.yard if yard is None else yard)


def take_order(life: Lifelong, book: Book, msg: OrderMsg, t: float) -> Book:
    """The book after the order message ``msg`` at ``t``; the same book when it changes nothing
    (an order posted again, a cancel or priority change of an unknown or finished order)."""
    entry = book.entries.get(msg.oid)
    if msg.kind in ("new", "load"):
        if entry is not None:
            if not _same(entry.order, msg):
                logger.warning("order %s: a different order under a taken id, ignored", msg.oid)
            return book
        problem = order_problem(life, book, msg)
        if problem is not None:
            return _with(book, msg.oid, Entry(msg, OrderStatusMsg(
                msg.oid, lo.FAILED, reason=REFUSED + problem, stamp=msg.stamp), t))
        yard = stream.hold(book.yard, scenario_order(msg, t))
        return _with(book, msg.oid, Entry(msg, OrderStatusMsg(msg.oid, lo.WAITING,
                                                              stamp=msg.stamp), t), yard)
    if entry is None or entry.status.state in FINAL:
        return book
    if msg.kind == "priority":
        if entry.order.priority == msg.priority:
            return book
        return _with(book, msg.oid, replace(entry, order=replace(entry.order, priority=msg.priority)))
    if entry.status.state != lo.WAITING:
        return book  # a team holds it: its leader cancels and says so
    return _with(book, msg.oid, replace(entry, status=OrderStatusMsg(
        msg.oid, lo.CANCELLED, reason="cancelled", stamp=msg.stamp)),
        _release(book.yard, entry, lifted=False))


def take_status(life: Lifelong, book: Book, msg: OrderStatusMsg) -> Book:
    """The book after an order's status: an unknown order's, or one after a final state,
    changes nothing. A delivery moves the order's load in the yard; a failure or cancel releases
    its stations (the load rests off any station once lifted)."""
    entry = book.entries.get(msg.oid)
    if entry is None or entry.status.state in FINAL or entry.status == msg:
        return book
    yard = None
    if msg.state == lo.DELIVERED:
        yard = stream.deliver(life, book.yard, scenario_order(entry.order, entry.t))
    elif msg.state in FINAL:
        lifted = msg.state == lo.FAILED or entry.status.state == lo.CARRYING  # fails only once up
        yard = _release(book.yard, entry, lifted=lifted)
    return _with(book, msg.oid, replace(entry, status=msg), yard)


def _release(yard: stream.Yard, entry: Entry, lifted: bool) -> stream.Yard:
    """``yard`` without ``entry``'s hold on its stations and load; a lifted load no longer
    rests at its station."""
    msg = entry.order
    load = msg.load or msg.oid
    resting = {st: ld for st, ld in yard.resting.items() if not (lifted and ld == load)}
    return replace(yard, resting=resting, held=yard.held - {msg.to, msg.source},
                   claimed=yard.claimed - {load})


def due(life: Lifelong, book: Book, t: float, stamp: float) -> tuple[tuple[OrderMsg, ...], Book]:
    """The orders falling due in ``(book.t, t]`` (the scenario's in time order, then the
    stream's against the book's yard) and the book with the stream advanced and ``t`` taken;
    the caller takes each message (:func:`take_order`)."""
    scenario = sorted((o for o in life.orders if o.t <= t and o.id not in book.entries),
                      key=lambda o: (o.t, o.id))
    posted, yard = stream.post(life, book.t, t, book.yard)
    counters = replace(book.yard, arrivals=yard.arrivals, posted=yard.posted)
    msgs = tuple(order_msg(o, stamp) for o in (*scenario, *posted))
    return msgs, replace(book, yard=counters, t=max(book.t, t))


# ---------------------------------------------------------------------------- the journal


def message_fields(msg: OrderMsg | OrderStatusMsg) -> dict[str, Any]:
    """A message's fields as JSON-ready data (a journal line's value)."""
    out = asdict(msg)
    if "roster" in out:
        out["roster"] = list(out["roster"])
    return out


def journal_line(t: float, what: str, value: Any) -> str:
    """One journal line: ``{"t": t, what: value}``."""
    return json.dumps({"t": t, what: value}, sort_keys=True) + "\n"


def replay(life: Lifelong, lines: Iterable[str]) -> Book:
    """The book a journal's lines leave (a torn last line, as a crash mid-write leaves it, is
    skipped)."""
    book = new_book(life)
    for n, line in enumerate(lines, 1):
        try:
            rec = json.loads(line)
            book = _replay_one(life, book, rec)
        except (ValueError, TypeError, KeyError) as exc:
            logger.warning("journal line %d skipped: %s", n, exc)
    return book


def _replay_one(life: Lifelong, book: Book, rec: Mapping[str, Any]) -> Book:
    t = float(rec["t"])
    book = replace(book, t=max(book.t, t))
    if "start" in rec:
        return replace(book, start=float(rec["start"]))
    if "order" in rec:
        return take_order(life, book, OrderMsg(**rec["order"]), t)
    if "status" in rec:
        fields = dict(rec["status"])
        fields["roster"] = tuple(fields["roster"])
        return take_status(life, book, OrderStatusMsg(**fields))
    counters = rec["stream"]
    return replace(book, yard=replace(book.yard, arrivals=int(counters["arrivals"]),
                                      posted=int(counters["posted"])))


# ---------------------------------------------------------------------------- the Zenoh part


class FleetManager:
    """The book on a Zenoh session (see the module docstring). ``folder``: the run's folder,
    where the journal is kept (read back first, so a restart continues it); ``stamp()``: the
    stamp of what it puts (None: the run's time each :meth:`tick` is given, as in lock-step).
    Call :meth:`tick` with the run's time [s];
    :meth:`close` undeclares everything (the session stays the caller's)."""

    def __init__(self, session: zenoh.Session, life: Lifelong, folder: Path,
                 prefix: str = keys.DEFAULT_PREFIX,
                 stamp: Callable[[], float] | None = time.time) -> None:
        self._session = session
        self._life = life
        self._prefix = keys.validate_prefix(prefix)
        self._stamp = stamp
        self._lock = threading.Lock()
        path = Path(folder) / JOURNAL
        self.book = replay(life, path.read_text(encoding="utf-8").splitlines()) if path.is_file() \
            else new_book(life)
        self._journal = path.open("a", encoding="utf-8")
        self.dropped = 0  # malformed or forged samples
        order_keys = all_orders_key(self._prefix)
        status_keys = f"{order_keys}/status"
        self._declared: list[Any] = [
            session.declare_subscriber(order_keys, self._on_sample),
            session.declare_subscriber(status_keys, self._on_sample),
            session.declare_queryable(order_keys, self._answer_orders),
            session.declare_queryable(status_keys, self._answer_status),
        ]

    def tick(self, t: float) -> tuple[OrderMsg, ...]:
        """Post the orders due by ``t``; the messages put."""
        with self._lock:
            before = (self.book.yard.arrivals, self.book.yard.posted)
            stamp = t if self._stamp is None else self._stamp()
            msgs, self.book = due(self._life, self.book, t, stamp)
            if (self.book.yard.arrivals, self.book.yard.posted) != before:
                self._write(journal_line(t, "stream", {"arrivals": self.book.yard.arrivals,
                                                       "posted": self.book.yard.posted}))
            for msg in msgs:
                self._take(msg)
        for msg in msgs:
            self._session.put(order_key(self._prefix, msg.oid), encode_order(msg))
        return msgs

    def post(self, msg: OrderMsg) -> None:
        """Take and put an order message of this manager's own (a test, an operator)."""
        with self._lock:
            self._take(msg)
        self._session.put(order_key(self._prefix, msg.oid), encode_order(msg))

    def begin(self, now: float) -> float:
        """The wall-clock time [s since the epoch] of the book's t = 0: the journal's, or
        ``now`` (journalled) for a new book. A real-time manager's run time is ``time.time() -
        begin(...)``, so a restarted one goes on where it stopped."""
        with self._lock:
            start = self.book.start
            if start is None:
                start = now
                self.book = replace(self.book, start=now)
                self._write(journal_line(0.0, "start", now))
            return start

    def on_tick(self, then: Callable[[int, float], None] | None) -> Callable[[int, float], None]:
        """A world's ``on_tick(k, t)`` that posts the orders due at ``t``, then calls ``then``
        (another hook, or None)."""

        def tick(k: int, t: float) -> None:
            self.tick(t)
            if then is not None:
                then(k, t)

        return tick

    def _take(self, msg: OrderMsg | OrderStatusMsg) -> None:
        """Take ``msg`` into the book (under the lock), journalled when it changed it."""
        if isinstance(msg, OrderMsg):
            book = take_order(self._life, self.book, msg, self.book.t)
            what = "order"
        else:
            book = take_status(self._life, self.book, msg)
            what = "status"
        if book is not self.book:
            self.book = book
            self._write(journal_line(book.t, what, message_fields(msg)))

    def _write(self, line: str) -> None:
        if self._journal.closed:  # a sample that arrived while closing: the book is done
            return
        self._journal.write(line)
        self._journal.flush()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            return
        try:
            msg = read_order_message(self._prefix, str(sample.key_expr), sample.payload.to_bytes())
        except DecodeError as exc:
            with self._lock:
                self.dropped += 1
            logger.debug("dropped: %s", exc)
            return
        if isinstance(msg, OrderMsg | OrderStatusMsg):  # a bid is no business of the book
            self.hear(msg)

    def hear(self, msg: OrderMsg | OrderStatusMsg) -> None:
        """An order or an order's status heard: on this manager's own subscriptions, or by
        another part of its process (the world of ``formation run`` passes on each status at the
        tick it takes it); one heard twice changes the book once."""
        with self._lock:
            self._take(msg)

    def entries(self) -> dict[str, Entry]:
        """A copy of the book's entries."""
        with self._lock:
            return dict(self.book.entries)

    def _answer_orders(self, query: zenoh.Query) -> None:
        self._answer(query, lambda oid, e: (order_key(self._prefix, oid), e.order))

    def _answer_status(self, query: zenoh.Query) -> None:
        self._answer(query, lambda oid, e: (order_status_key(self._prefix, oid), e.status))

    def _answer(self, query: zenoh.Query,
                reply: Callable[[str, Entry], tuple[str, OrderMsg | OrderStatusMsg]]) -> None:
        """One reply per order whose key the query asks for."""
        asked = zenoh.KeyExpr(str(query.key_expr))
        for oid, e in sorted(self.entries().items()):
            key, msg = reply(oid, e)
            if asked.intersects(zenoh.KeyExpr(key)):
                query.reply(key, encode_order(msg))

    def close(self) -> None:
        """Undeclare the subscribers and queryables; close the journal."""
        for d in self._declared:
            d.undeclare()
        self._declared = []
        with self._lock:
            self._journal.close()


@contextlib.contextmanager
def run_manager(life: Lifelong | None, folder: Path, endpoint: str, auth_file: Path | None,
                realtime: bool) -> Iterator[FleetManager | None]:
    """The fleet manager of ``formation run`` (None for a scenario without a fleet): on its own
    client session to the run's router, logged in with the manager's credentials
    (``auth_file``; None when insecure), its journal in ``folder``, stamping with the wall clock
    in real time and the run's time in lock-step."""
    if life is None:
        yield None
        return
    auth = None if auth_file is None else read_auth_file(auth_file).auth
    conf = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                         auth=auth).to_config()
    with zenoh.open(conf) as session:
        manager = FleetManager(session, life, folder, stamp=time.time if realtime else None)
        try:
            yield manager
        finally:
            manager.close()


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m simulator.manager SCENARIO --run DIR --connect EP [--auth FILE]``: a fleet
    manager alone, ticking every ``--period`` on the wall clock until SIGTERM or SIGINT; exit
    2 with one line for a scenario without a fleet or bad options, 1 when no session opens."""
    parser = argparse.ArgumentParser(prog="python -m simulator.manager",
                                     description="the fleet manager of lifelong operation")
    parser.add_argument("scenario", help="the run's scenario file (with a fleet)")
    parser.add_argument("--run", required=True, metavar="DIR", help="where its journal is kept")
    parser.add_argument("--connect", action="append", default=[], metavar="EP",
                        help="Zenoh endpoint of the fleet's router")
    parser.add_argument("--auth", default=None, metavar="FILE",
                        help="the fleet manager's credentials (DIR/secure/manager.json5)")
    parser.add_argument("--prefix", default=keys.DEFAULT_PREFIX, help="key-space prefix")
    parser.add_argument("--period", type=float, default=0.1, metavar="S",
                        help="post due orders this often [s]")
    ns = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    try:
        life = load_scenario(ns.scenario).lifelong
        if life is None:
            raise ValueError(f"{ns.scenario}: no fleet (a fleet manager serves lifelong scenarios)")
        if not (math.isfinite(ns.period) and ns.period > 0):
            raise ValueError("--period must be a positive number")
        auth = None if ns.auth is None else read_auth_file(ns.auth).auth
        settings = ZenohSettings(mode="client", connect=tuple(ns.connect),
                                 multicast_scouting=False, auth=auth)
        session = open_session(settings, "")
    except (ScenarioError, ValueError) as exc:
        print(f"simulator.manager: {exc}", file=sys.stderr)
        return 2
    except ConnectionError as exc:
        print(f"simulator.manager: cannot open a Zenoh session: {exc}", file=sys.stderr)
        return 1
    Path(ns.run).mkdir(parents=True, exist_ok=True)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda _s, _f: stop.set())
    with session:
        manager = FleetManager(session, life, Path(ns.run), ns.prefix)
        start = manager.begin(time.time())
        try:
            while not stop.is_set():
                manager.tick(time.time() - start)
                stop.wait(ns.period)
        finally:
            manager.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
