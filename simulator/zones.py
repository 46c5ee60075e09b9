"""Pose zones: the world's poses and the agents' commands through zone routers, not the run's.

Measured (docs/performance.md): with one router for everything, a pose went world ->
router -> agent and its command agent -> router -> world, and the router's one process relayed
every pose, command and state of the fleet. With ``Z`` pose zones the world opens ``Z`` Zenoh
sessions in ``router`` mode, each listening on its own endpoint and linked to the run's router,
as ``Z`` camera zones would each publish the robots they see. The robots are split into zones by
formation (a formation's robots share a zone, so the states its members exchange stay in that
zone's router); each agent connects to its zone's endpoint instead of the run's router. A pose
then goes straight from the world's zone session to its agent, the command straight back, and a
formation's states are relayed by its zone; only what crosses zones (obstacles, other formations'
states, a viewer's subscriptions) goes through the run's router.

The zone routers are sessions of the world's process: their routing runs on Zenoh's threads,
not the world's Python thread.

Secure runs (:class:`ZoneSecurity`): each zone router holds the run's access control list and
user dictionary, so the robots log in to it as themselves under the same policies as at the
run's router; it links to the run's router over a Unix socket in a private folder, logging in
as :data:`wire.acl.ZONE_USER` (allowed to relay), and trusts that link by its protocol
(:func:`wire.acl.zone_router_config`).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from runtime.ports import free_tcp_port, tcp_endpoint
from scenario import Scenario
from wire.acl import zone_router_config
from wire.zconf import UsrPwdAuth, ZenohSettings

logger = logging.getLogger(__name__)


def zone_assignment(scenario: Scenario, zones: int, per_process: int = 1) -> dict[str, int]:
    """Robot -> zone index. The units are the formations (or, with agent hosts of
    ``per_process`` K > 1, the hosts: K robots at a time in the scenario's order, so a host's
    one session serves one zone), split in order into ``zones`` contiguous groups of nearly
    equal size (unit ``k`` of ``U`` in zone ``k * Z // U``); more zones than units is capped at
    one zone per unit."""
    for name, v in (("pose zones", zones), ("per_process", per_process)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name}: must be an integer >= 1, got {v!r}")
    ids = scenario.robot_ids
    units = ([[r.id for r in f.robots] for f in scenario.formations] if per_process == 1
             else [list(ids[i:i + per_process]) for i in range(0, len(ids), per_process)])
    z = min(zones, len(units))
    return {rid: k * z // len(units) for k, unit in enumerate(units) for rid in unit}


def zone_count(zone_of: Mapping[str, int]) -> int:
    return max(zone_of.values(), default=-1) + 1


@dataclass(frozen=True)
class ZoneSecurity:
    """What a secure run's zone routers need: the run's ACL and user dictionary, the Unix-socket
    endpoint of the run's router (:data:`wire.acl.ZONE_LINK`) and the zone user's login."""

    acl: Mapping[str, Any]
    dictionary: Path
    link: str
    auth: UsrPwdAuth


class PoseZones:
    """``Z`` zone routers (Zenoh sessions in router mode) linked to the run's router at
    ``router_endpoint``; ``endpoint_of(robot)`` is where that robot's agent connects.
    Close with :meth:`close` (or use as a context manager)."""

    def __init__(self, scenario: Scenario, zones: int, router_endpoint: str,
                 per_process: int = 1, connect_timeout_s: float = 10.0,
                 security: ZoneSecurity | None = None) -> None:
        self.zone_of = zone_assignment(scenario, zones, per_process)
        self.endpoints: list[str] = []
        self.sessions: list[zenoh.Session] = []
        try:
            for _ in range(zone_count(self.zone_of)):
                endpoint = tcp_endpoint(free_tcp_port())
                if security is None:
                    conf = ZenohSettings(mode="router", listen=(endpoint,),
                                         connect=(router_endpoint,), multicast_scouting=False,
                                         connect_timeout_s=connect_timeout_s,
                                         scouting_delay_s=0.0).to_config()
                else:
                    d = zone_router_config([endpoint], security.acl, security.dictionary,
                                           security.link, security.auth)
                    d["connect"]["timeout_ms"] = round(connect_timeout_s * 1000)
                    d["scouting"]["delay"] = 0
                    conf = zenoh.Config.from_json5(json.dumps(d))
                self.sessions.append(zenoh.open(conf))
                self.endpoints.append(endpoint)
        except BaseException:
            self.close()
            raise
        logger.info("pose zones: %d zone routers at %s", len(self.sessions),
                    ", ".join(self.endpoints))

    def endpoint_of(self, rid: str) -> str:
        return self.endpoints[self.zone_of[rid]]

    def robots_of(self, zone: int) -> Sequence[str]:
        return [r for r, z in self.zone_of.items() if z == zone]

    def close(self) -> None:
        sessions, self.sessions = self.sessions, []
        for s in sessions:
            s.close()

    def __enter__(self) -> PoseZones:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
