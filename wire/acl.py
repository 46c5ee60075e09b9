"""Access control for the fleet: a Zenoh 1.x ``access_control`` section and the router config.

Only the fleet's own processes may command a robot. The router authenticates every session by
user/password (``transport/auth/usrpwd``, the router holding a ``user:password`` dictionary file)
and filters messages with the ACL of :func:`fleet_acl`, whose subjects are matched by user name:

* robot ``r`` (user ``r``) may publish (``put``, ingress to the router) only on
  ``{prefix}/robot/r/state``, ``.../cmd``, ``.../diag`` and its base's command key (``r/cmd_vel``
  unless told otherwise: ``zenoh-bridge-ros2dds`` with namespace ``r``); the bridge, logged in
  as ``r``, may subscribe to that key and be sent what is put there, and put the base's wheel
  odometry (``r/odom``: :func:`bridge_odom_key`), which the agent may hear. If ``r`` leads formation
  ``f``, or is its successor (:mod:`scenario.succession`, the member that takes over when the
  leader dies), also on ``{prefix}/formation/f/ellipse``, ``beacon``, ``others``, ``status``
  and ``plan``, hold the liveliness token ``{prefix}/formation/f/leader`` and answer
  ``status`` queries;
* the camera service or simulated world (user :data:`CAMERA_USER`) may publish only the poses
  ``{prefix}/robot/*/pose``, the simulated wheel odometry ``{prefix}/robot/*/odom``,
  ``{prefix}/obstacles`` and the frames ``{prefix}/camera/frame``,
  and answer queries on its counters ``{prefix}/camera/stats``;
* the fleet manager (:data:`MANAGER_USER`) may publish goals ``{prefix}/formation/*/goal`` and
  query ``status`` and the camera's counters; a viewer (:data:`VIEWER_USER`) may only read and
  query those two;
* with ``orders`` (a scenario with a fleet: lifelong operation, :mod:`wire.orders`), the fleet
  manager also puts orders ``{prefix}/order/*``, answers queries on them and on
  ``{prefix}/order/*/status`` (its order book) and asks them; robot ``r`` puts only its own
  bids ``{prefix}/order/*/bid/r`` and any order's ``{prefix}/order/*/status`` (the router
  cannot tell whether ``r`` leads that order's team: a receiver checks the sender against the
  roster it saw committed), and asks the order book; the simulated world (the camera user)
  puts the loads ``{prefix}/world/loads``, which robots and viewers read;
* every fleet user may declare subscribers and liveliness subscribers under ``{prefix}/**`` and be
  sent (``put``, ``delete``, liveliness tokens, replies; egress) what is published there;
* ``default_permission`` is ``deny``: anything else (another robot's keys, a member's ellipse,
  queryables, keys outside the prefix) is dropped by the router.

Schema (zenoh 1.x, ``DEFAULT_CONFIG.json5`` of eclipse-zenoh/zenoh)::

    access_control: {
      enabled: true, default_permission: "deny",
      rules: [{id, messages: ["put", "declare_subscriber", ...], flows: ["ingress", "egress"],
               permission: "allow" | "deny", key_exprs: [...]}],
      subjects: [{id, usernames: [...]}],      // also interfaces, cert_common_names, zids...
      policies: [{id, rules: [rule ids], subjects: [subject ids]}],
    }

The ACL is enforced by whichever Zenoh node holds it; in this project that is the router (a
Python session in router mode, ``python -m runtime.router --config FILE``), and the clients must
reach each other only through it (client mode, multicast scouting off). What a test verified
with zenoh-python 1.10 is in docs/faults.md ("Access control").
"""

from __future__ import annotations

import json
import logging
import os
import secrets
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import zenoh

from wire import keys, rmw_zenoh
from wire.diag import diag_key
from wire.frames import stats_key
from wire.keys import CAMERA_USER, MANAGER_USER, VIEWER_USER, ZONE_USER  # noqa: F401 (the ACL's users)
from wire.zconf import UsrPwdAuth, client_auth_config

