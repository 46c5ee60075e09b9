"""``formation deploy --status`` for robots on rmw_zenoh: is each base's ``cmd_vel``
subscription there? Asked of the fleet's router over liveliness (the robot's ``rmw_zenohd`` is
linked to it, :mod:`deploy.rmw_zenoh`), as the viewer under access control."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import zenoh

from wire import rmw_zenoh as rmw
from wire.acl import VIEWER_USER
from wire.zconf import make_config

from .inventory import Inventory
from .rmw_zenoh import rmw_robots
from .secure import SERVICE_FILES

logger = logging.getLogger(__name__)

STATUS_TIMEOUT_S = 5.0


def base_subscribers(session: Any, inv: Inventory,
                     timeout_s: float = STATUS_TIMEOUT_S) -> dict[str, list[str]]:
    """robot id -> the nodes (``/ns/name``) whose rmw_zenoh subscription reads the robot's
    command key (empty: the base is not there), asked of the router over liveliness."""
    out: dict[str, list[str]] = {}
    for rid, s in rmw_robots(inv).items():
        rel, type_name = rmw.resolve(s, rmw.distro_of(inv.base))
        topic = rmw.fully_qualified(s.namespace, "cmd_vel")
        selector = rmw.subscription_selector(s.domain, topic, type_name, rel)
        nodes = []
        for reply in session.liveliness().get(selector, timeout=timeout_s):
            if reply.ok is None:
                continue
            try:
                e = rmw.parse_token(str(reply.ok.key_expr))
            except ValueError:
                continue
            nodes.append(f"{e.namespace.rstrip('/')}/{e.node_name}")
        out[rid] = sorted(set(nodes))
    return out


def viewer_file(inv: Inventory) -> Path | None:
    """The viewer's credentials (a Zenoh config file) under access control, else None."""
    if not inv.zenoh.access_control:
        return None
    return inv.zenoh.secrets / SERVICE_FILES[VIEWER_USER]


def status_lines(inv: Inventory, viewer_file: Path | None = None) -> list[str]:
    """One line per rmw_zenoh robot: whether its base's ``cmd_vel`` subscriber is present.
    With access control, the viewer's credentials file (a Zenoh config) opens the session."""
    if not rmw_robots(inv):
        return []
    try:
        if viewer_file is not None:
            conf = zenoh.Config.from_file(str(viewer_file))
        else:
            conf = make_config("client", connect=[inv.zenoh.router] if inv.zenoh.router else [])
        session = zenoh.open(conf)
    except Exception as exc:  # noqa: BLE001 - zenoh.ZError: the router (or the file) is not there
        return [f"rmw_zenoh: cannot reach the router to look for the bases: {exc}"]
    try:
        found = base_subscribers(session, inv)
    finally:
        session.close()
    return [format_status(rid, nodes) for rid, nodes in found.items()]


def format_status(rid: str, nodes: list[str]) -> str:
    if nodes:
        return f"{rid:10s} rmw_zenoh base: cmd_vel subscriber present ({', '.join(nodes)})"
    return f"{rid:10s} rmw_zenoh base: NO cmd_vel subscriber (is the robot's bringup running?)"
