"""Traffic counting and the hand-off of Zenoh samples to an asyncio loop.

:class:`TrafficCounter` counts messages and payload bytes per key class (see
:func:`wire.keys.key_class`) on two sides: ``put`` (what this process published) and ``recv``
(what its subscribers received). It is thread-safe: zenoh callbacks count from zenoh's threads.
A snapshot is plain JSON-ready data::

    {"put":  {"pose": {"messages": 0, "bytes": 0}, "state": {...}, ..., "other": {...}},
     "recv": {...same classes...}}

and :func:`merge` adds snapshots of many processes into one. :func:`totals` sums one side;
:func:`orders_line` sums lifelong operation's order, bid and order-status classes
(:data:`wire.keys.ORDER_CLASSES`) into their own line, ``orders``, per side.

:class:`CountingPublisher` wraps a ``zenoh.Publisher`` and counts every ``put``.

:class:`Mailbox` keeps the latest decoded value per key for an asyncio node. zenoh-python has no
asyncio API: subscriber callbacks run on zenoh's own threads. ``Mailbox.callback`` (give it to
``session.declare_subscriber``) decodes the payload **on the zenoh thread**, so a malformed
payload costs the control loop nothing, then hands the result to the loop with
``loop.call_soon_threadsafe``. Every attribute of the mailbox (latest values, ``received``,
``dropped_malformed``) is therefore only written on the loop's thread and read there without
locks; the counters lag the network by one loop iteration. The decoder is injected (any
``bytes -> value`` callable that raises on bad input), so the mailbox is testable without zenoh
through :meth:`Mailbox.offer`.

:func:`in_order` makes a subscriber's callback run on the Zenoh thread that received the sample,
so samples that came over one link are taken in the order they came.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Generic, Protocol, TypeVar

import zenoh

from wire import keys
from wire.payloads import DecodeError, Message, encode_zbytes

logger = logging.getLogger(__name__)

SIDES: tuple[str, ...] = ("put", "recv")
ORDERS = "orders"  # the line of the order, bid and order-status classes together

Snapshot = dict[str, dict[str, dict[str, int]]]

T = TypeVar("T")

_DELETE = zenoh.SampleKind.DELETE

CLASS_CACHE_SIZE = 4096  # keys whose class a TrafficCounter remembers (cleared when full)


def in_order(callback: Callable[[zenoh.Sample], Any]) -> zenoh.handlers.Callback:
    """A subscriber handler calling ``callback`` right on the Zenoh thread that received the
    sample (``indirect=False``), with no Python thread woken for it. zenoh-python's default
    hands each subscriber's samples to a Python thread of its own, so samples on two keys may be
    taken in either order whatever order the link brought them in. A lock-step agent reads what
    its teammates, its leader and the world put before their commands of tick ``k - 1``
    (statuses, bids, plans, states, loads) when the pose of tick ``k`` arrives, and that pose
    reaches it through the same router link after them: taken in order, every one of them is in
    before the tick reads it. ``callback`` must be short (it holds up the link while it runs)."""
    return zenoh.handlers.Callback(callback, indirect=False)


def empty_snapshot() -> Snapshot:
    """A snapshot with every side and class at zero."""
    return {
        side: {cls: {"messages": 0, "bytes": 0} for cls in keys.KEY_CLASSES} for side in SIDES
    }


def _payload_len(payload: object) -> int:
    if type(payload) is zenoh.ZBytes:  # what encode_zbytes makes: the usual case first
        return len(payload)
    if isinstance(payload, bytes | bytearray):
        return len(payload)
    if isinstance(payload, memoryview):
        return payload.nbytes
    if isinstance(payload, zenoh.ZBytes):
        return len(payload)
    return len(zenoh.ZBytes(payload))  # type: ignore[arg-type]  # zenoh converts what it can


class TrafficCounter:
    """Thread-safe message and byte counts per key class and side (``put``/``recv``)."""

    def __init__(self, prefix: str = keys.DEFAULT_PREFIX) -> None:
        self._prefix = keys.validate_prefix(prefix)
        self._lock = threading.Lock()
        self._counts = empty_snapshot()
        # key -> class, so counting a message on a key seen before is a lookup; written from
        # several threads without the lock (a lost insert only costs one more parse)
        self._classes: dict[str, str] = {}

    @property
    def prefix(self) -> str:
        return self._prefix

    def key_class(self, key: object) -> str:
        """:func:`wire.keys.key_class` of ``key`` under this counter's prefix, cached."""
        name = key if type(key) is str else str(key)
        cls = self._classes.get(name)
        if cls is None:
            cls = keys.key_class(self._prefix, name)
            if len(self._classes) >= CLASS_CACHE_SIZE:
                self._classes.clear()
            self._classes[name] = cls
        return cls

    def _count(self, side: str, key: object, nbytes: int) -> None:
        if type(nbytes) is not int or nbytes < 0:  # the full check only off the usual path
            if isinstance(nbytes, bool) or not isinstance(nbytes, int) or nbytes < 0:
                raise ValueError(f"nbytes must be an int >= 0, got {nbytes!r}")
        cls = self._classes.get(key) if type(key) is str else None  # key_class's cache, inline
        if cls is None:
            cls = self.key_class(key)
        with self._lock:
            entry = self._counts[side][cls]
            entry["messages"] += 1
            entry["bytes"] += nbytes

    def entry(self, side: str, key: object) -> dict[str, int]:
        """The counts of ``key``'s class on ``side``, for a caller that counts many messages on
        one key with :meth:`add` (a publisher: the class looked up once)."""
        if side not in SIDES:
            raise ValueError(f"side {side!r} must be one of {SIDES}")
        return self._counts[side][self.key_class(key)]

    def add(self, entry: dict[str, int], nbytes: int) -> None:
        """Count one message of ``nbytes`` (an int >= 0) in ``entry`` (:meth:`entry`)."""
        with self._lock:
            entry["messages"] += 1
            entry["bytes"] += nbytes

    def count_put(self, key: object, nbytes: int) -> None:
        """Count one published message of ``nbytes`` payload bytes on ``key``."""
        self._count("put", key, nbytes)

    def count_recv(self, key: object, nbytes: int) -> None:
        """Count one received message of ``nbytes`` payload bytes on ``key``."""
        self._count("recv", key, nbytes)

    def snapshot(self) -> Snapshot:
        """A copy of the counts (see the module docstring for its shape)."""
        with self._lock:
            return {
                side: {cls: dict(entry) for cls, entry in per_class.items()}
                for side, per_class in self._counts.items()
            }

    def reset(self) -> None:
        """Set every count to zero (in place: an :meth:`entry` handed out stays this counter's)."""
        with self._lock:
            for per_class in self._counts.values():
                for entry in per_class.values():
                    entry["messages"] = entry["bytes"] = 0