logger = logging.getLogger(__name__)

# the services' user names are the key space's (wire.keys), where the name rule reserves them
ZONE_RULE = "zone-relay"
ZONE_LINK = "unixsock-stream"  # the zone routers' link to the run's router (a private socket)
FLEET_READ_RULE = "fleet-read"
CAMERA_RULE = "camera-publish"


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
    *,
    successors: Mapping[str, str] | None = None,
    cmd_vel: Mapping[str, str] | None = None,
    manager_user: str | None = MANAGER_USER,
    viewer_user: str | None = VIEWER_USER,
    zone_user: str | None = None,
    orders: bool = False,
) -> dict[str, Any]:
    """The ``access_control`` section for a fleet (see the module docstring).

    ``robots`` maps robot id -> formation id (the robot's user name is its id); ``leaders`` maps
    formation id -> leader robot id; ``successors`` formation id -> the member that takes the
    leader role when the leader dies (:mod:`scenario.succession`): it gets the leader's rights.
    ``cmd_vel`` maps robot id -> its base's command key (:func:`default_cmd_vel_key` when
    absent): the robot's user may put there, and the base's bridge, logged in as the same
    user, may subscribe to it. ``manager_user`` (goals) and ``viewer_user`` (read only) are
    left out when None. ``zone_user`` (pose zone routers, :func:`zone_router_config`) may relay
    every message under the prefix: a router of the run standing in for this one, whose own ACL
    checks the robots it serves. ``orders``: the rows of lifelong operation's order keys (the
    module docstring). ValueError names an invalid id or a leader not in ``robots``.
    """
    successors = dict(successors or {})
    _check_fleet(robots, leaders, successors, prefix,
                 [u for u in (camera_user, manager_user, viewer_user, zone_user) if u is not None])
    cmd_vel = dict(cmd_vel or {})
    fp = f"{prefix}/formation"
    rules: list[dict[str, Any]] = []

    def rule(rid: str, messages: list[str], flows: list[str], key_exprs: list[str]) -> str:
        rules.append({"id": rid, "messages": messages, "flows": flows, "permission": "allow",
                      "key_exprs": key_exprs})
        return rid

    common = [
        rule(FLEET_READ_RULE, ["declare_subscriber", "declare_liveliness_subscriber",
                               "liveliness_query"], ["ingress", "egress"], [f"{prefix}/**"]),
        rule("fleet-deliver", ["put", "delete", "liveliness_token", "reply"], ["egress"],
             [f"{prefix}/**"]),
    ]
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []

    def subject(user: str, own: list[str]) -> None:
        subjects.append({"id": user, "usernames": [user]})
        policies.append({"id": f"{user}-policy", "rules": [*common, *own], "subjects": [user]})

    stats = stats_key(prefix)
    order_rules = _order_rules(prefix, rule) if orders else {}
    subject(camera_user, [rule(CAMERA_RULE, ["put"], ["ingress"],
                               [f"{prefix}/robot/*/pose", f"{prefix}/robot/*/odom",
                                keys.obstacles_key(prefix),
                                f"{prefix}/camera/frame"]),
                          # the camera service answers its counters (a queryable)
                          rule("camera-stats", ["declare_queryable", "reply"], ["ingress"], [stats]),
                          rule("camera-stats-asked", ["query"], ["egress"], [stats]),
                          *order_rules.get("world", ())])
    if manager_user is not None:
        subject(manager_user, [
            rule("manager-goal", ["put"], ["ingress"], [f"{fp}/*/goal"]),
            rule("manager-query", ["query"], ["ingress"], [f"{fp}/*/status", stats]),
            *order_rules.get("manager", ()),
        ])
    if zone_user is not None:
        subject(zone_user, [zone_relay_rule(prefix, rules)])
    if viewer_user is not None:  # reads everything, may ask status and counters, writes nothing
        subject(viewer_user, [rule("viewer-query", ["query"], ["ingress"], [f"{fp}/*/status", stats])])
    lead = {leader: fid for fid, leader in leaders.items()}
    lead.update({rid: fid for fid, rid in successors.items()})
    for rid in robots:
        base_key = cmd_vel.get(rid) or default_cmd_vel_key(rid)
        odom = bridge_odom_key(base_key)  # the base's bridge puts it, the agent hears it
        own = [rule(f"{rid}-publish", ["put"], ["ingress"],
                    [keys.state_key(prefix, rid), keys.cmd_key(prefix, rid),
                     diag_key(prefix, rid), base_key, odom]),
               rule(f"{rid}-base", ["declare_subscriber"], ["ingress", "egress"], [base_key, odom]),
               rule(f"{rid}-base-deliver", ["put"], ["egress"], [base_key, odom])]
        if orders:
            own += [*order_rules["robot"],
                    rule(f"{rid}-bid", ["put"], ["ingress"], [f"{prefix}/order/*/bid/{rid}"])]
        if rid in lead:
            f = lead[rid]
            own += [
                rule(f"{rid}-lead", ["put"], ["ingress"],
                     [keys.ellipse_key(prefix, f), keys.beacon_key(prefix, f),
                      keys.others_key(prefix, f), f"{fp}/{f}/status", f"{fp}/{f}/plan"]),
                rule(f"{rid}-lead-token", ["liveliness_token"], ["ingress"],
                     [f"{fp}/{f}/leader"]),
                rule(f"{rid}-lead-status", ["declare_queryable", "reply"], ["ingress"],
                     [f"{fp}/{f}/status"]),
                # a client asks every leader at once (formation/*/status): the router matches a
                # query's own key expression, so the wildcard is named too (queries only)
                rule(f"{rid}-lead-asked", ["query"], ["egress"],
                     [f"{fp}/{f}/status", f"{fp}/*/status"]),
            ]
        subject(rid, own)
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def _order_rules(prefix: str, rule: Callable[[str, list[str], list[str], list[str]], str]
                 ) -> dict[str, list[str]]:
    """The rules of the order keys, made with ``rule`` (``fleet_acl``'s), by who holds them:
    ``world`` (the simulated world, as the camera user: put the loads ``{prefix}/world/loads``),
    ``manager`` (put orders; answer and ask queries on them and on their status) and
    ``robot`` (put an order's status, ask the orders and their status); each robot's own bid
    key is its own rule."""
    orders, statuses = f"{prefix}/order/*", f"{prefix}/order/*/status"
    return {
        "world": [rule("world-loads", ["put"], ["ingress"], [keys.loads_key(prefix)])],
        "manager": [rule("manager-orders", ["put"], ["ingress"], [orders]),
                    rule("manager-order-book", ["declare_queryable", "reply", "query"],
                         ["ingress"], [orders, statuses]),
                    rule("manager-order-book-asked", ["query"], ["egress"], [orders, statuses])],
        "robot": [rule("robot-order-status", ["put"], ["ingress"], [statuses]),
                  rule("robot-order-query", ["query"], ["ingress"], [orders, statuses])],
    }


