"""A scenario's fleet files for a router of its own: ``python -m deploy.router_files SCENARIO --out DIR``.

The router's ``router.json5`` (users and the access control list of :mod:`wire.acl`), ``users.txt``
and one ``USER.credentials`` per robot and service, with fresh passwords. Above the scenario layer,
so that :mod:`wire.acl` reads no scenario.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from scenario import load_scenario
from scenario.succession import formation_successor
from wire import keys
from wire.acl import (
    CAMERA_USER,
    MANAGER_USER,
    VIEWER_USER,
    fleet_acl,
    new_credentials,
    router_config,
    write_credentials,
    write_dictionary,
    write_router_config,
)


def write_fleet_files(scenario_path: str | os.PathLike[str], folder: str | os.PathLike[str],
                      listen: Sequence[str], prefix: str = keys.DEFAULT_PREFIX,
                      cmd_vel_key: str = "{robot}/cmd_vel") -> list[Path]:
    """The router's ``router.json5`` and ``users.txt`` and one ``ROBOT.credentials`` per robot
    (plus ``camera``, ``manager`` and ``viewer``) for a scenario's fleet, with fresh passwords,
    in ``folder``. ``cmd_vel_key`` is each robot's base command key (``{robot}`` replaced)."""
    sc = load_scenario(Path(scenario_path))
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    out.chmod(0o700)
    robots = {rid: sc.formation_of(rid).name for rid in sc.robot_ids}
    successors = {f.name: s for f in sc.formations if (s := formation_successor(f)) is not None}
    creds = new_credentials([CAMERA_USER, MANAGER_USER, VIEWER_USER, *robots])
    write_dictionary(out / "users.txt", creds)
    written = [out / "users.txt"]
    for user, auth in creds.items():
        write_credentials(out / f"{user}.credentials", auth)
        written.append(out / f"{user}.credentials")
    cmd_vel = {rid: cmd_vel_key.format(robot=rid) for rid in robots}
    conf = router_config(listen, fleet_acl(robots, {f.name: f.leader for f in sc.formations},
                                           prefix, successors=successors, cmd_vel=cmd_vel),
                         (out / "users.txt").resolve())
    write_router_config(out / "router.json5", conf)
    return [out / "router.json5", *written]


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m deploy.router_files SCENARIO --out DIR [--listen ENDPOINT]``: a fleet's router files."""
    parser = argparse.ArgumentParser(prog="python -m deploy.router_files", description=main.__doc__)
    parser.add_argument("scenario")
    parser.add_argument("--out", required=True, help="folder for the files (mode 0700)")
    parser.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                        help="router endpoint (repeatable; default tcp/0.0.0.0:7447)")
    parser.add_argument("--key-prefix", default=keys.DEFAULT_PREFIX)
    parser.add_argument("--cmd-vel-key", default="{robot}/cmd_vel", metavar="TEMPLATE",
                        help="each robot's base command key, {robot} replaced by its id "
                             "(default {robot}/cmd_vel: zenoh-bridge-ros2dds with "
                             "namespace {robot}, as formation deploy sets it up)")
    ns = parser.parse_args(argv)
    if "{robot}" not in ns.cmd_vel_key:
        print("deploy.router_files: --cmd-vel-key must contain {robot} (one base key per robot)",
              file=sys.stderr)
        return 2
    try:
        files = write_fleet_files(ns.scenario, ns.out, ns.listen or ["tcp/0.0.0.0:7447"],
                                  ns.key_prefix, ns.cmd_vel_key)
    except ValueError as exc:  # ScenarioError is a ValueError too
        print(f"deploy.router_files: {exc}", file=sys.stderr)
        return 2
    print("wrote " + ", ".join(str(f) for f in files))
    print(f"run the router with: python -m runtime.router --listen ... --config {files[0]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
