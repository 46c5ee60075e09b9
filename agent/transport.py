"""The agent's transport: one Zenoh session and what the agent declared on it (publishers,
subscribers, liveliness handles), so that the parts that publish or subscribe share one
record of it and closing undeclares everything once.

The interface is small on purpose: :meth:`Transport.publish` a message on a declared key,
:meth:`Transport.declare` a subscriber (recorded with :meth:`Transport.keep`),
:meth:`Transport.forget` one (handed back for the caller to undeclare outside its lock).
"""

from __future__ import annotations

from typing import Any

from wire.traffic import CountingPublisher, TrafficCounter


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
