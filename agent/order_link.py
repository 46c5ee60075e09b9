"""The bidding part on Zenoh: a robot's :class:`agent.bidder.Bidder` behind one subscription.

An :class:`OrderLink` subscribes to ``{prefix}/order/**`` (the orders, every robot's bids and
votes, the statuses), decodes each sample with the defensive decoders of :mod:`wire.orders`
and drops, counted, what is malformed or forged (a bid on another robot's key:
:func:`wire.orders.bid_is_forged`). Samples wait in a queue filled on Zenoh's threads and are
handed to the bidder at the start of the robot's next tick (:meth:`OrderLink.step`), so the
bidder, a pure state machine, is only ever touched by the tick. What the tick returns is put on
``order/{oid}/bid/{rid}`` (bids, votes, declines) and ``order/{oid}/status`` (a leader's
commit or release). Link faults (:class:`agent.faults.LinkFaults` ``drop``) lose the robots'
bids and statuses at this receiver, counted, as the runtime's ``--drop`` loses the other
inter-robot classes: each message by the same pure function of the seed, the receiver, the key
and the payload (:meth:`agent.faults.LinkFaults.dropped`), so a lock-step run with losses loses
the same messages whatever order Zenoh's threads deliver them in; the manager's orders are
not dropped (a robot that misses one learns it from the queryable). ``resolve`` turns a
posted order into its slots in the world (the robot's knowledge of the stations and load
types); None: not an order this robot can serve, ignored. ``on_team`` hears each committed
roster this robot follows, once; ``on_status`` every status heard from another robot (after
the bidder). What a robot puts is stamped with its tick's time, and a receiver takes it at its
first tick after that one, so in lock-step every robot hears a message at the same tick.
"""

from __future__ import annotations

import hashlib
import logging
import threading
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import zenoh

from agent.bidder import Bidder, Message, Point
from agent.faults import LinkFaults
from leader.allocation import OpenOrder
from wire.orders import (
    BidMsg,
    OrderMsg,
    OrderStatusMsg,
    bid_is_forged,
    bid_key,
    decode_bid,
    decode_order,
    decode_order_status,
    encode_order,
    order_status_key,
    parse_order_key,
)
from wire.reader import DecodeError
from wire.traffic import in_order

logger = logging.getLogger(__name__)

STAMP_EPS = 1e-6  # [s] stamps this near are the same tick's


def lost(faults: LinkFaults, receiver: str, key: str, payload: bytes) -> bool:
    """Whether ``receiver`` loses this message: a pure function of the message (its key and
    payload, whose stamp, round and phase tell apart a robot's puts on one key) and the seed."""
    if faults.drop <= 0.0:
        return False
    digest = hashlib.blake2b(payload, digest_size=8).hexdigest()
    return faults.dropped(receiver, f"{key}#{digest}", 0.0)