def zone_relay_rule(prefix: str, rules: list[dict[str, Any]]) -> str:
    """Append the rule that lets a router of the run relay every message under ``prefix`` (both
    flows) to ``rules``; its id."""
    rules.append({"id": ZONE_RULE, "permission": "allow", "flows": ["ingress", "egress"],
                  "messages": ["put", "delete", "declare_subscriber", "declare_queryable",
                               "query", "reply", "liveliness_token",
                               "declare_liveliness_subscriber", "liveliness_query"],
                  "key_exprs": [f"{prefix}/**"]})
    return ZONE_RULE


def zone_router_config(listen: Sequence[str], acl: Mapping[str, Any],
                       dictionary_file: str | os.PathLike[str], link: str,
                       auth: UsrPwdAuth) -> dict[str, Any]:
    """A pose zone router's configuration (:mod:`simulator.zones`): :func:`router_config` with the
    run's ``acl`` for the robots that connect to it, linked to the run's router at ``link`` (a
    :data:`ZONE_LINK` endpoint in the run's private folder) as user ``auth``. The run's router
    presents no user name on that link (user/password names only the side that connects), so
    the zone trusts the link by its protocol, which only the zone uses: the robots come in
    over TCP under their own policies."""
    if not link.startswith(ZONE_LINK + "/"):
        raise ValueError(f"link: {link!r} is not a {ZONE_LINK} endpoint")
    acl = json.loads(json.dumps(acl))  # a copy
    prefix_rules = [r for r in acl["rules"] if r["id"] == FLEET_READ_RULE]
    prefix = prefix_rules[0]["key_exprs"][0][:-len("/**")] if prefix_rules else keys.DEFAULT_PREFIX
    if not any(r["id"] == ZONE_RULE for r in acl["rules"]):
        zone_relay_rule(prefix, acl["rules"])
    acl["subjects"].append({"id": "run-router-link", "link_protocols": [ZONE_LINK]})
    acl["policies"].append({"id": "run-router-link-policy", "rules": [ZONE_RULE],
                            "subjects": ["run-router-link"]})
    conf = router_config(listen, acl, dictionary_file)
    conf["connect"] = {"endpoints": [link]}
    conf["transport"]["auth"]["usrpwd"].update({"user": auth.user, "password": auth.password})
    return conf


