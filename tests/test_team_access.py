"""A team's formation keys under access control in a fleet (wire.acl ``orders=True``),
enforced by a Python router: robot r may put a leader's keys of any team (named by an order
id), and of its own formation of one, but not of another robot's formation of one (those keys
name that robot), nor another robot's own keys, nor a goal. Each denied put goes out before an
allowed marker on the same session, so once the marker arrives the denied one would have."""

from __future__ import annotations

import queue
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.testing import fleet_acl_router, open_as
from wire import acl, keys

ROOT = Path(__file__).resolve().parent.parent
P = keys.DEFAULT_PREFIX
ROBOTS = {"r1": "r1", "r2": "r2", "r3": "r3"}  # a fleet: each robot a formation of one
FP = f"{P}/formation"


def test_every_robot_gets_the_team_rows_and_a_deny_row_for_each_other_robots_formation():
    conf = acl.fleet_acl(ROBOTS, ROBOTS, orders=True)
    by_id = {r["id"]: r for r in conf["rules"]}
    policy = {p["subjects"][0]: p["rules"] for p in conf["policies"]}
    assert set(by_id[acl.TEAM_LEADER_RULE]["key_exprs"]) == {
        f"{FP}/*/{k}" for k in ("ellipse", "beacon", "others", "status", "plan")}
    assert f"{FP}/*/goal" not in by_id[acl.TEAM_LEADER_RULE]["key_exprs"]  # the manager's
    solo = by_id[acl.SOLO_RULE + "r2"]
    assert solo["permission"] == "deny" and f"{FP}/r2/leader" in solo["key_exprs"]
    assert acl.TEAM_LEADER_RULE in policy["r1"] and acl.SOLO_RULE + "r2" in policy["r1"]
    assert acl.SOLO_RULE + "r1" not in policy["r1"]  # its own formation of one stays its own
    assert not any(r.startswith(acl.TEAM_LEADER_RULE) or r.startswith(acl.SOLO_RULE)
                   for u in (acl.VIEWER_USER, acl.MANAGER_USER, acl.CAMERA_USER)
                   for r in policy[u])
    plain = acl.fleet_acl(ROBOTS, ROBOTS)  # fixed formations: as before
    assert not any(r["id"].startswith((acl.TEAM_LEADER_RULE, acl.SOLO_RULE))
                   for r in plain["rules"])


ROSTERS = {"o7": ("r2", "r1", "r3")}  # o7's team: r2 leads, r1 succeeds


@pytest.mark.parametrize("key, sender, why", [
    (keys.ellipse_key(P, "o7"), "r2", None),                   # its leader
    (keys.others_key(P, "o7"), "r1", None),                    # its successor, taking over
    (keys.beacon_key(P, "o7"), "r3", acl.NOT_TEAM_LEADER),     # a member
    (f"{FP}/o7/plan", "r3", acl.NOT_TEAM_LEADER),
    (f"{FP}/o7/status", "r4", acl.NOT_TEAM_LEADER),            # a robot of no roster
    (f"{P}/order/o7/status", "r3", acl.NOT_TEAM_LEADER),
    (f"{P}/order/o7/status", "r2", None),
    (keys.goal_key(P, "o7"), "r3", None),                      # not a leader's key
    (f"{P}/order/o7/bid/r3", "r3", None),                      # a bid: its key names its robot
    (keys.ellipse_key(P, "o8"), "r3", None),                   # no roster known: the router's
    (keys.ellipse_key(P, "r3"), "r3", None),                   # a formation of one
    (keys.state_key(P, "r3"), "r3", None),
    ("elsewhere/formation/o7/ellipse", "r3", None),            # outside the prefix
])
def test_a_receiver_keeps_a_teams_leader_keys_only_from_its_leader_or_successor(key, sender, why):
    assert acl.team_sender_problem(P, key, sender, ROSTERS) == why


@pytest.fixture(scope="module")
def router(tmp_path_factory) -> Iterator[tuple[str, dict]]:
    with fleet_acl_router(tmp_path_factory.mktemp("team-acl"), ROBOTS) as r:
        yield r


def heard_after(router, talker_user: str, key: str) -> list[str]:
    """Robot r3, subscribed to everything under the prefix, hears ``talker_user`` put ``key``
    and then its own state (the marker) until the marker arrives; every key heard."""
    got: queue.SimpleQueue[str] = queue.SimpleQueue()
    marker = keys.state_key(P, talker_user)
    heard: list[str] = []
    with open_as(router, "r3") as listener, open_as(router, talker_user) as talker:
        sub = listener.declare_subscriber(f"{P}/**", lambda s: got.put(str(s.key_expr)))
        try:
            for _ in range(200):
                talker.put(key, b"x")
                talker.put(marker, b"m")
                try:
                    while (k := got.get(timeout=0.1)) != marker:
                        heard.append(k)
                    return heard
                except queue.Empty:
                    continue
        finally:
            sub.undeclare()
    raise AssertionError(f"the marker {marker} never arrived")


@pytest.mark.parametrize("key, allowed", [
    (keys.ellipse_key(P, "o7"), True),      # a team's: any robot may come to lead it
    (keys.others_key(P, "o7"), True),
    (f"{FP}/o7/status", True),
    (keys.ellipse_key(P, "r1"), True),      # its own formation of one
    (keys.ellipse_key(P, "r2"), False),     # another robot's formation of one: forged
    (keys.others_key(P, "r2"), False),
    (f"{FP}/r2/status", False),
    (keys.state_key(P, "r2"), False),       # another robot's own key: forged
    (keys.cmd_key(P, "r2"), False),
    (keys.goal_key(P, "o7"), False),        # the fleet manager's
])
def test_what_robot_r1_may_put_on_formation_and_robot_keys(router, key, allowed):
    assert (key in heard_after(router, "r1", key)) is allowed


def test_a_robot_holds_a_teams_leader_token_but_not_another_robots(router):
    with open_as(router, "r3") as watcher, open_as(router, "r1") as r1:
        team = r1.liveliness().declare_token(f"{FP}/o7/leader")
        other = r1.liveliness().declare_token(f"{FP}/r2/leader")
        try:
            for _ in range(200):
                found = {str(r.ok.key_expr) for r in watcher.liveliness().get(
                    f"{FP}/*/leader", timeout=2.0) if r.ok is not None}
                if f"{FP}/o7/leader" in found:
                    break
            assert found == {f"{FP}/o7/leader"}
        finally:
            team.undeclare()
            other.undeclare()
