"""The agent's formation as a value it replaces at run time (agent.node.AgentNode.regroup): a
formation of one, a team of two, one again, the subscriptions, the leader role and the
successor's watch following, derived the same way as at the start (agent.config.memberships)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
import zenoh

from agent.config import ZenohSettings, build_agent_configs, membership_of, memberships
from agent.node import AgentNode, NodeOptions
from leader.succession import leader_token_key
from runtime.testing import RouterProcess, has_matching_subscribers, wait_for_matching
from scenario import Scenario, load_scenario
from scenario.model import Edge, FormationSpec, RobotSpec
from simulator.lifelong import solo
from wire import keys, zconf
from wire.payloads import Pose, encode

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "tests" / "scenarios" / "lifelong-beam-pair.yaml"
P = keys.DEFAULT_PREFIX
TIMEOUT_S = 10.0
BEACONS = keys.all_formations_key(P, keys.BEACON)


def alone() -> Scenario:
    """The fleet f1, f2 as two formations of one, each where it starts."""
    sc = load_scenario(SCENARIO)
    assert sc.lifelong is not None
    starts = sc.lifelong.fleet.starts
    return replace(sc, formations=tuple(solo(r, starts[r], starts[r][:2])
                                        for r in sc.lifelong.fleet.robot_ids))


def teamed() -> Scenario:
    """f1 and f2 as the team of order o1: f1 at slot 0 (leads), f2 at slot 1 (succeeds)."""
    sc = alone()
    f1, f2 = (f.robots[0] for f in sc.formations)
    team = FormationSpec("o1", "f1", (RobotSpec("f1", "o1", f1.start, (-0.7, -1.2)),
                                      RobotSpec("f2", "o1", f2.start, (0.7, -1.2))),
                         (Edge("f1", "f2", 1.4),), None)
    return replace(sc, formations=(team,))


def test_memberships_are_the_configurations_formation_part() -> None:
    sc = alone()
    cfgs = build_agent_configs(sc)
    assert {r: membership_of(c) for r, c in cfgs.items()} == memberships(sc)


def test_before_it_opens_an_agent_changes_formation_at_once_and_back() -> None:
    sc = alone()
    node = AgentNode(build_agent_configs(sc)["f2"], NodeOptions(lockstep=True))
    first = set(node.subscribed_keys)
    # a formation of one leads itself: the other formation's ellipse (lock-step), no others
    assert first == {keys.pose_key(P, "f2"), keys.obstacles_key(P), keys.ellipse_key(P, "f1")}
    assert node.leader.leading
    node.regroup(memberships(teamed())["f2"])
    # a member of o1: its partner's state, its leader's others; no ellipse, no role
    assert set(node.subscribed_keys) == {keys.pose_key(P, "f2"), keys.obstacles_key(P),
                                         keys.state_key(P, "f1"), keys.others_key(P, "o1")}
    assert not node.leader.leading and node.cfg.standby is not None  # f2 succeeds f1
    assert node.ticker.keys.others == keys.others_key(P, "o1")
    node.regroup(memberships(sc)["f2"])
    assert set(node.subscribed_keys) == first and node.leader.leading
    assert node.regroups == 2


def test_a_changed_formation_that_is_invalid_is_refused_before_anything_changes() -> None:
    node = AgentNode(build_agent_configs(alone())["f1"])
    before = dict(node.subscribed_keys)
    bad = replace(memberships(teamed())["f1"], formation="o/1")
    with pytest.raises(ValueError, match="formation"):
        node.regroup(bad)
    assert node.subscribed_keys == before and node.cfg.formation == "f1"


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as proc:
        yield proc


def wait_until(predicate, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.005)


def alive(session: zenoh.Session, key: str) -> bool:
    """Whether a liveliness token is held on ``key``."""
    return any(r.ok is not None for r in session.liveliness().get(key, timeout=2.0))


def test_over_zenoh_an_agent_goes_from_one_to_a_team_of_two_and_back_its_subscriptions_following(
        router: RouterProcess) -> None:
    zs = ZenohSettings(mode="client", connect=(router.endpoint,))
    cfg = build_agent_configs(alone(), zenoh=zs)["f1"]
    peer = zenoh.open(zconf.make_config("client", connect=[router.endpoint],
                                        connect_timeout_s=TIMEOUT_S))
    partner = peer.declare_publisher(keys.state_key(P, "f1"))  # what f2 would read of f1
    mate = peer.declare_publisher(keys.state_key(P, "f2"))  # what f1 reads of f2 in the team
    pose = peer.declare_publisher(keys.pose_key(P, "f1"))
    seen: list[set[str]] = []

    async def main() -> None:
        node = AgentNode(cfg)  # real time
        stop = asyncio.Event()
        task = asyncio.create_task(node.run(stop))
        loop = asyncio.get_running_loop()
        try:
            await loop.run_in_executor(None, wait_for_matching, pose, TIMEOUT_S)
            seen.append(set(node.subscribed_keys))
            assert not has_matching_subscribers(mate)
            assert await loop.run_in_executor(None, alive, peer, leader_token_key(P, "f1"))
            node.regroup(memberships(teamed())["f1"])  # the team of o1, f1 leading
            await loop.run_in_executor(None, wait_for_matching, mate, TIMEOUT_S)
            assert node.regroups == 1
            seen.append(set(node.subscribed_keys))
            assert await loop.run_in_executor(None, alive, peer, leader_token_key(P, "o1"))
            # a fleet robot holds its own formation's token for its agent's life, in a team too
            # (its liveliness for the other leaders: leader.succession)
            assert await loop.run_in_executor(None, alive, peer, leader_token_key(P, "f1"))
            node.regroup(memberships(alone())["f1"])  # dissolved: one again
            await loop.run_in_executor(None, wait_until, lambda: node.regroups == 2, "regroup")
            await loop.run_in_executor(None, wait_until,
                                       lambda: not has_matching_subscribers(mate), "unsubscribe")
            seen.append(set(node.subscribed_keys))
            assert await loop.run_in_executor(None, alive, peer, leader_token_key(P, "f1"))
        finally:
            stop.set()
            await asyncio.wait_for(task, TIMEOUT_S)

    try:
        asyncio.run(main())
    finally:
        for pub in (partner, mate, pose):
            pub.undeclare()
        peer.close()
    one = {keys.pose_key(P, "f1"), keys.obstacles_key(P), BEACONS}
    assert [len(s) for s in seen] == [3, 4, 3]
    assert seen == [one, one | {keys.state_key(P, "f2")}, one]


def test_in_lock_step_the_change_waits_for_the_next_tick(router: RouterProcess) -> None:
    zs = ZenohSettings(mode="client", connect=(router.endpoint,))
    # as a robot of fixed formations (a fleet robot subscribes a tick ahead: agent.lifepart)
    cfg = replace(build_agent_configs(alone(), zenoh=zs)["f2"], lifelong=None)
    peer = zenoh.open(zconf.make_config("client", connect=[router.endpoint],
                                        connect_timeout_s=TIMEOUT_S))
    pose = peer.declare_publisher(keys.pose_key(P, "f2"))
    seen: list[set[str]] = []

    async def main() -> None:
        node = AgentNode(cfg, NodeOptions(lockstep=True, lockstep_timeout=0.1))
        stop = asyncio.Event()
        task = asyncio.create_task(node.run(stop))
        loop = asyncio.get_running_loop()
        try:
            await loop.run_in_executor(None, wait_for_matching, pose, TIMEOUT_S)
            node.regroup(memberships(teamed())["f2"])
            await asyncio.sleep(0)
            seen.append(set(node.subscribed_keys))  # no tick yet: as it was
            pose.put(encode(Pose(0.3, -2.4, 0.0, 0.0)))  # the frame stamped 0
            await loop.run_in_executor(None, wait_until, lambda: node.ticks >= 1, "a tick")
            seen.append(set(node.subscribed_keys))
        finally:
            stop.set()
            await asyncio.wait_for(task, TIMEOUT_S)

    try:
        asyncio.run(main())
    finally:
        pose.undeclare()
        peer.close()
    assert seen[0] == {keys.pose_key(P, "f2"), keys.obstacles_key(P), keys.ellipse_key(P, "f1")}
    assert seen[1] == {keys.pose_key(P, "f2"), keys.obstacles_key(P), keys.state_key(P, "f1"),
                       keys.others_key(P, "o1")}


def test_in_lock_step_a_fleet_robot_subscribes_a_tick_before_it_changes(
        router: RouterProcess) -> None:
    zs = ZenohSettings(mode="client", connect=(router.endpoint,))
    cfg = build_agent_configs(alone(), zenoh=zs)["f2"]
    life = cfg.lifelong
    assert life is not None  # a fleet robot; with no parking spot, it asks for no walk itself
    cfg = replace(cfg, lifelong=replace(life, fleet=replace(life.fleet, parking=())))
    peer = zenoh.open(zconf.make_config("client", connect=[router.endpoint],
                                        connect_timeout_s=TIMEOUT_S))
    pose = peer.declare_publisher(keys.pose_key(P, "f2"))
    seen: list[tuple[str, set[str]]] = []

    async def main() -> None:
        node = AgentNode(cfg, NodeOptions(lockstep=True, lockstep_timeout=0.1))
        stop = asyncio.Event()
        task = asyncio.create_task(node.run(stop))
        loop = asyncio.get_running_loop()
        try:
            await loop.run_in_executor(None, wait_for_matching, pose, TIMEOUT_S)
            node.regroup(memberships(teamed())["f2"])
            for k in (1, 2):
                pose.put(encode(Pose(0.3, -2.4, 0.0, 0.05 * (k - 1))))
                await loop.run_in_executor(None, wait_until, lambda k=k: node.ticks >= k,
                                           f"tick {k}")
                seen.append((node.cfg.formation, set(node.subscribed_keys)))
        finally:
            stop.set()
            await asyncio.wait_for(task, TIMEOUT_S)

    try:
        asyncio.run(main())
    finally:
        pose.undeclare()
        peer.close()
    old = {keys.pose_key(P, "f2"), keys.obstacles_key(P), keys.ellipse_key(P, "f1")}
    new = {keys.pose_key(P, "f2"), keys.obstacles_key(P), keys.state_key(P, "f1"),
           keys.others_key(P, "o1")}
    assert seen[0] == ("f2", old | new)  # the first tick: still alone, the team's inputs heard
    assert seen[1] == ("o1", new)  # the second: in the team
