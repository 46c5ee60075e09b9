"""Access control of one run (``formation run`` without ``--insecure``): fresh credentials for
every process and the router's access control list (:mod:`wire.acl`), written into
``DIR/secure`` before the router starts."""

from __future__ import annotations

import shutil
import tempfile
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

from scenario import Scenario
from scenario.succession import formation_successor
from wire import acl, keys
from wire.rmw_zenoh import RmwSettings
from wire.zconf import UsrPwdAuth

from .bases import robot_settings, run_bases
from .zones import ZoneSecurity

MANAGER_FILE = "manager.json5"  # in OUT/secure: the fleet manager's credentials (goals)
VIEWER_FILE = "viewer.json5"  # in OUT/secure: a read-only viewer's credentials


@dataclass(frozen=True)
class RunCredentials:
    """What the run's processes log in with, and the router's configuration."""

    router_config: Path
    files: dict[str, Path]  # robot -> its credentials file
    world: UsrPwdAuth
    folder: Path
    zone: ZoneSecurity | None = None  # with pose zones: what the zone routers need

    def summary(self) -> dict:
        """``secure`` of summary.json."""
        return {"auth": "usrpwd", "acl": str(self.router_config),
                "manager": str(self.folder / MANAGER_FILE), "viewer": str(self.folder / VIEWER_FILE)}


def zone_link(own: ExitStack) -> str:
    """A Unix-socket endpoint in a fresh private folder (mode 0700, removed when ``own``
    closes) for the zone routers' link to the run's router (:data:`wire.acl.ZONE_LINK`)."""
    sockets = Path(tempfile.mkdtemp(prefix="formation-zones-"))
    own.callback(shutil.rmtree, sockets, ignore_errors=True)
    return f"{acl.ZONE_LINK}/{sockets / 'router.sock'}"


def _fresh_folder(folder: Path) -> None:
    """``folder`` made private (0700) and emptied: a previous run's credentials are void."""
    folder.mkdir(parents=True, exist_ok=True)
    folder.chmod(0o700)
    for old in folder.iterdir():
        if old.is_file():
            old.unlink()


def secure_setup(scenario: Scenario, folder: Path, endpoint: str,
                 zone_link: str | None = None, rmw_base: RmwSettings | None = None
                 ) -> RunCredentials:
    """Fresh credentials for the world (as the camera user), every robot, the fleet manager and
    a viewer; the router's dictionary and its configuration with the fleet's access control
    list (:mod:`wire.acl`), all in ``folder`` (mode 0700, files 0600). ``manager.json5`` and
    ``viewer.json5`` are Zenoh configuration fragments (the router's endpoint, the user and
    password) that client commands take with ``--auth FILE`` (``viewer.credentials``, the
    viewer's ``user:password`` line, is kept for older scripts). ``zone_link``: pose zones; the
    router also listens there (a Unix socket in a private folder) for the zone routers, which log
    in as :data:`wire.acl.ZONE_USER`. ``rmw_base``: ``--base rmw_zenoh``, each robot's command
    goes to its base's rmw_zenoh key, which the world reads (:mod:`simulator.bases`). A scenario
    with a fleet (lifelong operation) adds the fleet's robots, each a formation of one that it
    leads, and the rows of the order keys."""
    _fresh_folder(folder)
    robots = {rid: scenario.formation_of(rid).name for rid in scenario.robot_ids}
    leaders = {f.name: f.leader for f in scenario.formations}
    life = scenario.lifelong
    for rid in () if life is None else life.fleet.robot_ids:  # each a formation of one
        robots[rid] = leaders[rid] = rid
    successors = {f.name: s for f in scenario.formations
                  if (s := formation_successor(f)) is not None}
    services = [acl.CAMERA_USER, acl.MANAGER_USER, acl.VIEWER_USER]
    creds = acl.new_credentials([*services, *([acl.ZONE_USER] if zone_link else []), *robots])
    dictionary = folder / "users.txt"
    acl.write_dictionary(dictionary, creds)
    acl.write_credentials(folder / "viewer.credentials", creds[acl.VIEWER_USER])
    files = {}
    for rid in robots:
        files[rid] = folder / f"{rid}.credentials"
        acl.write_credentials(files[rid], creds[rid])
    for name, user in ((MANAGER_FILE, acl.MANAGER_USER), (VIEWER_FILE, acl.VIEWER_USER)):
        acl.write_client_file(folder / name, creds[user], [endpoint])
    router_conf = folder / "router.json5"
    bases = {} if rmw_base is None else run_bases(scenario.robot_ids, rmw_base)
    rules = acl.fleet_acl(robots, leaders, keys.DEFAULT_PREFIX, successors=successors,
                          zone_user=acl.ZONE_USER if zone_link else None,
                          cmd_vel={rid: b.key for rid, b in bases.items()},
                          orders=life is not None)
    if rmw_base is not None:  # --base rmw_zenoh: the agents' ROS graph, the world reads the bases
        acl.add_rmw_zenoh(rules, {rid: robot_settings(rid, rmw_base) for rid in robots},
                          world_user=acl.CAMERA_USER)
    acl.write_router_config(router_conf, acl.router_config(
        [endpoint, *([zone_link] if zone_link else [])], rules, dictionary.resolve()))
    zone = None if zone_link is None else ZoneSecurity(rules, dictionary.resolve(), zone_link,
                                                       creds[acl.ZONE_USER])
    return RunCredentials(router_conf, files, creds[acl.CAMERA_USER], folder, zone)
