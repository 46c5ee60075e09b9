"""The deploy inventory (YAML): which robot is which machine, and how the fleet talks Zenoh.

Example (every key is listed; the commented ones are optional)::

    prefix: warehouse                 # Zenoh key prefix (default warehouse)
    base: turtlebot3-humble           # world | turtlebot3-humble | turtlebot3-jazzy
    # topology: reduced               # reduced | all-to-all
    # known_hosts: known_hosts        # SSH host keys, beside this file by default
    # connect_timeout: 10             # SSH connect timeout [s]
    # env: {RUST_LOG: warn}           # environment of every agent
    zenoh:
      router: tcp/192.168.0.10:7447   # the router on the camera PC
      mode: client                    # client | peer
      # peer_port: 7447               # peer mode: every robot listens here, and dials the others
      # access_control: true          # one Zenoh user per robot, camera, manager, viewer, and
      #                               # the router's ACL (deploy.secure; default: on in client
      #                               # mode without zenoh.user)
      # secrets: secure               # where their credentials and router.json5 are kept
      # user: formation               # one user for the whole fleet instead (no ACL) ...
      # password_file: zenoh-password # ... the password's file (first line), beside this file
      # tls: {root_ca: ca.pem, certificate: robot.pem, private_key: robot-key.pem}
    defaults:                         # any per-robot key, for every robot
      user: ubuntu
      key: ~/.ssh/turtlebots          # private key on this machine
      # port: 22
      # install_dir: ~/formation-cbf  # on the robot
      # python: python3               # on the robot
    robots:
      - {id: a1, host: 192.168.0.21}
      - {id: a2, host: 192.168.0.22, user: pi}
      # more per-robot keys: cmd_vel_key (default {id}/cmd_vel), frame_id, env
      # - {id: a3, host: 192.168.0.23, transport: rmw_zenoh, ros_namespace: a3}
      # transport: bridge | rmw_zenoh (default bridge: zenoh-bridge-ros2dds on cmd_vel_key;
      #   rmw_zenoh: ROS 2 on rmw_zenoh_cpp, no bridge, with these keys, see docs/deploy.md:)
      # cmd_type: Twist | TwistStamped   (default: the base's, Twist on Humble)
      # ros_namespace: a3                (the robot's ROS namespace; default none)
      # ros_domain: 0                    (ROS_DOMAIN_ID, 0..232)
      # rmw_zenoh_release: jazzy         (humble | humble-0.1.1 | jazzy | jazzy-0.2.3 | kilted;
      #                                   default: the base's distribution, current binaries)

Relative local paths (``key``, ``password_file``, ``known_hosts``, TLS files) are taken from the
inventory's folder; ``~`` is this machine's home for local paths and the robot user's home for
``install_dir``. :func:`load_inventory` raises :class:`InventoryError` with one line naming the
culprit for an unknown key, a missing or ill-typed field, a duplicate robot id, two robots
sharing one ``host:port`` and ``install_dir``, and (with :func:`check_against_scenario`) a robot
the scenario does not have or a scenario robot the inventory lacks.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from agent.config import BASES, TOPOLOGIES
from wire import keys
from wire import rmw_zenoh as rmw
from wire.rmw_zenoh import RmwSettings

logger = logging.getLogger(__name__)

DEFAULT_PORT = 22
DEFAULT_INSTALL_DIR = "~/formation-cbf"
DEFAULT_PYTHON = "python3"
DEFAULT_ZENOH_PORT = 7447
DEFAULT_CONNECT_TIMEOUT = 10.0  # [s]
DEFAULT_KNOWN_HOSTS = "known_hosts"
ZENOH_MODES = ("client", "peer")

_TOP_KEYS = {"prefix", "base", "topology", "known_hosts", "connect_timeout", "env", "zenoh",
             "defaults", "robots"}
_ROBOT_KEYS = {"id", "host", "port", "user", "key", "install_dir", "python", "cmd_vel_key",
               "frame_id", "env", "transport", "cmd_type", "ros_namespace", "ros_domain",
               "rmw_zenoh_release"}
TRANSPORTS = ("bridge", "rmw_zenoh")
_ZENOH_KEYS = {"router", "mode", "peer_port", "user", "password_file", "tls", "access_control",
               "secrets"}
DEFAULT_SECRETS = "secure"
_TLS_KEYS = {"root_ca", "certificate", "private_key"}
_ENV_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws)/\S+:\d+$")
_HOST = re.compile(r"^[A-Za-z0-9_.:\[\]-]+$")


class InventoryError(ValueError):
    """An invalid inventory; the message is one line naming the culprit."""


@dataclass(frozen=True)
class TlsSettings:
    """Local paths of PEM files; their contents go into each robot's Zenoh config."""

    root_ca: Path
    certificate: Path | None = None  # with private_key: mutual TLS
    private_key: Path | None = None


