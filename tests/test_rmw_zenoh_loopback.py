"""An agent configured for a robot on rmw_zenoh (no bridge) is an rmw_zenoh publisher on a real
Zenoh router (loopback, multicast scouting off): a subscriber on the rmw_zenoh data key gets
samples whose payload rosbags decodes and whose attachment parses, and the node's and
publisher's liveliness tokens are there for a liveliness get and go on shutdown."""

from __future__ import annotations

import asyncio
import dataclasses
import threading
import time
from pathlib import Path

import pytest
import zenoh
from rosbags.typesys import Stores, get_typestore

from agent.base import make_base
from agent.config import ZenohSettings, build_agent_configs
from agent.node import AgentNode, NodeOptions
from runtime.testing import RouterProcess, wait_for_matching
from scenario import load_scenario
from wire import rmw_zenoh as rmw
from wire import zconf
from wire.payloads import Cmd

ROOT = Path(__file__).resolve().parent.parent
STORE = get_typestore(Stores.ROS2_JAZZY)


def _wait(predicate, timeout_s: float = 60.0) -> None:
    """Until ``predicate`` holds; the deadline only ends a wait that would never end (a loaded
    machine's router may take seconds to pass a token on)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out waiting on the router"
        time.sleep(0.02)


class Watcher:
    """A plain Zenoh client reading one data key (with attachments) and the domain's tokens."""

    def __init__(self, endpoint: str, key: str, domain: int) -> None:
        self.session = zenoh.open(zconf.make_config("client", connect=[endpoint]))
        self.samples: list[tuple[bytes, bytes | None]] = []
        self.tokens: dict[str, bool] = {}
        self._lock = threading.Lock()
        self._sub = self.session.declare_subscriber(key, self._on_sample)
        self._lv = self.session.liveliness().declare_subscriber(
            rmw.liveliness_selector(domain), self._on_token, history=True)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        with self._lock:
            self.samples.append((sample.payload.to_bytes(),
                                 None if att is None else att.to_bytes()))

    def _on_token(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.tokens[str(sample.key_expr)] = sample.kind == zenoh.SampleKind.PUT

    def alive(self) -> list[str]:
        with self._lock:
            return [k for k, up in self.tokens.items() if up]

    def got(self) -> list[tuple[bytes, bytes | None]]:
        with self._lock:
            return list(self.samples)

    def get_tokens(self, selector: str) -> list[str]:
        return [str(r.ok.key_expr) for r in self.session.liveliness().get(selector, timeout=20.0)
                if r.ok is not None]

    def close(self) -> None:
        self._sub.undeclare()
        self._lv.undeclare()
        self.session.close()


@pytest.mark.parametrize("base,release,cmd_type", [
    ("turtlebot3-jazzy", "", ""),                   # jazzy: TwistStamped, RIHS01, positional
    ("turtlebot3-humble", "", ""),                  # humble: Twist, TypeHashNotSupported
    ("turtlebot3-jazzy", "jazzy-0.2.3", "Twist"),   # keyed attachment, Twist on Jazzy
])
def test_make_base_publishes_like_rmw_zenoh(base, release, cmd_type):
    settings = rmw.RmwSettings(release=release, cmd_type=cmd_type, namespace="a1", domain=5)
    with RouterProcess() as router:
        zs = ZenohSettings(mode="client", connect=(router.endpoint,))
        cfg = build_agent_configs(load_scenario(ROOT / "scenarios/thesis-6.5.yaml"), zenoh=zs)["a1"]
        cfg = dataclasses.replace(cfg, base=base, rmw=settings)
        rel, type_name = rmw.resolve(settings, base.rsplit("-", 1)[1])
        key = rmw.topic_key(5, "/a1/cmd_vel", type_name, rel)
        watcher = Watcher(router.endpoint, key, 5)
        session = zenoh.open(zconf.make_config("client", connect=[router.endpoint]))
        try:
            rbase = make_base(cfg, session)
            assert rbase.spec.key == key
            _wait(lambda: len(watcher.alive()) == 2)
            want = sorted([rbase.spec.node_token, rbase.spec.publisher_token])
            assert sorted(watcher.alive()) == want
            # a liveliness get answers with the tokens the router holds: asked until both are in
            # (under load a get's replies may end before the second token's declaration is in)
            seen: list[list[str]] = []

            def answered() -> bool:
                seen.append(sorted(watcher.get_tokens(rmw.liveliness_selector(5))))
                return seen[-1] == want or not set(seen[-1]) <= set(want)

            _wait(answered)
            assert seen[-1] == want
            subs = watcher.get_tokens(rmw.subscription_selector(5, "/a1/cmd_vel", type_name, rel))
            assert subs == []  # nobody subscribes the ROS way here
            wait_for_matching(rbase.publisher)
            for i in range(3):
                rbase.send(0.1 * (i + 1) / 3, -0.5, 12.25 + i)
            _wait(lambda: len(watcher.got()) >= 3)
            rbase.stop()
            _wait(lambda: len(watcher.got()) >= 4 and not watcher.alive())
        finally:
            session.close()
            watcher.close()
    samples = watcher.got()
    atts = [rmw.decode_attachment(a or b"", rel.attachment) for _, a in samples]
    assert [a.sequence_number for a in atts] == [1, 2, 3, 4]
    assert {a.gid for a in atts} == {rbase.spec.gid}
    msgs = [STORE.deserialize_cdr(p, type_name) for p, _ in samples]
    twists = [m.twist if type_name == rmw.TWIST_STAMPED else m for m in msgs]
    assert (twists[0].linear.x, twists[0].angular.z) == pytest.approx((0.1 / 3, -0.5))
    assert (twists[-1].linear.x, twists[-1].angular.z) == (0.0, 0.0)  # stopped on the way out
    node = rmw.parse_token(rbase.spec.node_token)
    pub = rmw.parse_token(rbase.spec.publisher_token)
    assert (node.kind, node.namespace, pub.kind, pub.topic) == ("NN", "/a1", "MP", "/a1/cmd_vel")
    assert pub.type_hash == (rmw.rihs01(type_name) if rel.type_hash else "TypeHashNotSupported")
    assert pub.zid == node.zid != ""


def test_an_agent_node_drives_its_rmw_zenoh_base():
    """The agent's own command path (AgentNode) reaches the rmw_zenoh key."""
    with RouterProcess() as router:
        zs = ZenohSettings(mode="client", connect=(router.endpoint,))
        cfg = build_agent_configs(load_scenario(ROOT / "scenarios/thesis-6.5.yaml"), zenoh=zs)["a1"]
        cfg = dataclasses.replace(cfg, base="turtlebot3-jazzy",
                                  rmw=rmw.RmwSettings(namespace="a1"))
        key = rmw.topic_key(0, "/a1/cmd_vel", rmw.TWIST_STAMPED, rmw.release("jazzy"))
        watcher = Watcher(router.endpoint, key, 0)
        node = AgentNode(cfg, NodeOptions())
        loop = asyncio.new_event_loop()
        try:
            node.open(loop)
            _wait(lambda: len(watcher.alive()) == 2)
            wait_for_matching(node.base.publisher)  # type: ignore[union-attr]
            node.send_command(Cmd(0.1, -0.5, 0.1, 0.0, 12.25))
            _wait(lambda: len(watcher.got()) >= 1)
            node.close()
            _wait(lambda: not watcher.alive())
        finally:
            loop.close()
            watcher.close()
    payload, att = watcher.got()[0]
    msg = STORE.deserialize_cdr(payload, rmw.TWIST_STAMPED)
    assert (msg.twist.linear.x, msg.twist.angular.z) == pytest.approx((0.1, -0.5))
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 250_000_000)
    assert rmw.decode_attachment(att or b"", rmw.POSITIONAL).sequence_number == 1
