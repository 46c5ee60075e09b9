"""Access control (wire.acl) enforced by a Python router (``python -m wire.router --config``)
with user/password authentication: only robot r1's agent can command r1."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from formation.cli import main
from wire import acl, keys
from wire.testing import free_tcp_port, tcp_endpoint, wait_for_tcp_port
from wire.zconf import UsrPwdAuth, ZenohSettings

ROOT = Path(__file__).resolve().parent.parent
P = keys.DEFAULT_PREFIX
ROBOTS = {"r1": "F1", "r2": "F1", "s1": "F2"}
LEADERS = {"F1": "r2", "F2": "s1"}
PAIRS = """\
name: two-pairs
dt: 0.05
duration: 30.0
goal_tolerance: 0.05
robot: {model: single_integrator, max_speed: 0.22, radius: 0.105}
controller: {kp: 2.0, gamma: 1.0, epsilon: 0.05}
formations:
  - name: A
    leader: a1
    robots:
      a1: {start: [0.0, 0.0], goal: [1.5, 0.0]}
      a2: {start: [0.0, 0.5], goal: [1.5, 0.5]}
    edges: [[a1, a2]]
  - name: B
    leader: b1
    robots:
      b1: {start: [1.5, -0.4], goal: [0.0, -0.4]}
      b2: {start: [1.9, -0.4], goal: [0.4, -0.4]}
    edges: [[b1, b2]]
"""
SETTLE_S = 0.5  # [s] for declarations and puts to cross the router
N = 5


class SecureRouter:
    """A router process with the fleet's ACL and a fresh password per user."""

    def __init__(self, folder: Path) -> None:
        self.port = free_tcp_port()
        self.endpoint = tcp_endpoint(self.port)
        self.creds = acl.new_credentials([acl.CAMERA_USER, *ROBOTS])
        acl.write_dictionary(folder / "users.txt", self.creds)
        self.config = folder / "router.json5"
        acl.write_router_config(self.config, acl.router_config(
            [self.endpoint], acl.fleet_acl(ROBOTS, LEADERS), (folder / "users.txt").resolve()))
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "wire.router", "--listen", self.endpoint, "--config",
             str(self.config), "--log-level", "WARNING"], env=env, stdin=subprocess.DEVNULL)
        try:
            wait_for_tcp_port(self.port, timeout_s=15.0)
        except BaseException:
            self.stop()
            raise

    def session(self, auth: UsrPwdAuth | None, timeout_s: float = 5.0) -> zenoh.Session:
        return zenoh.open(ZenohSettings(mode="client", connect=(self.endpoint,),
                                        connect_timeout_s=timeout_s, auth=auth).to_config())

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


@pytest.fixture(scope="module")
def router(tmp_path_factory) -> Iterator[SecureRouter]:
    r = SecureRouter(tmp_path_factory.mktemp("acl"))
    try:
        yield r
    finally:
        r.stop()


class Listener:
    """A subscriber session (the world, logged in as the camera user) recording payloads."""

    def __init__(self, router: SecureRouter, key: str, user: str = acl.CAMERA_USER) -> None:
        self.session = router.session(router.creds[user])
        self.got: list[bytes] = []
        self._lock = threading.Lock()
        self.sub = self.session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.got.append(sample.payload.to_bytes())

    def payloads(self) -> list[bytes]:
        with self._lock:
            return list(self.got)

    def close(self) -> None:
        self.session.close()


def publish(router: SecureRouter, auth: UsrPwdAuth | None, key: str, tag: bytes) -> None:
    with router.session(auth) as s:
        pub = s.declare_publisher(key)
        time.sleep(SETTLE_S)
        for _ in range(N):
            pub.put(tag)
        time.sleep(SETTLE_S)


# --- the generated list ------------------------------------------------------------------------

def test_the_acl_denies_by_default_and_lets_each_robot_publish_only_its_own_keys():
    a = acl.fleet_acl(ROBOTS, LEADERS)
    assert a["enabled"] is True and a["default_permission"] == "deny"
    rules = {r["id"]: r for r in a["rules"]}
    assert rules["r1-publish"]["key_exprs"] == [f"{P}/robot/r1/state", f"{P}/robot/r1/cmd",
                                                f"{P}/robot/r1/diag"]
    assert rules["r1-publish"]["flows"] == ["ingress"] and rules["r1-publish"]["messages"] == ["put"]
    assert f"{P}/formation/F1/ellipse" in rules["r2-publish"]["key_exprs"]  # r2 leads F1
    assert rules[acl.CAMERA_RULE]["key_exprs"] == [f"{P}/robot/*/pose", f"{P}/obstacles",
                                                   f"{P}/camera/frame"]
    subjects = {s["id"]: s["usernames"] for s in a["subjects"]}
    assert subjects == {"camera": ["camera"], "viewer": ["viewer"], "r1": ["r1"], "r2": ["r2"],
                        "s1": ["s1"]}
    policy = {p["id"]: p for p in a["policies"]}
    assert policy["r1-policy"]["subjects"] == ["r1"] and "r1-publish" in policy["r1-policy"]["rules"]
    assert "r2-publish" not in policy["r1-policy"]["rules"]
    zenoh.Config.from_json5(json.dumps({"access_control": a}))  # zenoh accepts the schema


