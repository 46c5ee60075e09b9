"""What an agent holds declared on its Zenoh session across a change of formation
(agent.node.AgentNode.regroup, agent.transport.Transport.forget_publishers): from a formation of
one to a team of two and back, every publisher and subscriber of the old formation is
undeclared, so the agent holds exactly what an agent started in the new formation holds."""

from __future__ import annotations

import asyncio
import time
from collections import Counter
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from agent.config import ZenohSettings, build_agent_configs, memberships
from agent.node import AgentNode
from agent.transport import Transport, formation_scope
from runtime.testing import RouterProcess, wait_for_matching
from tests.test_agent_regroup import alone, teamed
from wire import keys, zconf
from wire.traffic import TrafficCounter

P = keys.DEFAULT_PREFIX
TIMEOUT_S = 10.0


class Handle:
    """A declared publisher or subscriber that tells its session when it is undeclared."""

    def __init__(self, inner: Any, ledger: CountingSession, kind: str, key: str) -> None:
        self._inner, self._ledger, self._entry = inner, ledger, (kind, key)
        ledger.live[self._entry] += 1

    def undeclare(self) -> None:
        self._inner.undeclare()
        self._ledger.live[self._entry] -= 1

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


class CountingSession:
    """A real Zenoh session that counts the publishers and subscribers declared on it and not
    yet undeclared, by key."""

    def __init__(self, session: zenoh.Session) -> None:
        self._session = session
        self.live: Counter[tuple[str, str]] = Counter()

    def declare_publisher(self, key: str, *args: Any, **kwargs: Any) -> Handle:
        return Handle(self._session.declare_publisher(key, *args, **kwargs), self, "pub", key)

    def declare_subscriber(self, key: str, *args: Any, **kwargs: Any) -> Handle:
        return Handle(self._session.declare_subscriber(key, *args, **kwargs), self, "sub", key)

    def held(self) -> set[tuple[str, str]]:
        """What is declared and not undeclared; AssertionError on anything declared twice."""
        assert all(n in (0, 1) for n in self.live.values()), self.live
        return {entry for entry, n in self.live.items() if n}

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)


class CountedNode(AgentNode):
    """An agent whose session counts what it declares."""

    counted: CountingSession | None = None

    def open_session(self) -> Any:
        self.counted = CountingSession(super().open_session())
        return self.counted


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


def held_by_a_fresh_agent(router: RouterProcess, cfg) -> set[tuple[str, str]]:
    """What an agent started with ``cfg`` holds once open."""
    node = CountedNode(cfg)

    async def main() -> set[tuple[str, str]]:
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(None, node.open, loop)
        try:
            assert node.counted is not None
            return node.counted.held()
        finally:
            node.close()

    return asyncio.run(main())


def of_formation(held: set[tuple[str, str]], fid: str) -> set[tuple[str, str]]:
    scope = formation_scope(P, fid)
    return {(kind, key) for kind, key in held if key.startswith(scope)}