def merge(snapshots: Iterable[Mapping[str, Mapping[str, Mapping[str, int]]]]) -> Snapshot:
    """Add snapshots (of many processes, say) into one; unknown sides or classes are errors."""
    total = empty_snapshot()
    for index, snap in enumerate(snapshots):
        for side, per_class in snap.items():
            if side not in total:
                raise ValueError(f"snapshots[{index}] has unknown side {side!r}")
            for cls, entry in per_class.items():
                if cls not in total[side]:
                    raise ValueError(f"snapshots[{index}] has unknown class {cls!r}")
                for field in ("messages", "bytes"):
                    value = entry.get(field, 0)
                    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                        raise ValueError(
                            f"snapshots[{index}][{side!r}][{cls!r}][{field!r}] must be an "
                            f"int >= 0, got {value!r}"
                        )
                    total[side][cls][field] += value
    return total


def totals(snapshot: Mapping[str, Mapping[str, Mapping[str, int]]], side: str) -> dict[str, int]:
    """``{"messages": m, "bytes": b}`` over every class of one side of a snapshot."""
    if side not in SIDES:
        raise ValueError(f"side {side!r} must be one of {SIDES}")
    per_class = snapshot.get(side, {})
    return {
        "messages": sum(entry.get("messages", 0) for entry in per_class.values()),
        "bytes": sum(entry.get("bytes", 0) for entry in per_class.values()),
    }


