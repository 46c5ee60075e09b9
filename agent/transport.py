"""The agent's transport: one Zenoh session and what the agent declared on it (publishers,
subscribers, liveliness handles), so that the parts that publish or subscribe share one
record of it and closing undeclares everything once.

:class:`CommandOut` is the way the agent's commands leave: published on ``cmd`` and, on a real
robot, sent to its base, one at a time and none but zero once the way out's zero has gone.

The interface is small on purpose: :meth:`Transport.publish` a message on a declared key,
:meth:`Transport.declare` a subscriber (recorded with :meth:`Transport.keep`),
:meth:`Transport.forget` one, and :meth:`Transport.forget_publishers` the publishers a changed
formation no longer puts on (each handed back for the caller to undeclare outside its lock).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Collection
from typing import Any

from runtime.shutdown import STEP_LIMIT_S
from wire import keys
from wire.payloads import Cmd
from wire.traffic import CountingPublisher, TrafficCounter

logger = logging.getLogger(__name__)


class Transport:
    """What one agent declared on its Zenoh session (module docstring)."""

    def __init__(self, session: Any, counter: TrafficCounter) -> None:
        self.session = session
        self._counter = counter
        self._pubs: dict[str, Any] = {}
        self._subs: list[Any] = []  # subscribers and liveliness handles, undeclared on close
        self._sub_by_key: dict[str, Any] = {}

    # --- publishing -----------------------------------------------------------------------------

    def publisher(self, key: str) -> None:
        """Declare a (counted) publisher on ``key`` unless there is one."""
        if key not in self._pubs:
            self.adopt(key, CountingPublisher(self.session.declare_publisher(key), self._counter))

    def adopt(self, key: str, publisher: Any) -> None:
        """Publish on ``key`` through ``publisher`` (anything with ``put_message`` and
        ``undeclare``: a counted Zenoh publisher, or a stand-in)."""
        self._pubs[key] = publisher

    def publish(self, key: str, msg: Any) -> bool:
        """Put ``msg`` on ``key``; False (nothing sent) when no publisher is declared there."""
        pub = self._pubs.get(key)
        if pub is None:
            return False
        pub.put_message(msg)
        return True

    def publishing(self) -> list[str]:
        """The keys with a declared publisher, sorted."""
        return sorted(self._pubs)

    def forget_publishers(self, scope: str, keep: Collection[str]) -> list[Any]:
        """Stop recording the publishers on keys under ``scope`` (a key prefix ending in ``/``,
        e.g. :func:`formation_scope`) that are not in ``keep``; returned for the caller to
        undeclare (a publish on their keys then sends nothing, :meth:`publish`)."""
        gone = [k for k in self._pubs if k.startswith(scope) and k not in keep]
        return [self._pubs.pop(k) for k in gone]

    # --- subscribing ----------------------------------------------------------------------------

    def declare(self, key: str, handler: Any) -> Any:
        """Declare a subscriber on ``key`` (recorded only once :meth:`keep` is called)."""
        return self.session.declare_subscriber(key, handler)

    def keep(self, key: str | None, sub: Any) -> None:
        """Record a subscriber (``key`` None: a handle with no key, e.g. a liveliness one)."""
        self._subs.append(sub)
        if key is not None:
            self._sub_by_key[key] = sub

    def forget(self, key: str) -> Any:
        """Stop recording the subscriber of ``key``; returned for the caller to undeclare."""
        sub = self._sub_by_key.pop(key)
        self._subs.remove(sub)
        return sub

    # --- closing --------------------------------------------------------------------------------

    def handles(self) -> list[Any]:
        """Every subscriber, handle and publisher declared, for undeclaring."""
        return [*self._subs, *self._pubs.values()]

    def clear(self) -> None:
        self._subs.clear()
        self._sub_by_key.clear()
        self._pubs.clear()


def formation_scope(prefix: str, formation: str) -> str:
    """The prefix of every key of formation ``formation`` (``{prefix}/formation/{fid}/``)."""
    return keys.ellipse_key(prefix, formation).removesuffix(keys.ELLIPSE)


class CommandOut:
    """Where an agent's commands go (its ``cmd`` key and its base, :mod:`agent.base`), one at a
    time, and none but zero after the way out's zero: a tick that outlived closing (the tick
    lock not had in time) must not follow the zero."""

    def __init__(self, robot_id: str, cmd_key: str, note_command: Callable[[bool], None]) -> None:
        self.robot_id = robot_id
        self.cmd_key = cmd_key
        self.note_command = note_command  # the inbox's: a moving command or not (agent.inbox)
        self.transport: Transport | None = None
        self.base: Any = None  # a real robot base adapter (agent.base), when cfg.base is not "world"
        self.zero_sent = False  # the zero command of the way out has been published
        self.lock = threading.Lock()
        self.late_commands = 0  # commands of such a tick, dropped and logged

    def send_command(self, cmd: Cmd) -> None:
        """Publish a tick's command (and drive the base), unless the way out's zero went first:
        then a non-zero command is dropped and counted (``late_commands``)."""
        moving = any((cmd.v, cmd.omega, cmd.ux, cmd.uy))
        with self.lock:
            if self.zero_sent and moving:
                self.late_commands += 1
                logger.warning("%s: a tick outlived closing: its command after the zero dropped",
                               self.robot_id)
                return
            self.send(cmd, moving)

    def send(self, cmd: Cmd, moving: bool = False) -> None:
        """Under :attr:`lock`: publish ``cmd`` (``moving``: not zero) and drive the base."""
        self.note_command(moving)
        if self.transport is not None:
            self.transport.publish(self.cmd_key, cmd)
        if self.base is not None:
            self.base.send(cmd.v, cmd.omega, cmd.stamp)

    def zero_on_exit(self, stamp: float) -> None:
        """The way out's zero command; none but zero follows it."""
        with self.lock:
            self.send(Cmd(0.0, 0.0, 0.0, 0.0, stamp))
            self.zero_sent = True

    def emergency_zero(self, stamp: float) -> bool:
        """From any thread and without the tick lock (a shutdown that overran its time limit):
        publish the zero command unless the way out's zero went already. True once it is sent.
        The command lock is waited for at most ``STEP_LIMIT_S`` (a publish that hangs holds it)."""
        if self.zero_sent:
            return True
        t = self.transport
        locked = self.lock.acquire(timeout=STEP_LIMIT_S)
        try:
            if self.zero_sent:
                return True
            if t is None or not t.publish(self.cmd_key, Cmd(0.0, 0.0, 0.0, 0.0, stamp)):
                return False
            if self.base is not None:
                self.base.send(0.0, 0.0, stamp)
        except Exception:  # last resort: report, the caller exits anyway
            logger.exception("%s: emergency zero command failed", self.robot_id)
            return False
        finally:
            if locked:
                self.lock.release()
        self.zero_sent = True
        return True
