"""Per-robot Zenoh users for a deployed fleet, and the router's access control.

With ``zenoh.access_control`` on (the default in client mode), deploy gives every process of the
fleet its own Zenoh user, each with only the rights it needs (:func:`wire.acl.fleet_acl`):

* robot ``r`` (user ``r``): its own ``state``, ``cmd`` and ``diag``, its base's ``cmd_vel`` key
  (the inventory's ``cmd_vel_key``; ``zenoh-bridge-ros2dds`` on the robot logs in as the same
  user and may subscribe to that key only), and, for the leader and the member that takes over
  when the leader dies (:mod:`scenario.succession`), the formation's ``ellipse``, ``others``,
  ``status``, ``plan`` and the leader's liveliness token;
* ``camera``: the poses and the obstacles;
* ``manager``: goals (and status queries);
* ``viewer``: reads only.

The credentials live in the inventory's ``zenoh.secrets`` folder (default ``secure`` beside the
inventory; mode 0700, files 0600) and are kept across deploys (a redeploy changes nothing on the
robots)::

    users.txt        the router's user:password dictionary
    router.json5     the router's configuration: listen on zenoh.router, the dictionary, the ACL
                     (python -m runtime.router --config router.json5 on the router's machine; if the
                     folder moves there, the dictionary path in it must follow)
    camera.json5     the camera service's, manager.json5 the fleet manager's, viewer.json5 a
                     viewer's credentials: Zenoh configuration fragments for --auth FILE

Each robot's user and password go into its ``zenoh.json5`` and ``zenoh-bridge.json5``
(:mod:`deploy.zenoh_config`), installed with mode 0600.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from scenario import Scenario
from scenario.succession import formation_successor
from wire import acl
from wire.zconf import UsrPwdAuth

from . import rmw_zenoh
from .inventory import Inventory, InventoryError

logger = logging.getLogger(__name__)

DICTIONARY = "users.txt"
ROUTER_CONFIG = "router.json5"
SERVICE_FILES = {acl.CAMERA_USER: "camera.json5", acl.MANAGER_USER: "manager.json5",
                 acl.VIEWER_USER: "viewer.json5"}


@dataclass(frozen=True)
class FleetSecrets:
    folder: Path
    creds: dict[str, UsrPwdAuth]  # user -> credentials (robots by id, and the service users)
    router_config: dict  # the router's whole configuration


def read_dictionary(path: Path) -> dict[str, UsrPwdAuth]:
    """The ``user:password`` lines of a router dictionary (empty if there is none)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return {}
    except OSError as exc:
        raise InventoryError(f"zenoh.secrets: cannot read {path}: {exc.strerror or exc}") from None
    out = {}
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        user, sep, password = line.partition(":")
        if not sep or not user or not password:
            raise InventoryError(f"zenoh.secrets: {path} line {n} is not user:password")
        out[user] = UsrPwdAuth(user, password)
    return out


def fleet_secrets(inv: Inventory, scenario: Scenario, write: bool = True) -> FleetSecrets:
    """Every user's credentials (the folder's, new ones for users it lacks) and the router's
    configuration; with ``write`` the folder's files are (re)written, else nothing is touched."""
    z = inv.zenoh
    folder = z.secrets
    if z.router is None:
        raise InventoryError("zenoh.access_control: needs zenoh.router (the router enforces it)")
    robots = {r.id: scenario.formation_of(r.id).name for r in inv.robots}
    users = [*SERVICE_FILES, *robots]
    known = read_dictionary(folder / DICTIONARY)
    fresh = acl.new_credentials([u for u in users if u not in known])
    creds = {u: known.get(u) or fresh[u] for u in users}
    leaders = {f.name: f.leader for f in scenario.formations}
    successors = {f.name: s for f in scenario.formations
                  if (s := formation_successor(f)) is not None}
    cmd_vel = {r.id: rmw_zenoh.base_key(inv, r) for r in inv.robots}
    try:
        rights = acl.fleet_acl(robots, leaders, inv.prefix, successors=successors,
                               cmd_vel=cmd_vel)
        conf = acl.router_config([z.router], acl.add_rmw_zenoh(rights, rmw_zenoh.rmw_robots(inv)),
                                 (folder / DICTIONARY).resolve())
    except ValueError as exc:
        raise InventoryError(f"zenoh.access_control: {exc}") from None
    secrets = FleetSecrets(folder, creds, conf)
    if write:
        _write(secrets, [z.router], tls=z.tls is not None)
    return secrets


def _write(s: FleetSecrets, connect: Sequence[str], tls: bool) -> None:
    try:
        s.folder.mkdir(parents=True, exist_ok=True)
        s.folder.chmod(0o700)
        acl.write_dictionary(s.folder / DICTIONARY, s.creds)
        acl.write_router_config(s.folder / ROUTER_CONFIG, s.router_config)
        os.chmod(s.folder / ROUTER_CONFIG, 0o600)
        for user, name in SERVICE_FILES.items():
            acl.write_client_file(s.folder / name, s.creds[user], connect)
    except OSError as exc:
        raise InventoryError(f"zenoh.secrets: cannot write {s.folder}: {exc.strerror or exc}"
                             ) from None
    if tls:
        logger.info("%s: add the TLS link settings to router.json5 and the client files", s.folder)


def robot_auth(secrets: FleetSecrets | None, robot: str) -> UsrPwdAuth | None:
    return None if secrets is None else secrets.creds[robot]


def service_users(secrets: FleetSecrets) -> Mapping[str, Path]:
    """The service users' credential files (user -> path)."""
    return {u: secrets.folder / name for u, name in SERVICE_FILES.items()}