def orders_line(snapshot: Mapping[str, Mapping[str, Mapping[str, int]]]) -> dict[str, dict[str, int]]:
    """``{side: {"messages": m, "bytes": b}}`` over the order classes
    (:data:`wire.keys.ORDER_CLASSES`): the traffic of lifelong operation's orders, bids, votes
    and order status, apart from the formations' own."""
    out = {}
    for side in SIDES:
        per_class = snapshot.get(side, {})
        out[side] = {field: sum(per_class.get(cls, {}).get(field, 0) for cls in keys.ORDER_CLASSES)
                     for field in ("messages", "bytes")}
    return out


class _Publisher(Protocol):
    """What :class:`CountingPublisher` needs of a ``zenoh.Publisher``."""

    @property
    def key_expr(self) -> Any: ...

    def put(self, payload: Any) -> None: ...

    def undeclare(self) -> None: ...


class CountingPublisher:
    """A ``zenoh.Publisher`` that counts every payload it puts in a :class:`TrafficCounter`."""

    def __init__(self, publisher: _Publisher, counter: TrafficCounter) -> None:
        self._publisher = publisher
        self._counter = counter
        self._key = str(publisher.key_expr)
        self._entry = counter.entry("put", self._key)  # its key's class, looked up once

    @property
    def key(self) -> str:
        return self._key

    @property
    def publisher(self) -> _Publisher:
        return self._publisher

    def put(self, payload: bytes | zenoh.ZBytes) -> None:
        """Put raw payload bytes and count them."""
        nbytes = _payload_len(payload)
        self._publisher.put(payload)
        self._counter.add(self._entry, nbytes)

    def put_message(self, msg: Message) -> None:
        """Encode a wire payload (:mod:`wire.payloads`) and put it."""
        self.put(encode_zbytes(msg))

    def undeclare(self) -> None:
        self._publisher.undeclare()

    def __enter__(self) -> CountingPublisher:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.undeclare()


class _Sample(Protocol):
    """What :meth:`Mailbox.callback` needs of a ``zenoh.Sample``."""

    @property
    def key_expr(self) -> Any: ...

    @property
    def payload(self) -> Any: ...

    @property
    def kind(self) -> Any: ...


