"""The agent's inbox: the latest accepted message per key, and where it comes from.

It keeps one :class:`wire.traffic.Mailbox` per key class, each behind the one stamp check
(:func:`wire.stamps.check_stamp`, counted per class and reason; a lock-step agent the world
went on without catches up, counted ``lockstep_catch_ups``) and plausibility
(:mod:`agent.plausibility`; an implausible input is refused, counted, and makes the next tick
command zero; an obstacle list of a second source is kept as a rival whose obstacles the tick
avoids too, :meth:`Inbox.obstacle_rivals`), fed by the subscribers it declares on the
:class:`agent.transport.Transport` (through :class:`agent.fault_inject.FaultInjector` for the
faulted classes).

Real time on pose arrival (*polled*): every mailbox is inline, fed under the tick lock by the
tick that drains the ring channels (:meth:`Inbox.drain`) and by the pose callback, which ticks
right on the Zenoh thread that received the pose (:mod:`agent.schedule`). Otherwise a callback
stores on the loop and wakes the tick (:attr:`Inbox.arrived`).
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from agent.fault_inject import FaultInjector
from agent.faults import EPS, LinkFaults
from agent.plausibility import (
    JUMP_MARGIN_M,
    ObstacleRivals,
    Reacquire,
    common_agree,
    ellipse_ok,
    ellipses_ok,
    jump_ok,
    obstacles_agree,
    velocity_ok,
)
from agent.transport import Transport
from wire import keys
from wire.payloads import (
    Obstacles,
    decode_ellipse,
    decode_obstacles,
    decode_others,
    decode_pose,
    decode_state,
)
from wire.stamps import FUTURE, OLDER, StampCounter, check_stamp, used_stamp
from wire.traffic import Mailbox, TrafficCounter, in_order

logger = logging.getLogger(__name__)

RING_CAPACITY = 256  # real time: samples kept per key between two ticks (a flood beyond it
# loses its oldest samples uncounted; about one per tick arrives in normal operation)
CONTEST_HOLD_S = 1.0  # [s] real time: zero and no state this long after the pose's second source
DECODERS: dict[str, Callable[[bytes], Any]] = {  # mailbox class -> payload reader
    keys.POSE: decode_pose, keys.STATE: decode_state, keys.OTHERS: decode_others,
    keys.ELLIPSE: decode_ellipse, keys.OBSTACLES: decode_obstacles, keys.BEACON: decode_ellipse,
}
Entry = tuple[Any, float]  # (message, local reception time)
Take = Callable[[zenoh.Sample], None]


class DecodeMemo:
    """A payload decoder that remembers the values of the last payloads it decoded, shared by
    every agent of one process: in an agent host each agent decodes the same ``obstacles``
    message every tick, the members of a formation the same ``others`` and the neighbours of a
    robot its same ``state`` (without it a host of N agents decodes each obstacles list N times).
    Decoded messages are frozen, so sharing one changes nothing an agent sees; a payload that
    does not decode raises every time (each agent counts its own drop). Thread-safe under
    the GIL (a lost insert costs one more decode); emptied when it holds ``size`` payloads."""

    def __init__(self, decode: Callable[[bytes], Any], size: int = 256) -> None:
        self._decode = decode
        self._size = size
        self._values: dict[bytes, Any] = {}

    def __call__(self, payload: bytes) -> Any:
        if type(payload) is not bytes:  # only bytes are hashable keys; decode anything else
            return self._decode(payload)
        value = self._values.get(payload)
        if value is None:
            value = self._decode(payload)
            if len(self._values) >= self._size:
                self._values.clear()
            self._values[payload] = value
        return value

    def stamped(self, payload: bytes) -> Entry:
        """The value of ``payload`` and the local reception time (taken on the calling thread:
        Zenoh's, or the tick's that drains a ring channel), in one call."""
        value = self._values.get(payload) if type(payload) is bytes else None
        if value is None:
            value = self(payload)
        return value, time.monotonic()


#: mailbox class -> the process's memo of its decoder (:class:`DecodeMemo`)
MEMOS: dict[str, DecodeMemo] = {cls: DecodeMemo(decode) for cls, decode in DECODERS.items()}


class PairMemo:
    """A pure check of two messages and a number, remembered by the messages' identity for the
    newest pairs of the process: the agents of one agent host hold the same decoded messages
    (:class:`DecodeMemo`), so each checks the same ``others`` message, or the same pair of
    obstacle lists, that its formation's other members checked a moment before. The pair is
    held with its verdict (an identity never stands for another message); thread-safe under
    the GIL (a lost insert costs one more check); emptied when it holds ``size`` pairs."""

    def __init__(self, check: Callable[[Any, Any, float], bool], size: int = 64) -> None:
        self._check = check
        self._size = size
        self._verdicts: dict[tuple[int, int, float], tuple[Any, Any, bool]] = {}

    def __call__(self, a: Any, b: Any, x: float) -> bool:
        key = (id(a), id(b), x)
        hit = self._verdicts.get(key)
        if hit is not None and hit[0] is a and hit[1] is b:
            return hit[2]
        verdict = self._check(a, b, x)
        if len(self._verdicts) >= self._size:
            self._verdicts.clear()
        self._verdicts[key] = (a, b, verdict)
        return verdict


def _pose_ok(msg: Any, prev: Any | None, speed: float) -> bool:
    return prev is None or jump_ok(prev.x, prev.y, prev.stamp, msg.x, msg.y, msg.stamp,
                                   speed, JUMP_MARGIN_M)


def _state_ok(msg: Any, prev: Any | None, speed: float) -> bool:
    if not velocity_ok(msg.ux, msg.uy, speed):
        return False
    return prev is None or jump_ok(prev.x, prev.y, prev.stamp, msg.x, msg.y, msg.stamp,
                                   speed, JUMP_MARGIN_M)


def _ellipse_check(msg: Any, _none: None, speed: float) -> bool:
    return ellipse_ok(msg, speed)


def _others_check(msg: Any, _none: None, speed: float) -> bool:
    return ellipses_ok(msg.ellipses, speed) and (msg.own is None or ellipse_ok(msg.own, speed))


_ELLIPSE_VERDICTS = PairMemo(_ellipse_check)  # an ellipse's verdict: of the message alone
_OTHERS_VERDICTS = PairMemo(_others_check)
_LISTS_AGREE = PairMemo(lambda kept, msg, _x: common_agree(kept, msg))  # obstacle lists


def _ellipse_ok(msg: Any, _prev: Any | None, speed: float) -> bool:
    return _ELLIPSE_VERDICTS(msg, None, speed)


def _others_ok(msg: Any, _prev: Any | None, speed: float) -> bool:
    return _OTHERS_VERDICTS(msg, None, speed)


#: mailbox class -> whether a message of it is physically possible after the kept one
#: (classes without a check: every message is)
PLAUSIBLE: dict[str, Callable[[Any, Any | None, float], bool]] = {
    keys.POSE: _pose_ok, keys.STATE: _state_ok, keys.ELLIPSE: _ellipse_ok,
    keys.BEACON: _ellipse_ok, keys.OTHERS: _others_ok,
}


def plausible(cls: str, msg: Any, prev: Any | None, speed: float) -> bool:
    """Whether ``msg`` is physically possible after ``prev`` (agent.plausibility)."""
    check = PLAUSIBLE.get(cls)
    return check is None or check(msg, prev, speed)


def exact_take(key: str, box: Mailbox) -> Take:
    """The ring channel's take of a subscriber on the exact ``key`` (no wildcards): each PUT
    sample's payload into ``box`` under ``key``, as ``box.callback`` does, without reading
    the key back from the sample; a DELETE carries no value and is ignored."""
    offer = box.offer

    def take(sample: zenoh.Sample) -> None:
        if sample.kind != _DELETE:
            offer(key, sample.payload.to_bytes())

    return take


_DELETE = zenoh.SampleKind.DELETE


class Receiver:
    """The receiver's side of the stamp check: its clock (the frame in lock-step, the wall
    clock in real time) and whether the world went on without it (:mod:`agent.clock`)."""

    def __init__(self, now: Callable[[], float], starved: Callable[[], bool], tolerance: float,
                 stale_after: float, speed: float) -> None:
        self.now = now
        self.starved = starved
        self.tolerance = tolerance
        self.stale_after = stale_after
        self.speed = speed  # [m/s] plausibility bound


class Inbox:
    """The latest accepted message per key (module docstring). ``lock`` is the tick lock: the
    inbox takes it where it stores from the loop while a tick may read on another thread.

    Over 20 attributes on purpose: every check a received message passes (its stamp, its
    plausibility, a second source, a marker re-acquire, the link faults) runs on the one accept
    path under that lock, and each reads the others' state (a contest resets a re-acquire run, a
    re-acquire needs the commands since the jump); split into objects they would each hold the
    others."""

    def __init__(self, robot_id: str, receiver: Receiver, counter: TrafficCounter,
                 link_faults: LinkFaults, timing: tuple[float, bool], lock: threading.Lock,
                 polled: bool) -> None:
        self.robot_id = robot_id
        self.receiver = receiver
        self.counter = counter
        period, lockstep = timing
        self.lockstep = lockstep
        self.faults = FaultInjector(link_faults, robot_id, period, lockstep, lock,
                                    self.store_delayed)
        self.polled = polled
        self.stamps = StampCounter()  # the one stamp check: rejections per class and reason
        self.catch_ups = 0  # lock-step: future frames taken after the world went on
        self.implausible: dict[str, int] = {}  # inputs refused as physically impossible, by class
        self._implausible_pending: set[str] = set()  # classes refused since the last tick
        self._boxes: dict[str, Mailbox] = {}
        self.subscribed_keys: dict[str, str] = {}  # key -> the mailbox class that holds it
        self._rings: list[tuple[Any, Take]] = []  # polled subscribers, drained by the tick
        self._late: set[str] = set()  # lock-step: keys whose last wait timed out
        # key -> the last used stamp of its kept message, never later than the clock was when
        # it was accepted (wire.stamps.used_stamp): what "older" is judged against
        self._used: dict[str, float] = {}
        # marker re-acquire (agent.plausibility.Reacquire): a run of jumped poses that agree,
        # taken once the robot has been commanded zero on every tick since the first of them
        self.reacquire = Reacquire(receiver.speed)
        self.reacquired = 0  # poses taken as the new kept pose after a jump
        self._still_since_jump = True
        # real time: when the pose last had a second source (:meth:`_conflicts`); the robot
        # commands zero and withholds its state until CONTEST_HOLD_S after it (:meth:`contested`)
        self._contested_at = -math.inf
        # real time: the obstacle lists of second sources, avoided beside the kept one
        self.rivals = ObstacleRivals()
        self.arrived = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._transport: Transport | None = None
        self._on_pose: Take | None = None
        self._ring_caps: dict[str, int] = {}

    # --- what is accepted -----------------------------------------------------------------------

    def acceptor(self, cls: str) -> Callable[[str, Entry, Entry | None], bool]:
        """The mailbox's ``accept`` for class ``cls``: the stamp check (future, stale, older than
        the one kept; counted per reason), then plausibility against the one kept (counted;
        the next tick commands zero). Runs where the mailbox stores: the loop's thread, or
        under the tick lock."""
        rx = self.receiver
        check = PLAUSIBLE.get(cls)  # the class's plausibility check, found once
        obstacles = cls == keys.OBSTACLES
        pose = cls == keys.POSE
        used = self._used

        def accept(key: str, value: Entry, prev: Entry | None) -> bool:
            msg = value[0]
            stamp = msg.stamp
            kept = None if prev is None else prev[0]
            now = rx.now()
            reason = check_stamp(now, stamp, None if kept is None else used.get(key, kept.stamp),
                                 rx.tolerance, rx.stale_after)
            if reason is not None:
                if reason == FUTURE and rx.starved():
                    reason = None  # lock-step: the world went on without this agent; catch up
                    self.catch_ups += 1
                else:
                    self.stamps.count(cls, reason)
            # stamped before the kept message (refused as older, or taken past a kept one
            # stamped ahead of the clock) and disagreeing with it: a second source on the key
            if kept is not None and stamp < kept.stamp and reason in (None, OLDER) \
                    and self._conflicts(cls, msg, kept):
                self._second_source(cls, msg, now)
                return False
            if reason is not None:
                return False
            # plausible after the kept message while that one is fresh; a stale one says nothing
            # any more (a robot carried elsewhere, or a forged first pose: it blocks for at most
            # stale_after)
            ref = None if kept is None or now - kept.stamp > rx.stale_after else kept
            if check is None or check(msg, ref, rx.speed):
                if pose:
                    self.reacquire.reset()
            elif self._refused(cls, msg):
                return False
            if obstacles and ref is not None:
                self._check_newer_list(msg, ref, now)
            used[key] = used_stamp(now, stamp)
            return True

        return accept

    def _refused(self, cls: str, msg: Any) -> bool:
        """An input that broke physics: refused and counted (the next tick commands zero),
        unless it is a pose that completes a re-acquire run (then taken; ``reacquired``)."""
        if cls == keys.POSE:
            if not self.reacquire.run:  # the first pose of a new jump
                self._still_since_jump = True
            if self.reacquire.offer(msg.x, msg.y, msg.stamp, self._still_since_jump):
                self.reacquired += 1
                logger.warning("%s: marker re-acquired at (%.3f, %.3f) after a jump",
                               self.robot_id, msg.x, msg.y)
                return False
        self._flag(cls, "refused")
        return True

    def _flag(self, cls: str, what: str, stop: bool = True) -> None:
        """Count an implausible input of class ``cls``; with ``stop``, the next tick commands
        zero."""
        self.implausible[cls] = self.implausible.get(cls, 0) + 1
        if stop:
            self._implausible_pending.add(cls)
        logger.info("%s: implausible %s %s", self.robot_id, cls, what)

    def _second_source(self, cls: str, msg: Any, now: float) -> None:
        """A message of a second source on its key (:meth:`_conflicts`), refused and counted. A
        pose: neither source is trusted until it has gone quiet (:meth:`contested`). An obstacle
        list: a rival, whose obstacles the robot avoids beside the kept list's
        (:meth:`obstacle_rivals`) rather than stop in a moving obstacle's way."""
        if cls == keys.OBSTACLES:
            self._flag(cls, "stamped before the kept one and disagreeing with it", stop=False)
            self.rivals.offer(msg, now)
            return
        self._flag(cls, "stamped before the kept one and disagreeing with it")
        self._contested_at = now
        if cls == keys.POSE:
            self.reacquire.reset()  # a second source's poses re-acquire nothing

    def _check_newer_list(self, msg: Obstacles, kept: Obstacles, now: float) -> None:
        """Real time: an obstacle list taken after ``kept`` that moves or drops what ``kept``
        reports (walls, shelves, an obstacle elsewhere than its velocity takes it) is one of two
        sources as well, and which one is genuine cannot be told: ``kept`` becomes a rival
        (counted), so both stay avoided. An obstacle missing from it is held
        (:class:`agent.plausibility.ObstacleMemory`)."""
        if not self.lockstep and not _LISTS_AGREE(kept, msg, 0.0):
            self._flag(keys.OBSTACLES, "moving or dropping what the kept one reports", stop=False)
            self.rivals.offer(kept, now)

    def _conflicts(self, cls: str, msg: Any, kept: Any) -> bool:
        """Real time: a pose or obstacle list stamped before the kept one that disagrees with it.
        One publisher's messages arrive in order, so this is a second source on the key (a
        faulty camera, a clock step, a forger stamping ahead: docs/faults.md), and neither is
        to be trusted (:meth:`_second_source`)."""
        if self.lockstep:
            return False
        if cls == keys.POSE:
            return not jump_ok(msg.x, msg.y, msg.stamp, kept.x, kept.y, kept.stamp,
                               self.receiver.speed)
        if cls == keys.OBSTACLES:
            return not obstacles_agree(msg, kept)
        return False

    def contested(self) -> bool:
        """Whether this robot's pose had a second source within :data:`CONTEST_HOLD_S` (real
        time; :meth:`_conflicts`), or its obstacle list more sources than it tracks
        (:class:`agent.plausibility.ObstacleRivals`): then the robot commands zero and publishes
        no state from its pose (its neighbours hold theirs, then stop as its state goes stale)
        until the input has been one source for that long."""
        now = self.receiver.now()
        return now - self._contested_at < CONTEST_HOLD_S or self.rivals.overflowed(now)

    def obstacle_rivals(self) -> tuple[Obstacles, ...]:
        """The obstacle lists of the sources other than the kept list's, while they come (real
        time; :class:`agent.plausibility.ObstacleRivals`): the tick avoids their obstacles
        too."""
        return self.rivals.current(self.receiver.now())

    def note_command(self, moving: bool) -> None:
        """The node sent a command; ``moving``: not the zero command (ends "still since the
        jump" for the re-acquire run under way)."""
        if moving:
            self._still_since_jump = False

    def take_implausible(self) -> bool:
        """Whether an input broke physics since the last call (then forgotten)."""
        if not self._implausible_pending:
            return False
        self._implausible_pending.clear()
        return True

    def mailbox(self, cls: str) -> Mailbox:
        """The mailbox of class ``cls``, made on first use (inline when polled)."""
        box = self._boxes.get(cls)
        if box is None:
            box = self._boxes[cls] = Mailbox(None if self.polled else self._loop,
                                             MEMOS[cls].stamped, counter=self.counter,
                                             accept=self.acceptor(cls))
        return box

    def offer(self, cls: str, key: str, payload: bytes) -> None:
        """Hand ``payload`` to the mailbox of ``cls`` on the calling thread (as a subscriber
        would; tests and the pose callback)."""
        self.mailbox(cls).offer(key, payload)

    # --- reading --------------------------------------------------------------------------------

    def latest(self, cls: str, key: str) -> Entry | None:
        box = self._boxes.get(cls)
        return None if box is None else box.latest(key)

    def values(self, cls: str) -> dict[str, Any]:
        """Every key of class ``cls`` held -> its entry."""
        box = self._boxes.get(cls)
        return {} if box is None else dict(box.values())

    def counts(self) -> dict[str, dict[str, int]]:
        """Per class: malformed payloads dropped, messages refused, samples received."""
        boxes = self._boxes.items()
        return {"dropped": {cls: box.dropped_malformed for cls, box in boxes},
                "rejected": {cls: box.rejected for cls, box in boxes},
                "received": {cls: box.received for cls, box in boxes}}

    @property
    def dropped_malformed(self) -> int:
        return sum(box.dropped_malformed for box in self._boxes.values())

    # --- lock-step waits ------------------------------------------------------------------------

    def missing(self, inputs: list[tuple[str, str]], t: float) -> list[str]:
        """Lock-step: the keys of ``inputs`` not late and not yet holding the tick ``t``'s."""
        return [k for cls, k in inputs if k not in self._late and not self.current(cls, k, t)]

    def current(self, cls: str, key: str, t: float) -> bool:
        """Lock-step: the message on ``key`` belongs to the tick stamped ``t`` (or later), or,
        under added delay, to the newest tick that can have arrived; or it was lost."""
        need = self.faults.need(cls, t)
        entry = self.latest(cls, key)
        if entry is not None and entry[0].stamp >= need - EPS:
            return True
        return self.faults.lost_since(key, need)

    def mark_late(self, late: list[str]) -> None:
        self._late.update(late)

    def advance(self, t: float) -> bool:
        """Lock-step: release the delayed inputs due at ``t``; True if there is a delay line."""
        if self.faults.delay_line is None:
            return False
        self.faults.advance(t)
        return True

    def on_arrival(self, key: str) -> None:
        """Loop thread: something arrived on ``key`` (its publisher is alive): wake the tick."""
        self._late.discard(key)
        self.arrived.set()

    # --- subscribers ----------------------------------------------------------------------------

    def open(self, transport: Transport, loop: asyncio.AbstractEventLoop, on_pose: Take,
             ring_caps: dict[str, int]) -> None:
        """Subscribe through ``transport``; ``on_pose`` receives the pose samples when polled;
        ``ring_caps``: ring channel sizes by class beyond :data:`RING_CAPACITY`."""
        self._transport, self._loop, self._on_pose = transport, loop, on_pose
        self._ring_caps = ring_caps

    def declare(self, key: str, cls: str) -> None:
        """Subscribe to ``key`` into the mailbox of class ``cls``."""
        self.install(key, cls, *self.make(key, cls))

    def make(self, key: str, cls: str) -> tuple[Any, Take | None]:
        """Declare the subscriber of ``key``: (subscriber, the take of its ring channel, None
        when it has a callback). Touches no state a tick reads, so it may run outside the tick
        lock (:meth:`agent.leader_step.LeaderPart.relisten`)."""
        t = self._transport
        assert t is not None and self._on_pose is not None  # set by open()
        box = self.mailbox(cls)
        if self.polled and cls != keys.POSE:
            cap = max(RING_CAPACITY, self._ring_caps.get(cls, 0))
            return (t.declare(key, zenoh.handlers.RingChannel(cap)),
                    self._handler(cls, box, notify=False, key=key))
        if self.polled:  # the pose: tick right on the Zenoh thread that received it
            return t.declare(key, in_order(self._on_pose)), None
        return t.declare(key, self._handler(cls, box)), None

    def install(self, key: str, cls: str, sub: Any, take: Take | None) -> None:
        """Record a subscriber :meth:`make` declared (under the tick lock once ticks run: a ring
        channel joins the ones the tick drains)."""
        assert self._transport is not None
        if take is not None:
            self._rings.append((sub, take))
        self._transport.keep(key, sub)
        self.subscribed_keys[key] = cls

    def forget(self, key: str) -> Any:
        """Under the tick lock: stop draining and recording the subscriber of ``key``; it is
        returned for the caller to undeclare (outside the lock). Its mailbox keeps what came."""
        assert self._transport is not None
        sub = self._transport.forget(key)
        self._rings = [r for r in self._rings if r[0] is not sub]
        del self.subscribed_keys[key]
        return sub

    def drain(self) -> None:
        """Real time: hand every sample waiting in the ring channels to its mailbox (an inline
        one: stored at once)."""
        for sub, take in self._rings:
            while (sample := sub.try_recv()) is not None:
                take(sample)

    def close(self) -> None:
        self._rings.clear()

    def store_delayed(self, key: str, payload: bytes) -> None:
        """A delayed payload (:class:`FaultInjector`) into its mailbox; wakes the tick."""
        cls = self.subscribed_keys.get(key, keys.STATE)  # all-to-all: a wildcard's concrete key
        self.mailbox(cls).offer(key, payload)
        self.on_arrival(key)

    def _handler(self, cls: str, box: Mailbox, notify: bool = True, key: str | None = None
                 ) -> Take:
        """A subscriber's callback: the sample to ``box`` (through the link faults for a
        faulted class) and, with ``notify``, a wake-up of the loop's tick. ``key``: the
        subscriber's key; one without wildcards is every sample's key, so it is not read back
        from each sample."""
        loop = self._loop
        assert loop is not None  # set by open()
        decode = DECODERS[cls]
        faults = self.faults
        faulty = faults.applies_to(cls)
        if not (faulty or notify):  # polled: straight into the mailbox
            if key is None or "*" in key or "$" in key:
                return box.callback
            return exact_take(key, box)

        def on_sample(sample: zenoh.Sample) -> None:
            if faulty and sample.kind != zenoh.SampleKind.DELETE:
                faults.sample(loop, cls, decode, str(sample.key_expr), sample.payload.to_bytes(),
                              box.offer)
            else:
                box.callback(sample)
            if not notify:
                return
            try:
                loop.call_soon_threadsafe(self.on_arrival, str(sample.key_expr))
            except RuntimeError:  # loop closed: shutting down
                pass

        return on_sample
