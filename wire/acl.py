"""Access control for the fleet: a Zenoh 1.x ``access_control`` section and the router config.

Only the fleet's own processes may command a robot. The router authenticates every session by
user/password (``transport/auth/usrpwd``, the router holding a ``user:password`` dictionary file)
and filters messages with the ACL of :func:`fleet_acl`, whose subjects are matched by user name:

* robot ``r`` (user ``r``) may publish (``put``, ingress to the router) only on
  ``{prefix}/robot/r/state``, ``{prefix}/robot/r/cmd`` and ``{prefix}/robot/r/diag`` and, if it
  leads formation ``f``, on ``{prefix}/formation/f/ellipse`` and ``{prefix}/formation/f/others``;
* the viewer (user :data:`VIEWER_USER`: ``formation view``, ``formation record``) may only
  subscribe and be sent what is published: it publishes nothing;
* the camera service or simulated world (user :data:`CAMERA_USER`) may publish only the poses
  ``{prefix}/robot/*/pose``, ``{prefix}/obstacles`` and the frames ``{prefix}/camera/frame``;
* every fleet user may declare subscribers under ``{prefix}/**`` and be sent (``put``, egress)
  what is published there;
* ``default_permission`` is ``deny``: anything else (another robot's keys, queries, queryables,
  liveliness, keys outside the prefix) is dropped by the router.

Schema (zenoh 1.x, ``DEFAULT_CONFIG.json5`` of eclipse-zenoh/zenoh)::

    access_control: {
      enabled: true, default_permission: "deny",
      rules: [{id, messages: ["put", "declare_subscriber", ...], flows: ["ingress", "egress"],
               permission: "allow" | "deny", key_exprs: [...]}],
      subjects: [{id, usernames: [...]}],      // also interfaces, cert_common_names, zids...
      policies: [{id, rules: [rule ids], subjects: [subject ids]}],
    }

The ACL is enforced by whichever Zenoh node holds it; in this project that is the router (a
Python session in router mode, ``python -m wire.router --config FILE``), and the clients must
reach each other only through it (client mode, multicast scouting off). What a test verified
with zenoh-python 1.10 is in docs/faults.md ("Access control").
"""

from __future__ import annotations

import json
import logging
import os
import secrets
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from wire import keys
from wire.diag import diag_key
from wire.zconf import UsrPwdAuth

logger = logging.getLogger(__name__)

CAMERA_USER = "camera"  # the camera service, or the simulated world that stands in for it
FLEET_READ_RULE = "fleet-read"
CAMERA_RULE = "camera-publish"
VIEWER_USER = "viewer"  # read-only: the live page and recorders of a fleet


def _check_user(name: str, what: str) -> str:
    problem = keys.user_problem(name)  # robots' names follow keys.name_problem, stricter
    if problem is not None:
        raise ValueError(f"{what} {name!r} {problem}")
    return name


def fleet_acl(
    robots: Mapping[str, str],
    leaders: Mapping[str, str],
    prefix: str = keys.DEFAULT_PREFIX,
    camera_user: str = CAMERA_USER,
) -> dict[str, Any]:
    """The ``access_control`` section for a fleet (see the module docstring).

    ``robots`` maps robot id -> formation id (the robot's user name is its id); ``leaders`` maps
    formation id -> leader robot id. ValueError names an invalid id or a leader not in
    ``robots``.
    """
    keys.validate_prefix(prefix)
    _check_user(camera_user, "camera_user")
    if not robots:
        raise ValueError("robots: must not be empty")
    for rid, fid in robots.items():
        _check_user(rid, "robot id")
        keys.validate_id(fid, "formation id")
        if rid in (camera_user, VIEWER_USER):
            raise ValueError(f"robot id {rid!r} is the {rid} user")
    for fid, leader in leaders.items():
        if robots.get(leader) != fid:
            raise ValueError(f"leaders: {leader!r} is not a robot of formation {fid!r}")
    rules: list[dict[str, Any]] = [
        {"id": FLEET_READ_RULE, "messages": ["declare_subscriber"],
         "flows": ["ingress", "egress"], "permission": "allow", "key_exprs": [f"{prefix}/**"]},
        {"id": "fleet-deliver", "messages": ["put"], "flows": ["egress"], "permission": "allow",
         "key_exprs": [f"{prefix}/**"]},
        {"id": CAMERA_RULE, "messages": ["put"], "flows": ["ingress"], "permission": "allow",
         "key_exprs": [f"{prefix}/robot/*/pose", keys.obstacles_key(prefix),
                       f"{prefix}/camera/frame"]},
    ]
    subjects: list[dict[str, Any]] = [{"id": camera_user, "usernames": [camera_user]},
                                      {"id": VIEWER_USER, "usernames": [VIEWER_USER]}]
    policies: list[dict[str, Any]] = [
        {"id": f"{camera_user}-policy", "rules": [FLEET_READ_RULE, "fleet-deliver", CAMERA_RULE],
         "subjects": [camera_user]},
        {"id": f"{VIEWER_USER}-policy", "rules": [FLEET_READ_RULE, "fleet-deliver"],
         "subjects": [VIEWER_USER]},
    ]
    led = {leader: fid for fid, leader in leaders.items()}
    for rid in robots:
        own = [keys.state_key(prefix, rid), keys.cmd_key(prefix, rid), diag_key(prefix, rid)]
        if rid in led:
            own += [keys.ellipse_key(prefix, led[rid]), keys.others_key(prefix, led[rid])]
        rules.append({"id": f"{rid}-publish", "messages": ["put"], "flows": ["ingress"],
                      "permission": "allow", "key_exprs": own})
        subjects.append({"id": rid, "usernames": [rid]})
        policies.append({"id": f"{rid}-policy",
                         "rules": [FLEET_READ_RULE, "fleet-deliver", f"{rid}-publish"],
                         "subjects": [rid]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def router_config(
    listen: Sequence[str],
    acl: Mapping[str, Any],
    dictionary_file: str | os.PathLike[str],
) -> dict[str, Any]:
    """A router's whole configuration: listen endpoints, no multicast scouting, user/password
    authentication against ``dictionary_file``, and ``acl`` as ``access_control``."""
    if isinstance(listen, str) or not listen:
        raise ValueError("listen: must be a non-empty sequence of endpoints")
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"dictionary_file": str(dictionary_file)}}},
        "access_control": dict(acl),
    }


