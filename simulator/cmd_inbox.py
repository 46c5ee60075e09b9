"""The world's command inbox: the latest command of every robot, kept only when its stamp
passes the one stamp check (:mod:`wire.stamps`), filled on Zenoh's threads and read by the
world's loop (:class:`simulator.world.World`)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import zenoh

from wire import keys
from wire.payloads import Cmd, DecodeError, decode_cmd
from wire.stamps import CLOCK_TOLERANCE_S, EPS, StampCounter, used_stamp
from wire.traffic import TrafficCounter


class CmdInbox:
    """Latest command per robot, filled on Zenoh's threads, read by the world's loop."""

    def __init__(self, prefix: str, counter: TrafficCounter, robots: Sequence[str],
                 stale_after: float = 0.25) -> None:
        self._prefix = prefix
        self._counter = counter
        self.stamps = StampCounter()  # commands refused by the stamp check
        self.stale_after = stale_after
        self.realtime = False
        self.clock_offset = 0.0  # [s] real time: the camera's clock minus the wall clock
        self.now_t = 0.0  # lock-step: the simulated time of the tick under way
        self._robot_of = {keys.cmd_key(prefix, r): r for r in robots}  # cmd key -> robot
        self._cond = threading.Condition()
        self.latest: dict[str, tuple[Cmd, float]] = {}  # robot -> (cmd, local receive time)
        # robot -> its kept command's last used stamp, never later than the clock was when it
        # came (wire.stamps.used_stamp): one command stamped ahead cannot hide the later ones
        self._used: dict[str, float] = {}
        self.late: set[str] = set()  # lock-step: robots whose last command timed out
        # lock-step: robots not waited for at the tick under way only (an agent restarted during
        # it never saw its poses); cleared when the next tick starts
        self.excused: set[str] = set()
        self.malformed = 0
        self.latency_ms: list[float] = []
        self.measure_latency = False

    def callback(self, sample: zenoh.Sample) -> None:
        """The subscriber of every robot's ``cmd`` (one wildcard); other robots' are ignored."""
        key = str(sample.key_expr)
        rid = self._robot_of.get(key)
        if rid is None:
            return
        data = sample.payload.to_bytes()
        try:
            cmd = decode_cmd(data)
        except DecodeError:
            self._counter.count_recv(key, len(data))
            with self._cond:
                self.malformed += 1
            return
        self.offer(rid, cmd, key, len(data))

    def count_malformed(self) -> None:
        with self._cond:
            self.malformed += 1

    def offer(self, rid: str, cmd: Cmd, key: str, nbytes: int) -> None:
        """``rid``'s command ``cmd`` (``nbytes`` on ``key``), kept if its stamp passes."""
        self._counter.count_recv(key, nbytes)
        now = time.monotonic()
        with self._cond:
            prev = self.latest.get(rid)
            if self.realtime:
                clock, tolerance = time.time() + self.clock_offset, CLOCK_TOLERANCE_S
            else:
                clock, tolerance = self.now_t, 0.0  # only this tick's (or older) commands
            if not self.stamps.check(keys.CMD, clock, cmd.stamp,
                                     None if prev is None else self._used.get(rid, prev[0].stamp),
                                     tolerance, self.stale_after):
                return
            self._used[rid] = used_stamp(clock, cmd.stamp)
            if self.measure_latency and (prev is None or prev[0].stamp != cmd.stamp):
                self.latency_ms.append((time.time() + self.clock_offset - cmd.stamp) * 1e3)
            self.latest[rid] = (cmd, now)
            self.late.discard(rid)
            self._cond.notify_all()

    def expect(self, rid: str) -> None:
        """Lock-step: wait for ``rid``'s commands again (a restarted agent), instead of only once
        one of them arrives: the world does not run ahead of it."""
        with self._cond:
            self.late.discard(rid)

    def excuse(self, rid: str) -> None:
        """Lock-step: do not wait for ``rid``'s command of the tick under way (its agent was
        restarted after the tick's poses went out, so none will come); from the next tick on it
        is waited for again, not late."""
        with self._cond:
            self.late.discard(rid)
            self.excused.add(rid)
            self._cond.notify_all()

    def waited_for(self, rid: str) -> bool:
        """Lock-step: whether this tick's step waits for ``rid``'s command (call under the
        lock, as :meth:`wait`'s ``ready`` is)."""
        return rid not in self.late and rid not in self.excused

    def all_in(self, t: float, robots: Sequence[str]) -> bool:
        """Lock-step: the step barrier of the tick stamped ``t``: every robot of ``robots``
        waited for has a command stamped ``t`` (call under the lock, as :meth:`wait`'s
        ``ready``)."""
        return all(r in self.latest and abs(self.latest[r][0].stamp - t) <= EPS
                   for r in robots if self.waited_for(r))

    def begin_tick(self, t: float) -> None:
        """Lock-step: the tick at simulated time ``t`` starts (before its poses go out): the
        stamp check's clock for the commands that arrive from now on."""
        with self._cond:
            self.now_t = t
            self.excused.clear()

    def fresh(self, now: float, max_age: float, robots: Sequence[str] | None = None) -> dict[str, Cmd]:
        """The latest command of each robot (of ``robots``; default every one heard) whose
        *stamp* is at most ``max_age`` before ``now`` (the camera's clock: ``time.time()`` plus
        the clock offset), however late it arrived."""
        with self._cond:
            if robots is None:
                return {r: c for r, (c, _rx) in self.latest.items() if now - c.stamp <= max_age}
            entries = ((r, self.latest.get(r)) for r in robots)
            return {r: e[0] for r, e in entries if e is not None and now - e[0].stamp <= max_age}

    def take_since(self, t: float, robots: Sequence[str]) -> tuple[dict[str, Cmd], list[str]]:
        """Lock-step: the commands stamped exactly ``t`` (the step barrier counts nothing else),
        and the robots of ``robots`` that sent none and were not late already (now marked
        late)."""
        with self._cond:
            got = {r: c for r, (c, _rx) in self.latest.items() if abs(c.stamp - t) <= EPS}
            late = [r for r in robots if r not in got and self.waited_for(r)]
            self.late.update(late)
        return got, late

    def wait(self, ready: Callable[[], bool], timeout: float, abort: Callable[[], None]) -> bool:
        """Wait until ``ready()`` (checked under the lock) or the timeout; ``abort()`` is called
        between waits, outside the lock, and may raise."""
        deadline = time.monotonic() + timeout
        while True:
            with self._cond:
                if ready():
                    return True
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.wait(min(remaining, 0.1))
                if ready():
                    return True
            abort()