@dataclass(frozen=True)
class FleetZenoh:
    """How every robot's Zenoh session is set up (multicast scouting is always off)."""

    router: str | None  # e.g. tcp/192.168.0.10:7447
    mode: str = "client"  # client | peer
    peer_port: int = DEFAULT_ZENOH_PORT
    user: str | None = None
    password_file: Path | None = None
    tls: TlsSettings | None = None
    access_control: bool = False  # per-process users and the router's ACL (deploy.secure)
    secrets: Path = Path(DEFAULT_SECRETS)  # their credentials, router.json5


@dataclass(frozen=True)
class RobotHost:
    """One robot: its id in the scenario and how to reach it over SSH."""

    id: str
    host: str
    user: str
    key: Path  # private key on this machine
    port: int = DEFAULT_PORT
    install_dir: str = DEFAULT_INSTALL_DIR  # on the robot; ~ is the robot user's home
    python: str = DEFAULT_PYTHON  # on the robot
    cmd_vel_key: str = ""  # "" -> "{id}/cmd_vel"
    frame_id: str = "base_link"
    env: tuple[tuple[str, str], ...] = ()
    rmw: RmwSettings | None = None  # transport rmw_zenoh; None: the bridge

    @property
    def address(self) -> str:
        return f"{self.user}@{self.host}:{self.port}"

    @property
    def cmd_vel(self) -> str:
        return self.cmd_vel_key or f"{self.id}/cmd_vel"


@dataclass(frozen=True)
class Inventory:
    path: Path
    robots: tuple[RobotHost, ...]
    zenoh: FleetZenoh
    prefix: str = keys.DEFAULT_PREFIX
    base: str = "world"
    topology: str = "reduced"
    known_hosts: Path = Path(DEFAULT_KNOWN_HOSTS)
    connect_timeout: float = DEFAULT_CONNECT_TIMEOUT  # [s]

    def robot(self, robot_id: str) -> RobotHost:
        for r in self.robots:
            if r.id == robot_id:
                return r
        raise KeyError(robot_id)