def new_credentials(users: Sequence[str]) -> dict[str, UsrPwdAuth]:
    """A fresh random password (128 bits) for each user."""
    return {u: UsrPwdAuth(_check_user(u, "user"), secrets.token_urlsafe(16)) for u in users}


def _write_private(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.chmod(path, 0o600)


def write_dictionary(path: str | os.PathLike[str], creds: Mapping[str, UsrPwdAuth]) -> None:
    """The router's ``user:password`` dictionary (mode 0600)."""
    _write_private(Path(path), "".join(f"{a.user}:{a.password}\n" for a in creds.values()))


def write_credentials(path: str | os.PathLike[str], auth: UsrPwdAuth) -> None:
    """One process's credentials, ``user:password`` on one line (mode 0600)."""
    _write_private(Path(path), f"{auth.user}:{auth.password}\n")


def read_credentials(path: str | os.PathLike[str]) -> UsrPwdAuth:
    """The ``user:password`` of a file written by :func:`write_credentials`."""
    try:
        text = Path(path).read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise ValueError(f"credentials {path}: cannot read: {exc}") from None
    user, sep, password = text.partition(":")
    if not sep or not user or not password or "\n" in text:
        raise ValueError(f"credentials {path}: expected one line user:password")
    return UsrPwdAuth(user, password)


def write_router_config(path: str | os.PathLike[str], conf: Mapping[str, Any]) -> None:
    """Write ``conf`` as JSON (valid JSON5) after zenoh itself accepted it."""
    import zenoh

    text = json.dumps(conf, indent=2) + "\n"
    try:
        zenoh.Config.from_json5(text)
    except Exception as exc:  # zenoh.ZError: an unknown key or a bad value
        raise ValueError(f"router config rejected by zenoh: {exc}") from None
    Path(path).write_text(text, encoding="utf-8")


def write_fleet_files(scenario_path: str | os.PathLike[str], folder: str | os.PathLike[str],
                      listen: Sequence[str], prefix: str = keys.DEFAULT_PREFIX) -> list[Path]:
    """The router's ``router.json5`` and ``users.txt`` and one ``ROBOT.credentials`` per robot
    (plus ``camera.credentials``) for a scenario's fleet, with fresh passwords, in ``folder``."""
    from scenario import load_scenario

    sc = load_scenario(Path(scenario_path))
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    out.chmod(0o700)
    robots = {rid: sc.formation_of(rid).name for rid in sc.robot_ids}
    creds = new_credentials([CAMERA_USER, VIEWER_USER, *robots])
    write_dictionary(out / "users.txt", creds)
    written = [out / "users.txt"]
    for user, auth in creds.items():
        write_credentials(out / f"{user}.credentials", auth)
        written.append(out / f"{user}.credentials")
    conf = router_config(listen, fleet_acl(robots, {f.name: f.leader for f in sc.formations},
                                           prefix), (out / "users.txt").resolve())
    write_router_config(out / "router.json5", conf)
    return [out / "router.json5", *written]


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m wire.acl SCENARIO --out DIR [--listen ENDPOINT]``: a fleet's router files."""
    import argparse
    import sys

    parser = argparse.ArgumentParser(prog="python -m wire.acl", description=main.__doc__)
    parser.add_argument("scenario")
    parser.add_argument("--out", required=True, help="folder for the files (mode 0700)")
    parser.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                        help="router endpoint (repeatable; default tcp/0.0.0.0:7447)")
    parser.add_argument("--key-prefix", default=keys.DEFAULT_PREFIX)
    ns = parser.parse_args(argv)
    try:
        files = write_fleet_files(ns.scenario, ns.out, ns.listen or ["tcp/0.0.0.0:7447"],
                                  ns.key_prefix)
    except ValueError as exc:  # ScenarioError is a ValueError too
        print(f"wire.acl: {exc}", file=sys.stderr)
        return 2
    print("wrote " + ", ".join(str(f) for f in files))
    print(f"run the router with: python -m wire.router --listen ... --config {files[0]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