def test_a_regroup_undeclares_the_old_formations_publishers_and_subscribers(
        router: RouterProcess) -> None:
    zs = ZenohSettings(mode="client", connect=(router.endpoint,))
    one_cfg = build_agent_configs(alone(), zenoh=zs)["f1"]
    team_cfg = build_agent_configs(teamed(), zenoh=zs)["f1"]
    peer = zenoh.open(zconf.make_config("client", connect=[router.endpoint],
                                        connect_timeout_s=TIMEOUT_S))
    pose = peer.declare_publisher(keys.pose_key(P, "f1"))
    mate = peer.declare_publisher(keys.state_key(P, "f2"))  # what f1 reads of f2 in the team
    seen: list[set[tuple[str, str]]] = []
    published: list[list[str]] = []

    async def main() -> None:
        node = CountedNode(one_cfg)  # real time
        stop = asyncio.Event()
        task = asyncio.create_task(node.run(stop))
        loop = asyncio.get_running_loop()
        try:
            await loop.run_in_executor(None, wait_for_matching, pose, TIMEOUT_S)
            counted, t = node.counted, node.transport
            assert counted is not None and t is not None
            # the pose is subscribed before the lifelong part's keys: wait for its last one
            loads = ("sub", keys.loads_key(P))
            await loop.run_in_executor(None, wait_until, lambda: node.life is None
                                       or loads in counted.held(), "the loads subscribed")
            seen.append(counted.held())
            published.append(t.publishing())
            node.regroup(memberships(teamed())["f1"])  # the team of o1, f1 leading
            await loop.run_in_executor(None, wait_until, lambda: node.regroups == 1, "team")
            await loop.run_in_executor(None, wait_for_matching, mate, TIMEOUT_S)
            seen.append(counted.held())
            published.append(t.publishing())
            node.regroup(memberships(alone())["f1"])  # dissolved: one again
            await loop.run_in_executor(None, wait_until, lambda: node.regroups == 2, "one again")
            seen.append(counted.held())
            published.append(t.publishing())
        finally:
            stop.set()
            await asyncio.wait_for(task, TIMEOUT_S)

    try:
        asyncio.run(main())
    finally:
        for pub in (pose, mate):
            pub.undeclare()
        peer.close()
    one, team, again = seen
    fresh_one = held_by_a_fresh_agent(router, one_cfg)
    fresh_team = held_by_a_fresh_agent(router, team_cfg)
    # in the team: nothing of the formation of one is left, the team's keys as a fresh leader's
    assert of_formation(team, "f1") == set()
    assert of_formation(team, "o1") == of_formation(fresh_team, "o1") != set()
    assert ("pub", keys.ellipse_key(P, "o1")) in team and ("pub", keys.others_key(P, "o1")) in team
    # one again: nothing of the team is left, and it holds what it held at the start
    assert of_formation(again, "o1") == set()
    assert again == one == fresh_one
    counts = [(sum(k == "pub" for k, _ in s), sum(k == "sub" for k, _ in s)) for s in seen]
    assert counts[0] == counts[2] and counts[1] != counts[0]
    # the transport's own record: the leader keys of the formation it is in, no other's
    assert [sorted(k for k in p if "/formation/" in k) for p in published] == [
        sorted([keys.ellipse_key(P, "f1"), keys.beacon_key(P, "f1"), keys.others_key(P, "f1")]),
        sorted([keys.ellipse_key(P, "o1"), keys.beacon_key(P, "o1"), keys.others_key(P, "o1")]),
        sorted([keys.ellipse_key(P, "f1"), keys.beacon_key(P, "f1"), keys.others_key(P, "f1")])]


class StandIn:
    def __init__(self) -> None:
        self.sent = 0

    def put_message(self, _msg: object) -> None:
        self.sent += 1

    def undeclare(self) -> None:
        pass


def test_the_transport_forgets_only_the_publishers_of_one_formation_that_are_not_kept() -> None:
    t = Transport(None, TrafficCounter(P))
    names = [keys.state_key(P, "f1"), keys.ellipse_key(P, "f1"), keys.others_key(P, "f1"),
             keys.ellipse_key(P, "f10"), keys.ellipse_key(P, "o1")]
    pubs = {k: StandIn() for k in names}
    for k, pub in pubs.items():
        t.adopt(k, pub)
    gone = t.forget_publishers(formation_scope(P, "f1"), [keys.others_key(P, "f1")])
    assert gone == [pubs[keys.ellipse_key(P, "f1")]]  # not f10's: the scope ends in "/"
    assert t.publishing() == sorted(set(names) - {keys.ellipse_key(P, "f1")})
    assert not t.publish(keys.ellipse_key(P, "f1"), object())  # nothing sent on a forgotten key
    assert t.publish(keys.others_key(P, "f1"), object()) and pubs[keys.others_key(P, "f1")].sent == 1