def load_inventory(path: str | Path) -> Inventory:
    """Read and validate an inventory file; :class:`InventoryError` with one line if invalid."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InventoryError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise InventoryError(f"{path}: not valid YAML{where}") from None
    try:
        return parse_inventory(data, path)
    except InventoryError as exc:
        raise InventoryError(f"{path}: {exc}") from None


def parse_inventory(data: Any, path: Path) -> Inventory:
    """Validate the parsed YAML of an inventory at ``path`` (for relative local paths)."""
    folder = path.parent.resolve()
    top = _mapping(data, "inventory")
    _no_unknown(top, _TOP_KEYS, "")
    if "robots" not in top:
        raise InventoryError("missing key 'robots'")
    prefix = _str(top.get("prefix", keys.DEFAULT_PREFIX), "prefix")
    try:
        keys.validate_prefix(prefix)
    except ValueError as exc:
        raise InventoryError(str(exc)) from None
    base = _choice(top.get("base", "world"), BASES, "base")
    topology = _choice(top.get("topology", "reduced"), TOPOLOGIES, "topology")
    known_hosts = _local_path(top.get("known_hosts", DEFAULT_KNOWN_HOSTS), "known_hosts", folder)
    connect_timeout = _positive(top.get("connect_timeout", DEFAULT_CONNECT_TIMEOUT),
                                "connect_timeout")
    fleet_env = _env(top.get("env", {}), "env")
    zenoh = _zenoh(top.get("zenoh"), folder)
    defaults = _mapping(top.get("defaults", {}), "defaults")
    _no_unknown(defaults, _ROBOT_KEYS - {"id", "host"}, "defaults.")

    items = top["robots"]
    if not isinstance(items, list) or not items:
        raise InventoryError("robots: must be a non-empty list")
    robots: list[RobotHost] = []
    seen_ids: set[str] = set()
    seen_targets: dict[tuple[str, int, str], str] = {}
    for i, item in enumerate(items):
        entry = _mapping(item, f"robots[{i}]")
        label = f"robots[{i}]" + (f" ({entry['id']})" if isinstance(entry.get("id"), str) else "")
        _no_unknown(entry, _ROBOT_KEYS, f"{label}.")
        merged = {**defaults, **entry}
        robot = _robot(merged, label, folder, fleet_env)
        if robot.id in seen_ids:
            raise InventoryError(f"{label}: duplicate robot id {robot.id!r}")
        seen_ids.add(robot.id)
        target = (robot.host.lower(), robot.port, robot.install_dir.rstrip("/") or "/")
        if target in seen_targets:
            raise InventoryError(
                f"{label}: {robot.host}:{robot.port} with install_dir {robot.install_dir!r} is "
                f"already robot {seen_targets[target]!r}'s"
            )
        seen_targets[target] = robot.id
        robots.append(robot)
    if zenoh.mode == "peer":
        hosts: dict[str, str] = {}
        for r in robots:
            if r.host in hosts:
                raise InventoryError(
                    f"zenoh.mode: peer needs one robot per host (listening on port "
                    f"{zenoh.peer_port}), but {hosts[r.host]!r} and {r.id!r} share {r.host}"
                )
            hosts[r.host] = r.id
    _check_transports(base, robots)
    return Inventory(path=path, robots=tuple(robots), zenoh=zenoh, prefix=prefix, base=base,
                     topology=topology, known_hosts=known_hosts, connect_timeout=connect_timeout)


def check_against_scenario(inventory: Inventory, robot_ids: tuple[str, ...] | list[str]) -> None:
    """Every inventory robot is in the scenario and every scenario robot has a machine."""
    wanted = list(robot_ids)
    have = [r.id for r in inventory.robots]
    for rid in have:
        if rid not in wanted:
            raise InventoryError(f"{inventory.path}: robot {rid!r} is not in the scenario "
                                 f"(its robots: {', '.join(wanted)})")
    for rid in wanted:
        if rid not in have:
            raise InventoryError(f"{inventory.path}: scenario robot {rid!r} is missing from "
                                 f"the inventory")


def check_keys(inventory: Inventory, robots: Sequence[str] | None = None) -> None:
    """Every robot's (of ``robots``, default all) SSH key is a file on this machine; else
    :class:`InventoryError` naming the first that is not."""
    for r in inventory.robots:
        if (robots is None or r.id in robots) and not r.key.is_file():
            what = "is not a file" if r.key.exists() else "does not exist"
            raise InventoryError(f"{inventory.path}: robot {r.id!r}: SSH key {r.key} {what}")


def _robot(d: dict[str, Any], label: str, folder: Path,
           fleet_env: tuple[tuple[str, str], ...]) -> RobotHost:
    for name in ("id", "host", "user", "key"):
        if name not in d:
            raise InventoryError(f"{label}: missing key {name!r}")
    rid = _str(d["id"], f"{label}.id")
    problem = keys.name_problem(rid)  # the scenario's rule for robot names
    if problem is not None:
        raise InventoryError(f"{label}.id {rid[:64]!r} {problem}")
    host = _str(d["host"], f"{label}.host")
    if not _HOST.match(host):
        raise InventoryError(f"{label}.host: {host!r} is not a host name or address")
    user = _str(d["user"], f"{label}.user")
    if not re.match(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$", user):
        raise InventoryError(f"{label}.user: {user!r} is not a user name")
    port = d.get("port", DEFAULT_PORT)
    if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
        raise InventoryError(f"{label}.port: must be an integer in 1..65535, got {port!r}")
    install_dir = _install_dir(d.get("install_dir", DEFAULT_INSTALL_DIR), f"{label}.install_dir")
    python = _str(d.get("python", DEFAULT_PYTHON), f"{label}.python")
    if not re.match(r"^[A-Za-z0-9_./+-]+$", python):
        raise InventoryError(f"{label}.python: {python!r} is not a command name or path")
    cmd_vel_key = _cmd_vel_key(d.get("cmd_vel_key", ""), f"{label}.cmd_vel_key")
    frame_id = _str(d.get("frame_id", "base_link"), f"{label}.frame_id")
    env = dict(fleet_env)
    env.update(dict(_env(d.get("env", {}), f"{label}.env")))
    return RobotHost(
        id=rid, host=host, user=user, key=_local_path(d["key"], f"{label}.key", folder),
        port=port, install_dir=install_dir, python=python, cmd_vel_key=cmd_vel_key,
        frame_id=frame_id, env=tuple(sorted(env.items())), rmw=_rmw_settings(d, label),
    )


def _install_dir(value: Any, name: str) -> str:
    install_dir = _str(value, name)
    if not (install_dir.startswith("/") or install_dir == "~" or install_dir.startswith("~/")):
        raise InventoryError(f"{name}: must be absolute or start with ~/, got {install_dir!r}")
    if any(c in install_dir for c in "\n\0'\"$`\\"):
        raise InventoryError(f"{name}: must not contain quotes, $, ` or \\")
    return install_dir


def _cmd_vel_key(value: Any, name: str) -> str:
    """A plain Zenoh key, or "" (the default)."""
    if value == "":
        return ""
    key = _str(value, name)
    if any(not c or keys.id_problem(c) for c in key.split("/")):
        raise InventoryError(f"{name}: {key!r} is not a plain Zenoh key")
    return key


def _rmw_settings(d: dict[str, Any], label: str) -> RmwSettings | None:
    """A robot's rmw_zenoh keys: None for the bridge (which takes none of them)."""
    transport = _choice(d.get("transport", "bridge"), TRANSPORTS, f"{label}.transport")
    given = [k for k in ("cmd_type", "ros_namespace", "ros_domain", "rmw_zenoh_release") if k in d]
    if transport == "bridge":
        if given:
            raise InventoryError(f"{label}.{given[0]}: only for transport rmw_zenoh")
        return None
    cmd_type = _choice(d.get("cmd_type", ""), ("", *rmw.CMD_TYPES), f"{label}.cmd_type") \
        if "cmd_type" in d else ""
    release = _choice(d["rmw_zenoh_release"], tuple(rmw.RELEASES), f"{label}.rmw_zenoh_release") \
        if "rmw_zenoh_release" in d else ""
    namespace = _str(d["ros_namespace"], f"{label}.ros_namespace") if "ros_namespace" in d else ""
    domain = d.get("ros_domain", 0)
    for name, check in (("ros_namespace", lambda: rmw.namespace_of(namespace)),
                        ("ros_domain", lambda: rmw.check_domain(domain))):
        try:
            check()
        except ValueError as exc:
            raise InventoryError(f"{label}.{name}: {exc}") from None
    return RmwSettings(release=release, cmd_type=cmd_type, namespace=namespace, domain=domain)