def _check_fleet(robots: Mapping[str, str], leaders: Mapping[str, str],
                 successors: Mapping[str, str], prefix: str, services: list[str]) -> None:
    """ValueError naming the first invalid id, clash or leader/successor outside its formation."""
    keys.validate_prefix(prefix)
    _check_user(services[0], "camera_user")
    if not robots:
        raise ValueError("robots: must not be empty")
    for u in services[1:]:
        _check_user(u, "user")
    if len(set(services)) != len(services):
        raise ValueError(f"users: the service users {services} must differ")
    for rid, fid in robots.items():
        _check_user(rid, "robot id")
        keys.validate_id(fid, "formation id")
        if rid in services:
            raise ValueError(f"robot id {rid!r} is a service user's name")
    for what, chosen in (("leaders", leaders), ("successors", successors)):
        for fid, rid in chosen.items():
            if robots.get(rid) != fid:
                raise ValueError(f"{what}: {rid!r} is not a robot of formation {fid!r}")


def bridge_odom_key(cmd_vel_key: str) -> str:
    """The key zenoh-bridge-ros2dds carries a base's ``odom`` topic on: the namespace of its
    command key, ``/odom`` (``a1/cmd_vel`` -> ``a1/odom``; ``cmd_vel`` -> ``odom``)."""
    namespace, _sep, _topic = cmd_vel_key.rpartition("/")
    return f"{namespace}/odom" if namespace else "odom"


def default_cmd_vel_key(robot: str) -> str:
    """The key of ``robot``'s base commands where none is configured: ``{robot}/cmd_vel``, the
    key ``zenoh-bridge-ros2dds`` with ``namespace: {robot}`` maps ``/cmd_vel`` to (as deploy
    sets it up)."""
    return f"{robot}/cmd_vel"


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


def write_client_file(path: str | os.PathLike[str], auth: UsrPwdAuth,
                      connect: Sequence[str]) -> None:
    """A client's credentials as a Zenoh JSON5 fragment (:func:`wire.zconf.client_auth_config`:
    the router's endpoints, the user and password; mode 0600), for ``--auth FILE``."""
    text = json.dumps(client_auth_config(auth, connect), indent=2) + "\n"
    _write_private(Path(path), text)


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
    text = json.dumps(conf, indent=2) + "\n"
    try:
        zenoh.Config.from_json5(text)
    except Exception as exc:  # noqa: BLE001 - zenoh.ZError: an unknown key or a bad value
        raise ValueError(f"router config rejected by zenoh: {exc}") from None
    Path(path).write_text(text, encoding="utf-8")



