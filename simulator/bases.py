"""The simulated world plays robot bases on rmw_zenoh (``formation run --base rmw_zenoh``).

Each agent then drives its base as it would a TurtleBot3 running ROS 2 on rmw_zenoh
(:class:`agent.base.RmwZenohBase`), in the ROS namespace of its robot id, and the world takes
each robot's command from that robot's rmw_zenoh data key instead of the project's ``cmd`` key,
reading it as an rmw_zenoh subscription does: a sample without a well-formed attachment of the
release's layout is dropped (and counted), as ``SubscriptionData`` drops it; the CDR payload
gives ``v`` and ``omega``. The stamp the world judges a command by is the ``TwistStamped``
header's (the pose stamp the agent answered, as on the ``cmd`` key) or, for a ``Twist``, the
attachment's source timestamp (the agent's wall clock when it published).

A unicycle's ``(v, omega)`` is all a ROS base takes, so only unicycle scenarios can run this way.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

from agent.base import decode_cmd
from wire import rmw_zenoh as rmw
from wire.payloads import Cmd
from wire.traffic import in_order

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RmwBase:
    """What the world reads for one robot: its data key, message type and attachment layout."""

    robot: str
    key: str
    type_name: str  # geometry_msgs/msg/Twist or TwistStamped
    layout: str  # rmw.KEYED | rmw.POSITIONAL


def robot_settings(robot: str, settings: rmw.RmwSettings) -> rmw.RmwSettings:
    """``settings`` for ``robot``: its namespace is its id (``ros_namespace`` of a run)."""
    return rmw.check_settings(rmw.RmwSettings(settings.release, settings.cmd_type, robot,
                                              settings.domain))


def plan_bases(robots: Sequence[str], settings: rmw.RmwSettings, distro: str
               ) -> dict[str, RmwBase]:
    """robot id -> :class:`RmwBase` for a run whose robots' bases speak ``distro``'s ROS."""
    out = {}
    for r in robots:
        s = robot_settings(r, settings)
        rel, type_name = rmw.resolve(s, distro)
        out[r] = RmwBase(r, rmw.data_key(s, distro), type_name, rel.attachment)
    return out


def command_of(base: RmwBase, payload: bytes, attachment: bytes | None) -> Cmd:
    """The :class:`Cmd` a sample on ``base.key`` carries; ``ValueError`` when rmw_zenoh would
    not deliver it (no attachment, a malformed one) or its CDR is malformed."""
    if attachment is None:
        raise ValueError("no attachment (rmw_zenoh drops such a sample)")
    att = rmw.decode_attachment(attachment, base.layout)
    v, omega, stamp = decode_cmd(base.type_name, payload)
    if stamp is None:
        stamp = att.source_timestamp * 1e-9
    return Cmd(v=v, omega=omega, ux=0.0, uy=0.0, stamp=stamp)


class RmwBaseReader:
    """The world's subscriptions to every robot's rmw_zenoh data key: each good command goes
    to ``offer(robot, cmd, key, nbytes)``; the rest are counted in :attr:`dropped` and
    reported to ``on_drop`` (the world's malformed commands)."""

    def __init__(self, bases: Mapping[str, RmwBase],
                 offer: Callable[[str, Cmd, str, int], None],
                 on_drop: Callable[[], None] | None = None) -> None:
        self._bases = {b.key: b for b in bases.values()}
        self._offer = offer
        self._on_drop = on_drop
        self._lock = threading.Lock()
        self.dropped = 0
        self._subs: list[Any] = []

    def callback(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        base = self._bases.get(key)
        if base is None:
            return
        payload = sample.payload.to_bytes()
        att = sample.attachment
        try:
            cmd = command_of(base, payload, None if att is None else att.to_bytes())
        except ValueError as exc:
            with self._lock:
                self.dropped += 1
            logger.debug("%s: dropped: %s", key, exc)
            if self._on_drop is not None:
                self._on_drop()
            return
        self._offer(base.robot, cmd, key, len(payload))

    def declare(self, session_of: Callable[[str], Any]) -> list[Any]:
        """One subscriber per robot, on the session ``session_of(robot)`` gives."""
        self._subs = [session_of(b.robot).declare_subscriber(
            b.key, in_order(self.callback))
            for b in self._bases.values()]
        return self._subs


def base_of(settings: rmw.RmwSettings) -> str:
    """The agents' base for a run: the release's distribution (default Jazzy)."""
    distro = rmw.release(settings.release).distro if settings.release else "jazzy"
    return "turtlebot3-humble" if distro == "humble" else "turtlebot3-jazzy"


def run_bases(robots: Sequence[str], settings: rmw.RmwSettings) -> dict[str, RmwBase]:
    """The bases the world plays in a run with ``settings`` (namespace: each robot's id)."""
    return plan_bases(robots, settings, rmw.distro_of(base_of(settings)))


def with_rmw_bases(configs: Mapping[str, Any], settings: rmw.RmwSettings) -> dict[str, Any]:
    """Each robot's :class:`agent.config.AgentConfig` driving its base over rmw_zenoh."""
    return {rid: dataclasses.replace(cfg, base=base_of(settings),
                                     rmw=robot_settings(rid, settings))
            for rid, cfg in configs.items()}