def _check_transports(base: str, robots: Sequence[RobotHost]) -> None:
    """rmw_zenoh needs a ROS base (the release defaults to the base's distribution)."""
    for r in robots:
        if r.rmw is not None and base == "world":
            raise InventoryError(f"robots ({r.id}).transport: rmw_zenoh needs base "
                                 f"turtlebot3-humble or turtlebot3-jazzy, not world")


def _zenoh(value: Any, folder: Path) -> FleetZenoh:
    if value is None:
        raise InventoryError("missing key 'zenoh'")
    z = _mapping(value, "zenoh")
    _no_unknown(z, _ZENOH_KEYS, "zenoh.")
    mode = _choice(z.get("mode", "client"), ZENOH_MODES, "zenoh.mode")
    router = z.get("router")
    if router is not None:
        router = _str(router, "zenoh.router")
        if not _ENDPOINT.match(router):
            raise InventoryError(f"zenoh.router: {router!r} is not an endpoint like "
                                 f"tcp/192.168.0.10:7447")
    elif mode == "client":
        raise InventoryError("zenoh.router: required in client mode")
    peer_port = z.get("peer_port", DEFAULT_ZENOH_PORT)
    if isinstance(peer_port, bool) or not isinstance(peer_port, int) or not 0 < peer_port < 65536:
        raise InventoryError(f"zenoh.peer_port: must be an integer in 1..65535, got {peer_port!r}")
    user = z.get("user")
    password_file = z.get("password_file")
    if (user is None) != (password_file is None):
        raise InventoryError("zenoh.user: user and password_file go together")
    if user is not None:
        user = _str(user, "zenoh.user")
        password_file = _local_path(password_file, "zenoh.password_file", folder)
    tls = None if z.get("tls") is None else _tls(z["tls"], folder, router)
    access_control = _access_control(z.get("access_control", mode == "client" and user is None),
                                     mode, user)
    secrets = _local_path(z.get("secrets", DEFAULT_SECRETS), "zenoh.secrets", folder)
    return FleetZenoh(router=router, mode=mode, peer_port=peer_port, user=user,
                      password_file=password_file, tls=tls, access_control=access_control,
                      secrets=secrets)


