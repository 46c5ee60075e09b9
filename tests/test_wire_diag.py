"""The ``diag`` payload: round trip, defensive decoding, and its key outside the control classes."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from wire import keys
from wire.diag import Diag, DiagPublisher, decode_diag, diag_key, encode_diag
from wire.payloads import DecodeError


def sample(**kw) -> Diag:
    values = dict(formation="A", status="relaxed", stamp=12.5, slack=0.01, h_formation=0.02,
                  h_obstacle=math.inf, h_formations=1.5, goal_x=2.0, goal_y=-1.0, ticks=250,
                  stale=3, relaxed=7, fallback=0, dropped=1)
    values.update(kw)
    return Diag(**values)


def test_a_diag_survives_encoding_with_infinite_barriers_kept():
    d = sample()
    back = decode_diag(encode_diag(d))
    assert back == d and back.h_obstacle == math.inf


@given(st.binary(max_size=200))
def test_arbitrary_bytes_decode_to_a_diag_or_raise_decode_error(data):
    try:
        decode_diag(data)
    except DecodeError:
        pass


def test_truncated_or_trailing_or_non_finite_counters_are_rejected():
    raw = encode_diag(sample())
    for bad in (raw[:-1], raw + b"\0", b"", bytes([9]) + raw[1:]):
        with pytest.raises(DecodeError):
            decode_diag(bad)
    with pytest.raises(ValueError):
        sample(stamp=math.nan)
    with pytest.raises(ValueError):
        sample(status="two words")


class FakePublisher:
    def __init__(self) -> None:
        self.puts: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.puts.append(payload)


class FakeSession:
    def __init__(self) -> None:
        self.declared: dict[str, FakePublisher] = {}

    def declare_publisher(self, key: str) -> FakePublisher:
        return self.declared.setdefault(key, FakePublisher())


class FakeConfig:
    def __init__(self, formation: str, goal: tuple[float, float]) -> None:
        self.formation = formation
        self.goal = goal


class FakeNode:
    """The agent's parts a diagnostics put reads."""

    def __init__(self, cfg: FakeConfig) -> None:
        self.cfg = cfg
        self.stale = 0
        self.ticks = 1
        self.status_counts = {"relaxed": 0, "fallback": 0}
        self.dropped_malformed = 0
        self.last_stamp = 1.0


def test_a_robot_that_regroups_names_its_new_formation_and_goal_in_its_diag():
    session = FakeSession()
    pub = DiagPublisher(session, "warehouse", "r1", period=0.0)
    node = FakeNode(FakeConfig("r1", (1.0, 2.0)))  # a fleet robot: a formation of one
    pub.tick(node, None)
    node.cfg = FakeConfig("team-7", (5.0, -3.0))  # regrouped into a team
    pub.tick(node, None)
    node.cfg = FakeConfig("r1", (0.5, 0.5))  # back to a formation of one
    pub.tick(node, None)
    sent = [decode_diag(p) for p in session.declared["warehouse/robot/r1/diag"].puts]
    assert [(d.formation, d.goal_x, d.goal_y) for d in sent] == [
        ("r1", 1.0, 2.0), ("team-7", 5.0, -3.0), ("r1", 0.5, 0.5)]


def test_the_diag_key_is_counted_as_other_not_as_control_traffic():
    key = diag_key("warehouse", "a1")
    assert key == "warehouse/robot/a1/diag"
    assert keys.key_class("warehouse", key) == keys.OTHER


@pytest.mark.integration
def test_with_access_control_a_robot_publishes_its_own_diag_and_the_viewer_only_reads(tmp_path):
    import os
    import subprocess
    import sys
    import threading
    import time
    from pathlib import Path

    import zenoh

    from runtime.testing import free_tcp_port, tcp_endpoint, wait_for_tcp_port
    from wire import acl
    from wire.zconf import ZenohSettings

    root = Path(__file__).resolve().parent.parent
    port = free_tcp_port()
    ep = tcp_endpoint(port)
    creds = acl.new_credentials([acl.CAMERA_USER, acl.VIEWER_USER, "r1", "r2"])
    acl.write_dictionary(tmp_path / "users.txt", creds)
    acl.write_router_config(tmp_path / "router.json5", acl.router_config(
        [ep], acl.fleet_acl({"r1": "F", "r2": "F"}, {"F": "r1"}), (tmp_path / "users.txt").resolve()))
    router = subprocess.Popen([sys.executable, "-m", "runtime.router", "--listen", ep, "--config",
                               str(tmp_path / "router.json5"), "--log-level", "ERROR"],
                              env=dict(os.environ, PYTHONPATH=str(root)), stdin=subprocess.DEVNULL)

    def session(user: str) -> zenoh.Session:
        return zenoh.open(ZenohSettings(mode="client", connect=(ep,), connect_timeout_s=5.0,
                                        auth=creds[user]).to_config())

    got: dict[str, list[bytes]] = {"viewer": [], "camera": []}
    lock = threading.Lock()

    def keep(who: str):
        def on(sample: zenoh.Sample) -> None:
            with lock:
                got[who].append(sample.payload.to_bytes())
        return on

    try:
        wait_for_tcp_port(port, timeout_s=15.0)
        with session(acl.VIEWER_USER) as viewer, session(acl.CAMERA_USER) as world, \
                session("r1") as r1, session("r2") as r2:
            viewer.declare_subscriber("warehouse/robot/*/diag", keep("viewer"))
            world.declare_subscriber("warehouse/robot/*/cmd", keep("camera"))
            pubs = [(r1.declare_publisher(diag_key("warehouse", "r1")), b"own"),
                    (r2.declare_publisher(diag_key("warehouse", "r1")), b"forged"),
                    (viewer.declare_publisher(keys.cmd_key("warehouse", "r1")), b"viewer-cmd")]
            time.sleep(0.5)
            for pub, tag in pubs:
                for _ in range(3):
                    pub.put(tag)
            time.sleep(0.5)
        with lock:
            assert got["viewer"] == [b"own"] * 3  # r2 may not publish r1's diagnostics
            assert got["camera"] == []  # the viewer commands nothing
    finally:
        router.terminate()
        router.wait(timeout=10)