class Mailbox(Generic[T]):
    """Latest decoded value per key, fed from zenoh threads, read on an asyncio loop.

    ``received`` counts every sample handed over (valid or not); ``dropped_malformed`` counts
    those the decoder rejected; ``rejected`` those the optional ``accept(key, value, previous)``
    refused (the owner's stamp and plausibility checks, :mod:`wire.stamps`: a refused value never
    replaces the stored one, so one bad message cannot block the good ones after it). All of
    them, like :meth:`latest`, are updated on the loop's thread only.
    Construct it on the loop (``Mailbox(asyncio.get_running_loop(), decode_state)``).

    With ``loop=None`` the mailbox is *inline*: :meth:`offer` stores the value on the calling
    thread at once (no loop pass). The owner makes sure one thread at a time feeds it (the agent
    feeds its inline mailboxes under its tick lock); :meth:`wait_update` and :meth:`wait_for`
    need a loop.
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop | None,
        decoder: Callable[[bytes], T],
        *,
        counter: TrafficCounter | None = None,
        accept: Callable[[str, T, T | None], bool] | None = None,
    ) -> None:
        self._loop = loop
        self._decoder = decoder
        self._counter = counter
        self._accept = accept
        self._latest: dict[str, T] = {}
        self._updated = asyncio.Event()
        self._seq = 0
        self.received = 0
        self.dropped_malformed = 0
        self.rejected = 0  # decoded, but refused by ``accept``
        self.dropped_closed = 0  # samples that arrived after the loop closed (thread side)

    # --- zenoh thread side ---------------------------------------------------------------------

    def callback(self, sample: _Sample) -> None:
        """Subscriber callback: ``session.declare_subscriber(key, mailbox.callback)``.

        Delete samples carry no value and are ignored.
        """
        if sample.kind == _DELETE:
            return
        self.offer(str(sample.key_expr), sample.payload.to_bytes())

    def offer(self, key: str, payload: bytes) -> None:
        """Decode ``payload`` (on the calling thread) and hand it to the loop (inline: store it).
        Never raises."""
        if self._counter is not None:
            try:
                self._counter.count_recv(key, len(payload))
            except Exception:  # a broken counter must not kill zenoh's thread
                logger.exception("traffic counter failed on %s", key)
        value: T | None
        ok: bool
        try:
            value, ok = self._decoder(payload), True
        except DecodeError as exc:
            logger.debug("dropped malformed sample on %s: %s", key, exc)
            value, ok = None, False
        except Exception as exc:  # noqa: BLE001 - a decoder's bug drops the sample, never the agent
            logger.warning("decoder raised %s on %s: %s", type(exc).__name__, key, exc)
            value, ok = None, False
        if self._loop is None:  # inline: store it here
            self._store(key, value, ok)
            return
        try:
            self._loop.call_soon_threadsafe(self._deliver, key, value, ok)
        except RuntimeError:  # loop closed: the node is shutting down
            self.dropped_closed += 1

    # --- loop side -----------------------------------------------------------------------------

    def _store(self, key: str, value: T | None, ok: bool) -> bool:
        self.received += 1
        if not ok:
            self.dropped_malformed += 1
            return False
        if self._accept is not None and not self._accept(key, value,  # type: ignore[arg-type]
                                                         self._latest.get(key)):
            self.rejected += 1
            return False
        self._latest[key] = value  # type: ignore[assignment]
        self._seq += 1
        return True

    def _deliver(self, key: str, value: T | None, ok: bool) -> None:
        if self._store(key, value, ok):
            self._updated.set()

    @property
    def accepted(self) -> int:
        """Samples decoded and stored (``received - dropped_malformed - rejected``)."""
        return self.received - self.dropped_malformed - self.rejected

    @property
    def seq(self) -> int:
        """Increases by one with every stored value."""
        return self._seq

    def latest(self, key: str) -> T | None:
        """The latest value received on ``key``, or ``None``."""
        return self._latest.get(key)

    def values(self) -> dict[str, T]:
        """A copy of the latest value of every key."""
        return dict(self._latest)

    def _need_loop(self) -> None:
        if self._loop is None:
            raise RuntimeError("an inline Mailbox (loop=None) cannot be waited on")

    async def wait_update(self, timeout: float | None = None) -> bool:
        """Wait until a value is stored after this call starts; ``False`` on timeout."""
        self._need_loop()
        start = self._seq

        async def changed() -> None:
            while self._seq == start:
                self._updated.clear()
                await self._updated.wait()

        try:
            await asyncio.wait_for(changed(), timeout)
        except (TimeoutError, asyncio.TimeoutError):  # distinct classes on 3.10
            return False
        return True

    async def wait_for(self, key: str, timeout: float | None = None) -> T:
        """The latest value of ``key``, waiting for the first one; ``TimeoutError`` if none."""
        self._need_loop()

        async def first() -> T:
            while key not in self._latest:
                self._updated.clear()
                await self._updated.wait()
            return self._latest[key]

        return await asyncio.wait_for(first(), timeout)