@pytest.mark.parametrize("robots, leaders, name", [
    ({}, {}, "robots"),
    ({"r/1": "F1"}, {}, "robot id"),
    ({"r:1": "F1"}, {}, "robot id"),
    ({"r1": "F1"}, {"F1": "r9"}, "leaders"),
    ({"camera": "F1"}, {}, "camera user"),
])
def test_invalid_fleets_are_refused_naming_the_culprit(robots, leaders, name):
    with pytest.raises(ValueError, match=name):
        acl.fleet_acl(robots, leaders)


def test_credentials_files_are_private_and_read_back(tmp_path):
    auth = acl.new_credentials(["r1"])["r1"]
    acl.write_credentials(tmp_path / "r1.credentials", auth)
    assert (tmp_path / "r1.credentials").stat().st_mode & 0o777 == 0o600
    assert acl.read_credentials(tmp_path / "r1.credentials") == auth
    (tmp_path / "bad").write_text("nocolon\n")
    with pytest.raises(ValueError, match="user:password"):
        acl.read_credentials(tmp_path / "bad")


# --- enforced by the router --------------------------------------------------------------------

def test_only_r1s_agent_can_command_r1(router):
    key = keys.cmd_key(P, "r1")
    world = Listener(router, key)
    try:
        publish(router, router.creds["r2"], key, b"r2")  # another robot's agent
        publish(router, router.creds[acl.CAMERA_USER], key, b"camera")  # the camera user
        publish(router, router.creds["r1"], key, b"r1")  # the legitimate agent
        time.sleep(SETTLE_S)
        assert world.payloads() == [b"r1"] * N
    finally:
        world.close()


def test_a_robot_cannot_forge_another_robots_state_nor_a_pose(router):
    state = Listener(router, keys.state_key(P, "r1"), user="r2")
    pose = Listener(router, keys.pose_key(P, "r1"), user="r1")
    try:
        publish(router, router.creds["s1"], keys.state_key(P, "r1"), b"forged")
        publish(router, router.creds["r1"], keys.pose_key(P, "r1"), b"forged")
        publish(router, router.creds["r1"], keys.state_key(P, "r1"), b"own")
        publish(router, router.creds[acl.CAMERA_USER], keys.pose_key(P, "r1"), b"camera")
        time.sleep(SETTLE_S)
        assert state.payloads() == [b"own"] * N
        assert pose.payloads() == [b"camera"] * N
    finally:
        state.close()
        pose.close()


def test_only_a_leader_publishes_its_formations_ellipse(router):
    key = keys.ellipse_key(P, "F1")
    other_leader = Listener(router, key, user="s1")
    try:
        publish(router, router.creds["r1"], key, b"member")
        publish(router, router.creds["r2"], key, b"leader")
        time.sleep(SETTLE_S)
        assert other_leader.payloads() == [b"leader"] * N
    finally:
        other_leader.close()


@pytest.mark.parametrize("auth", [None, UsrPwdAuth("r1", "wrong"), UsrPwdAuth("intruder", "x")],
                         ids=["anonymous", "wrong-password", "unknown-user"])
def test_a_client_without_valid_credentials_cannot_even_connect(router, auth):
    with pytest.raises(zenoh.ZError):
        router.session(auth, timeout_s=1.0)


def test_formation_run_secure_logs_every_process_in_and_equals_the_open_run(tmp_path):
    scenario = tmp_path / "pair.yaml"
    scenario.write_text(PAIRS, encoding="utf-8")
    assert main(["run", str(scenario), "--out", str(tmp_path / "sim"), "--quiet",
                 "--no-plots", "--secure"]) == 0
    s = json.loads((tmp_path / "sim" / "summary.json").read_text())
    assert s["secure"]["auth"] == "usrpwd"
    assert s["all_reached"] is True and s["collisions"] == 0
    assert s["agents"]["stale"] == 0 and s["world"]["missing_cmds"] == 0
    secure = tmp_path / "sim" / "secure"
    assert secure.stat().st_mode & 0o777 == 0o700
    assert all(p.stat().st_mode & 0o777 == 0o600 for p in secure.glob("*.credentials"))
    assert main(["sim", str(scenario), "--out", str(tmp_path / "ref"), "--quiet", "--no-plots"]) == 0
    assert (tmp_path / "sim" / "robots.csv").read_text() == (tmp_path / "ref" / "robots.csv").read_text()


def test_python_m_wire_acl_writes_a_fleets_router_files_zenoh_accepts(tmp_path, capsys):
    assert acl.main([str(ROOT / "scenarios" / "thesis-5.2.2.yaml"), "--out", str(tmp_path / "f")]) == 0
    folder = tmp_path / "f"
    conf = zenoh.Config.from_file(str(folder / "router.json5"))
    assert json.loads(conf.get_json("access_control/default_permission")) == "deny"
    users = (folder / "users.txt").read_text().splitlines()
    assert sorted(u.split(":")[0] for u in users) == sorted(
        ["camera", "viewer", "r1", "r2", "r3", "r4", "s1", "s2", "s3", "s4"])
    assert acl.read_credentials(folder / "r1.credentials").user == "r1"
    assert acl.main([str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "g")]) == 2