class OrderLink:
    """One robot's bidding over Zenoh (module docstring)."""

    def __init__(self, session: zenoh.Session, prefix: str, bidder: Bidder,
                 resolve: Callable[[OrderMsg], OpenOrder | None],
                 faults: LinkFaults | None = None,
                 on_team: Callable[[str], None] | None = None,
                 on_status: Callable[[OrderStatusMsg], None] | None = None) -> None:
        self.session = session
        self.prefix = prefix
        self.bidder = bidder
        self.resolve = resolve
        self.on_team = on_team
        self.on_status = on_status
        self._faults = faults or LinkFaults()
        self._lock = threading.Lock()
        self._queue: list[tuple[str, bytes]] = []
        self._pubs: dict[str, Any] = {}
        self._team: str | None = None
        self.received = 0  # samples from others that reached this robot (before link faults)
        self.fault_dropped = 0
        self.malformed = 0
        self.forged = 0
        self.puts = 0
        self.now = 0.0  # [s] the time of the tick under way (its stamp on what is put)
        self.sub = session.declare_subscriber(f"{prefix}/order/**", in_order(self._on_sample))

    def _on_sample(self, sample: zenoh.Sample) -> None:  # Zenoh thread
        key = str(sample.key_expr)
        where = parse_order_key(key, self.prefix)
        if where is None or (where[1] == "bid" and where[2] == self.bidder.rid):
            return  # not an order key, or this robot's own bid
        payload = sample.payload.to_bytes()
        if where[1] == "status" and self._own_status(payload):
            return  # this robot's own (a session hears its own puts)
        with self._lock:
            self.received += 1
            if where[1] != "order" and lost(self._faults, self.bidder.rid, key, payload):
                self.fault_dropped += 1
                return
            self._queue.append((key, payload))

    def _own_status(self, payload: bytes) -> bool:
        try:
            return decode_order_status(payload).leader == self.bidder.rid
        except DecodeError:
            return False  # counted where it is taken

    def step(self, k: int, position: Point) -> list[Message]:
        """The robot's tick ``k``: what arrived goes to the bidder, then the bidder's tick; what
        it puts is returned (and put)."""
        self.now = k * self.bidder.settings.tick_s
        with self._lock:
            arrived, self._queue = self._queue, []
        out: list[Message] = []
        later = []
        for key, payload in arrived:
            if self._this_tick(key, payload):
                later.append((key, payload))
            else:
                out += self._take(key, payload)
        if later:  # heard at the next tick, whenever in this one they came
            with self._lock:
                self._queue[:0] = later
        out += self.bidder.tick(k, position)
        for msg in out:
            self.put(msg)
        following = self.bidder.following
        if following != self._team:
            self._team = following
            if following is not None and self.on_team is not None:
                self.on_team(following)
        return out

    def _this_tick(self, key: str, payload: bytes) -> bool:
        """Whether a robot's bid, vote or status was put at this tick (or later): it is taken
        at the next tick, so every robot of a lock-step run hears it at the same tick, however
        the puts of one tick interleave with its receivers' ticks."""
        kind = parse_order_key(key, self.prefix)
        if kind is None or kind[1] == "order":
            return False
        try:
            msg = decode_bid(payload) if kind[1] == "bid" else decode_order_status(payload)
        except DecodeError:
            return False  # counted where it is taken
        return msg.stamp > self.now - STAMP_EPS

    def _take(self, key: str, payload: bytes) -> list[Message]:
        """One sample to the bidder (malformed and forged ones dropped, counted)."""
        where = parse_order_key(key, self.prefix)
        assert where is not None  # filtered on arrival
        try:
            if where[1] == "order":
                order = self.resolve(decode_order(payload))
                if order is not None:
                    self.bidder.order(order)
                return []
            msg: Message = decode_bid(payload) if where[1] == "bid" else \
                decode_order_status(payload)
        except DecodeError as exc:
            self.malformed += 1
            logger.info("%s: dropped an order message on %s: %s", self.bidder.rid, key, exc)
            return []
        forged = bid_is_forged(key, self.prefix, msg) if isinstance(msg, BidMsg) \
            else msg.oid != where[0]
        if forged:  # a robot speaks only for itself, of the order its key names
            self.forged += 1
            return []
        out = self.bidder.hear(msg)
        if isinstance(msg, OrderStatusMsg) and self.on_status is not None:
            self.on_status(msg)
        return out

    def put(self, msg: Message) -> None:
        """Put a bid, vote, decline or status on its key, stamped with this tick's time."""
        msg = replace(msg, stamp=self.now)
        key = bid_key(self.prefix, msg.oid, self.bidder.rid) if isinstance(msg, BidMsg) \
            else order_status_key(self.prefix, msg.oid)
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(key)
        pub.put(encode_order(msg))
        self.puts += 1

    def close(self) -> None:
        """Undeclare the subscriber and the publishers."""
        for handle in [self.sub, *self._pubs.values()]:
            handle.undeclare()
        self._pubs.clear()
