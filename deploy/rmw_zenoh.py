"""Robots whose base runs ROS 2 on rmw_zenoh (inventory ``transport: rmw_zenoh``): no bridge.

The agent is an rmw_zenoh publisher itself (:class:`agent.base.RmwZenohBase`). The robot's own
Zenoh router, ``rmw_zenohd``, is linked to the fleet's router. Deploy writes, per such robot:

- ``rmw_zenohd.json5`` (``ZENOH_ROUTER_CONFIG_URI``): router mode, listening on the robot's
  loopback ``tcp/127.0.0.1:7447`` only, dialling the fleet's router (peer mode: the robot's own
  agent on 127.0.0.1), logged in as the robot's user when the fleet has credentials;
- ``rmw_zenoh_session.json5`` (``ZENOH_SESSION_CONFIG_URI``) for the robot's ROS nodes
  (``turtlebot3_node`` ...): peers of that ``rmw_zenohd`` on the loopback;
- with credentials, ``rmw_zenoh_users.txt``: a Zenoh node configured with a user and password
  also asks them of every session that joins it (zenoh 1.x refuses the link otherwise, checked
  here), so ``rmw_zenohd`` and the ROS nodes check each other against this one-line dictionary
  (the robot's own user; both files name it by its absolute path, :func:`users_path`) and log
  in with the same credentials.

The fleet router's access control applies to everything that crosses the link: the robot's user
may have its commands' data key delivered and declare the ROS graph's tokens of its own
namespace (:func:`wire.acl.add_rmw_zenoh`); nothing else of the robot's ROS traffic (scans,
odometry, tf) is let through, and it stays on the robot. ``rmw_zenohd`` itself has no access
control: only processes on the robot reach it.

``formation deploy --status`` also asks the fleet's router, over liveliness, whether each such
robot's base has its ``cmd_vel`` subscription (:mod:`deploy.rmw_status`).
"""

from __future__ import annotations

import logging
from typing import Any

from wire import rmw_zenoh as rmw
from wire.zconf import UsrPwdAuth

from .inventory import Inventory, InventoryError, RobotHost
from .zenoh_config import add_security, fleet_endpoints, to_json5

logger = logging.getLogger(__name__)

ROUTER_FILE = "rmw_zenohd.json5"  # ZENOH_ROUTER_CONFIG_URI of the robot's rmw_zenohd
SESSION_FILE = "rmw_zenoh_session.json5"  # ZENOH_SESSION_CONFIG_URI of its ROS nodes
USERS_FILE = "rmw_zenoh_users.txt"  # who may join the robot's rmw_zenohd (secured fleets)
ROS_ENDPOINT = "tcp/127.0.0.1:7447"  # rmw_zenohd listens on the robot's loopback only
SECRET_FILES = (ROUTER_FILE, SESSION_FILE, USERS_FILE)  # mode 0600 when the fleet has secrets


def base_key(inv: Inventory, robot: RobotHost) -> str:
    """The key of ``robot``'s base commands: its rmw_zenoh data key, or the bridge's key."""
    if robot.rmw is None:
        return robot.cmd_vel
    try:
        return rmw.data_key(robot.rmw, rmw.distro_of(inv.base))
    except ValueError as exc:
        raise InventoryError(f"robots ({robot.id}): {exc}") from None


def rmw_robots(inv: Inventory) -> dict[str, rmw.RmwSettings]:
    """robot id -> its rmw_zenoh settings, for the robots on rmw_zenoh."""
    return {r.id: r.rmw for r in inv.robots if r.rmw is not None}


def router_config_dict(inv: Inventory, robot: RobotHost,
                       auth: UsrPwdAuth | None = None) -> dict[str, Any]:
    """``rmw_zenohd``'s configuration on ``robot`` (see the module docstring)."""
    connect = fleet_endpoints(inv)
    conf: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": [ROS_ENDPOINT]},
        "connect": {"endpoints": connect},
        "scouting": {"multicast": {"enabled": False}},
        # as rmw_zenoh's default configurations: every sample is stamped
        "timestamping": {"enabled": {"router": True, "peer": True, "client": True}},
    }
    add_security(conf, inv, auth)
    usrpwd = _usrpwd(conf)
    if usrpwd is not None:  # a node with credentials asks them of whoever joins it too
        usrpwd["dictionary_file"] = users_path(robot)
    return conf


def users_path(robot: RobotHost) -> str:
    """The users file's absolute path on the robot (ROS nodes start in any folder): in
    ``install_dir``, whose ``~`` is taken as ``/home/USER`` (``/root`` for root); give an
    absolute ``install_dir`` where the robot user's home is elsewhere."""
    d = robot.install_dir.rstrip("/")
    if d == "~" or d.startswith("~/"):
        home = "/root" if robot.user == "root" else f"/home/{robot.user}"
        d = home + d[1:]
    return f"{d}/{USERS_FILE}"


def _usrpwd(conf: dict[str, Any]) -> dict[str, Any] | None:
    usrpwd: dict[str, Any] | None = conf.get("transport", {}).get("auth", {}).get("usrpwd")
    return usrpwd


def session_config_dict(router_conf: dict[str, Any]) -> dict[str, Any]:
    """The robot's ROS nodes' session: peers of its ``rmw_zenohd`` on the loopback, with the
    same credentials (if any)."""
    conf: dict[str, Any] = {
        "mode": "peer",
        "connect": {"endpoints": [ROS_ENDPOINT]},
        "listen": {"endpoints": ["tcp/127.0.0.1:0"]},
        "scouting": {"multicast": {"enabled": False}},
        "timestamping": {"enabled": {"router": True, "peer": True, "client": True}},
    }
    usrpwd = _usrpwd(router_conf)
    if usrpwd is not None:
        conf["transport"] = {"auth": {"usrpwd": dict(usrpwd)}}
    return conf


def robot_files(inv: Inventory, robot: RobotHost,
                auth: UsrPwdAuth | None = None) -> dict[str, bytes]:
    """``rmw_zenohd.json5``, ``rmw_zenoh_session.json5`` and, with credentials, the users file."""
    router = router_config_dict(inv, robot, auth)
    session = session_config_dict(router)
    files = {
        ROUTER_FILE: to_json5(router, f"rmw_zenohd on robot {robot.id}: "
                                      f"ZENOH_ROUTER_CONFIG_URI=THIS_FILE").encode(),
        SESSION_FILE: to_json5(session, f"ROS 2 nodes on robot {robot.id}: "
                                        f"ZENOH_SESSION_CONFIG_URI=THIS_FILE").encode(),
    }
    usrpwd = _usrpwd(router)
    if usrpwd is not None:
        files[USERS_FILE] = f"{usrpwd['user']}:{usrpwd['password']}\n".encode()
    return files


def base_files(inv: Inventory, robot: RobotHost, auth: UsrPwdAuth | None,
               bridge_file: str, bridge_json5: Any) -> dict[str, bytes]:
    """The base's Zenoh file for ``robot``: the bridge's, or ``rmw_zenohd``'s (none for the
    simulated world)."""
    if inv.base == "world":
        return {}
    if robot.rmw is not None:
        return robot_files(inv, robot, auth)
    return {bridge_file: bridge_json5(inv, robot, auth).encode()}