def add_rmw_zenoh(acl: dict[str, Any], robots: Mapping[str, Any],
                  viewer_user: str | None = VIEWER_USER,
                  world_user: str | None = None) -> dict[str, Any]:
    """``acl`` (of :func:`fleet_acl`, given each robot's rmw_zenoh data key as its ``cmd_vel``)
    with the ROS graph rights of robots whose base is on rmw_zenoh (``robots``: robot id ->
    :class:`wire.rmw_zenoh.RmwSettings`), changed in place and returned.

    Robot ``r``'s user (its agent, and the robot's ``rmw_zenohd`` linked to this router as the
    same user) may hold liveliness tokens in its own namespace and domain (the agent's node and
    publisher; the robot's ROS nodes), and declare liveliness subscribers and queries on and be
    sent every token of its domain (rmw_zenoh's graph). The viewer may subscribe to the
    domain's data keys and tokens and hold tokens of its own (an rmw_zenoh subscriber, e.g.
    ``ros2 topic echo``, watching a run). ``world_user`` (``formation run --base rmw_zenoh``:
    the simulated world playing the bases) may subscribe to the domain's data keys."""
    if not robots:
        return acl
    rules: list[dict[str, Any]] = acl["rules"]
    policies = {p["subjects"][0]: p for p in acl["policies"]}
    domains = sorted({int(s.domain) for s in robots.values()})

    def rule(rid: str, messages: list[str], flows: list[str], key_exprs: list[str]) -> str:
        rules.append({"id": rid, "messages": messages, "flows": flows, "permission": "allow",
                      "key_exprs": key_exprs})
        return rid

    graph = [f"{rmw_zenoh.ADMIN_SPACE}/{d}/**" for d in domains]
    read = rule("rmw-graph-read", ["declare_liveliness_subscriber", "liveliness_query"],
                ["ingress", "egress"], graph)
    deliver = rule("rmw-graph-deliver", ["liveliness_token"], ["egress"], graph)
    for rid, settings in robots.items():
        own = rule(f"{rid}-rmw-tokens", ["liveliness_token"], ["ingress"],
                   [rmw_zenoh.graph_key(settings)])
        # the robot's own odom topic: its rmw_zenohd puts it, its agent hears it (every
        # distribution's type hash unless the release is pinned)
        distros = ([rmw_zenoh.release(settings.release).distro] if settings.release
                   else sorted(rmw_zenoh.DEFAULT_RELEASE))
        odom = sorted({rmw_zenoh.odom_data_key(settings, d) for d in distros})
        policies[rid]["rules"] += [
            read, deliver, own,
            rule(f"{rid}-rmw-odom", ["put"], ["ingress", "egress"], odom),
            rule(f"{rid}-rmw-odom-read", ["declare_subscriber"], ["ingress", "egress"], odom)]
    data = [f"{d}/**" for d in domains]
    if world_user is not None and world_user in policies:
        policies[world_user]["rules"] += [
            rule("world-rmw-read", ["declare_subscriber"], ["ingress", "egress"], data),
            rule("world-rmw-deliver", ["put"], ["egress"], data)]
    if viewer_user is not None and viewer_user in policies:
        policies[viewer_user]["rules"] += [
            read, deliver,
            rule("viewer-rmw-read", ["declare_subscriber"], ["ingress", "egress"], data),
            rule("viewer-rmw-deliver", ["put"], ["egress"], data),
            rule("viewer-rmw-tokens", ["liveliness_token"], ["ingress"], graph)]
    return acl