def _access_control(value: Any, mode: str, user: str | None) -> bool:
    if not isinstance(value, bool):
        raise InventoryError(f"zenoh.access_control: must be true or false, got {value!r}")
    if value and user is not None:
        raise InventoryError("zenoh.access_control: one user per robot; drop zenoh.user and "
                             "zenoh.password_file (or set access_control: false)")
    if value and mode != "client":
        raise InventoryError("zenoh.access_control: needs mode client (peers bypass the "
                             "router that enforces it)")
    return value


def _tls(value: Any, folder: Path, router: str | None) -> TlsSettings:
    t = _mapping(value, "zenoh.tls")
    _no_unknown(t, _TLS_KEYS, "zenoh.tls.")
    if "root_ca" not in t:
        raise InventoryError("zenoh.tls: missing key 'root_ca'")
    if ("certificate" in t) != ("private_key" in t):
        raise InventoryError("zenoh.tls: certificate and private_key go together")
    tls = TlsSettings(
        root_ca=_local_path(t["root_ca"], "zenoh.tls.root_ca", folder),
        certificate=(_local_path(t["certificate"], "zenoh.tls.certificate", folder)
                     if "certificate" in t else None),
        private_key=(_local_path(t["private_key"], "zenoh.tls.private_key", folder)
                     if "private_key" in t else None),
    )
    if router is not None and not router.startswith("tls/"):
        raise InventoryError(f"zenoh.router: {router!r} must be a tls/ endpoint with zenoh.tls")
    return tls


def _mapping(value: Any, name: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise InventoryError(f"{name}: must be a mapping")
    for k in value:
        if not isinstance(k, str):
            raise InventoryError(f"{name}: key {k!r} must be a string")
    return value


def _no_unknown(d: dict[str, Any], known: set[str], where: str) -> None:
    unknown = sorted(set(d) - known)
    if unknown:
        raise InventoryError(f"unknown key '{where}{unknown[0]}'")


def _str(value: Any, name: str) -> str:
    if not isinstance(value, str) or not value or "\n" in value:
        raise InventoryError(f"{name}: must be a non-empty one-line string, got {value!r}")
    return value


def _choice(value: Any, choices: tuple[str, ...], name: str) -> str:
    if value not in choices:
        raise InventoryError(f"{name}: {value!r} is not one of {', '.join(choices)}")
    return value


def _positive(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not (
            math.isfinite(value) and value > 0):
        raise InventoryError(f"{name}: must be a positive number, got {value!r}")
    return float(value)


def _local_path(value: Any, name: str, folder: Path) -> Path:
    p = Path(_str(value, name)).expanduser()
    return p if p.is_absolute() else folder / p


def _env(value: Any, name: str) -> tuple[tuple[str, str], ...]:
    env = _mapping(value, name)
    out = []
    for k, v in env.items():
        if not _ENV_NAME.match(k):
            raise InventoryError(f"{name}: {k!r} is not an environment variable name")
        if isinstance(v, bool) or not isinstance(v, str | int | float) or "\n" in str(v):
            raise InventoryError(f"{name}.{k}: must be a one-line string or number")
        out.append((k, str(v)))
    return tuple(out)
