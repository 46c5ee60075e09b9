"""Access control (wire.acl) enforced by a Python router (``python -m runtime.router --config``)
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

from deploy import router_files
from formation.cli import main
from runtime.testing import free_tcp_port, tcp_endpoint, wait_for_tcp_port
from wire import acl, keys, zconf
from wire.frames import stats_key
from wire.zconf import UsrPwdAuth, ZenohSettings

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
P = keys.DEFAULT_PREFIX
ROBOTS = {"r1": "F1", "r2": "F1", "r3": "F1", "s1": "F2"}
LEADERS = {"F1": "r2", "F2": "s1"}
SUCCESSORS = {"F1": "r3"}  # r3 takes over F1 if r2 dies; r1 never leads
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
        self.creds = acl.new_credentials([acl.CAMERA_USER, acl.MANAGER_USER, acl.VIEWER_USER,
                                          *ROBOTS])
        acl.write_dictionary(folder / "users.txt", self.creds)
        self.config = folder / "router.json5"
        acl.write_router_config(self.config, acl.router_config(
            [self.endpoint], acl.fleet_acl(ROBOTS, LEADERS, successors=SUCCESSORS),
            (folder / "users.txt").resolve()))
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "runtime.router", "--listen", self.endpoint, "--config",
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
                                                f"{P}/robot/r1/diag", "r1/cmd_vel", "r1/odom"]
    assert rules["r1-publish"]["flows"] == ["ingress"] and rules["r1-publish"]["messages"] == ["put"]
    assert f"{P}/formation/F1/ellipse" in rules["r2-lead"]["key_exprs"]  # r2 leads F1
    assert "r1-lead" not in rules
    assert rules[acl.CAMERA_RULE]["key_exprs"] == [f"{P}/robot/*/pose", f"{P}/robot/*/odom",
                                                   f"{P}/obstacles", f"{P}/camera/frame"]
    subjects = {s["id"]: s["usernames"] for s in a["subjects"]}
    assert subjects == {u: [u] for u in ("camera", "manager", "viewer", *ROBOTS)}
    policy = {p["id"]: p for p in a["policies"]}
    assert policy["r1-policy"]["subjects"] == ["r1"] and "r1-publish" in policy["r1-policy"]["rules"]
    assert "r2-publish" not in policy["r1-policy"]["rules"]
    zenoh.Config.from_json5(json.dumps({"access_control": a}))  # zenoh accepts the schema


@pytest.mark.parametrize("robots, leaders, name", [
    ({}, {}, "robots"),
    ({"r/1": "F1"}, {}, "robot id"),
    ({"r:1": "F1"}, {}, "robot id"),
    ({"r1": "F1"}, {"F1": "r9"}, "leaders"),
    ({"camera": "F1"}, {}, "service user"),
    ({"viewer": "F1"}, {}, "service user"),
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


def test_python_m_deploy_router_files_writes_a_fleets_router_files_zenoh_accepts(tmp_path, capsys):
    scenario = str(ROOT / "scenarios" / "thesis-5.2.2.yaml")
    assert router_files.main([scenario, "--out", str(tmp_path / "f")]) == 0
    folder = tmp_path / "f"
    conf = zenoh.Config.from_file(str(folder / "router.json5"))
    assert json.loads(conf.get_json("access_control/default_permission")) == "deny"
    users = (folder / "users.txt").read_text().splitlines()
    assert sorted(u.split(":")[0] for u in users) == sorted(
        ["camera", "manager", "viewer", "r1", "r2", "r3", "r4", "s1", "s2", "s3", "s4"])
    assert acl.read_credentials(folder / "r1.credentials").user == "r1"
    assert router_files.main([str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "g")]) == 2


def test_a_robot_drives_its_own_base_and_no_other(router):
    """The base's bridge logs in as its robot: it subscribes to the robot's cmd_vel key."""
    bridge = Listener(router, "r1/cmd_vel", user="r1")
    try:
        publish(router, router.creds["r2"], "r1/cmd_vel", b"r2")
        publish(router, router.creds["r1"], "r1/cmd_vel", b"r1")
        time.sleep(SETTLE_S)
        assert bridge.payloads() == [b"r1"] * N
    finally:
        bridge.close()


def test_a_robots_base_puts_its_odometry_and_only_that_robots_agent_hears_it(router):
    """The bridge, logged in as r1, puts the base's odom topic (r1/odom, where a fused agent
    listens); another robot's user can neither put there nor hear it."""
    agent = Listener(router, acl.bridge_odom_key("r1/cmd_vel"), user="r1")
    other = Listener(router, "r1/odom", user="r2")
    try:
        publish(router, router.creds["r2"], "r1/odom", b"r2")
        publish(router, router.creds["r1"], "r1/odom", b"r1")
        time.sleep(SETTLE_S)
        assert agent.payloads() == [b"r1"] * N
        assert other.payloads() == []
    finally:
        agent.close()
        other.close()


def test_a_robot_on_rmw_zenoh_may_put_and_hear_its_own_odom_data_key():
    from wire import rmw_zenoh

    settings = rmw_zenoh.RmwSettings(namespace="/r1", domain=0)
    got = acl.add_rmw_zenoh(acl.fleet_acl({"r1": "F1", "r2": "F1"}, {"F1": "r1"}),
                            {"r1": settings})
    rules = {r["id"]: r for r in got["rules"]}
    policy = next(p for p in got["policies"] if p["subjects"] == ["r1"])
    odom = {k for rid in policy["rules"] if "odom" in rid for k in rules[rid]["key_exprs"]}
    assert rmw_zenoh.odom_data_key(settings, "jazzy") in odom
    assert rmw_zenoh.odom_data_key(settings, "humble") in odom
    r2 = next(p for p in got["policies"] if p["subjects"] == ["r2"])
    assert not any(rmw_zenoh.odom_data_key(settings, "jazzy") in rules[rid]["key_exprs"]
                   for rid in r2["rules"])


def test_the_successor_may_lead_and_a_plain_member_may_not(router):
    key = keys.ellipse_key(P, "F1")
    other_leader = Listener(router, key, user="s1")
    try:
        publish(router, router.creds["r1"], key, b"member")
        publish(router, router.creds["r3"], key, b"successor")
        time.sleep(SETTLE_S)
        assert other_leader.payloads() == [b"successor"] * N
    finally:
        other_leader.close()


def test_the_manager_sends_goals_and_the_viewer_only_reads(router):
    goal = f"{P}/formation/F1/goal"
    leader = Listener(router, goal, user="r2")
    viewer = Listener(router, keys.state_key(P, "r1"), user=acl.VIEWER_USER)
    try:
        publish(router, router.creds[acl.VIEWER_USER], goal, b"viewer")
        publish(router, router.creds[acl.MANAGER_USER], goal, b"manager")
        publish(router, router.creds["r1"], keys.state_key(P, "r1"), b"state")
        publish(router, router.creds[acl.VIEWER_USER], keys.state_key(P, "r1"), b"forged")
        time.sleep(SETTLE_S)
        assert leader.payloads() == [b"manager"] * N
        assert viewer.payloads() == [b"state"] * N
    finally:
        leader.close()
        viewer.close()


def test_the_successor_sees_the_leaders_liveliness_token_go(router):
    token_key = f"{P}/formation/F1/leader"
    events: list[str] = []
    watcher = router.session(router.creds["r3"])
    leader = router.session(router.creds["r2"])
    try:
        token = leader.liveliness().declare_token(token_key)
        time.sleep(SETTLE_S)
        watcher.liveliness().declare_subscriber(
            token_key, lambda s: events.append(str(s.kind)), history=True)
        time.sleep(SETTLE_S)
        assert events == ["SampleKind.PUT"]
        token.undeclare()
        time.sleep(SETTLE_S)
        assert events == ["SampleKind.PUT", "SampleKind.DELETE"]
        forged = router.session(router.creds["r1"])  # a member may not pose as the leader
        try:
            forged.liveliness().declare_token(token_key)
            time.sleep(SETTLE_S)
            assert events == ["SampleKind.PUT", "SampleKind.DELETE"]
        finally:
            forged.close()
    finally:
        leader.close()
        watcher.close()


def test_refused_credentials_are_reported_as_such(router, tmp_path):
    path = tmp_path / "manager.json5"
    acl.write_client_file(path, UsrPwdAuth(acl.MANAGER_USER, "wrong"), [router.endpoint])
    found = zconf.read_auth_file(path)
    assert found.connect == (router.endpoint,) and found.auth.user == acl.MANAGER_USER
    settings = ZenohSettings(mode="client", connect=found.connect, connect_timeout_s=1.0,
                             auth=found.auth)
    with pytest.raises(ConnectionError, match="refused the credentials of user 'manager'"):
        zconf.open_session(settings, "status")
    acl.write_client_file(path, router.creds[acl.MANAGER_USER], [router.endpoint])
    with zconf.open_session(ZenohSettings(mode="client", connect=(router.endpoint,),
                                          auth=zconf.read_auth_file(path).auth)):
        pass


def test_python_m_deploy_router_files_lets_each_robot_drive_its_base(tmp_path):
    """The router files ``python -m deploy.router_files`` writes: r1's agent puts on r1/cmd_vel and the
    bridge (logged in as r1) gets every put (it got 0 of 10 before)."""
    port = free_tcp_port()
    folder = tmp_path / "f"
    assert router_files.main([str(ROOT / "scenarios" / "thesis-5.2.2.yaml"), "--out", str(folder),
                     "--listen", tcp_endpoint(port)]) == 0
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "runtime.router", "--listen", tcp_endpoint(port),
                             "--config", str(folder / "router.json5"), "--log-level", "WARNING"],
                            env=env, stdin=subprocess.DEVNULL)
    try:
        wait_for_tcp_port(port, timeout_s=15.0)
        r1 = acl.read_credentials(folder / "r1.credentials")
        conf = ZenohSettings(mode="client", connect=(tcp_endpoint(port),), auth=r1).to_config()
        got: list[bytes] = []
        with zenoh.open(conf) as bridge, zenoh.open(conf) as agent:
            bridge.declare_subscriber("r1/cmd_vel", lambda s: got.append(s.payload.to_bytes()))
            pub = agent.declare_publisher("r1/cmd_vel")
            time.sleep(SETTLE_S)
            for _ in range(10):
                pub.put(b"twist")
            time.sleep(SETTLE_S)
        assert got == [b"twist"] * 10
    finally:
        proc.terminate()
        proc.wait(10)


def test_an_agent_with_refused_credentials_says_so(router, tmp_path):
    import asyncio

    from agent.config import ZenohSettings as AgentZenoh
    from agent.config import build_agent_configs
    from agent.node import AgentNode, NodeOptions
    from scenario import load_scenario

    path = tmp_path / "pairs.yaml"
    path.write_text(PAIRS, encoding="utf-8")
    cfg = build_agent_configs(load_scenario(path), zenoh=AgentZenoh(
        mode="client", connect=(router.endpoint,)))["a1"]
    node = AgentNode(cfg, NodeOptions(connect_timeout=1.0, auth=UsrPwdAuth("a1", "wrong")))
    loop = asyncio.new_event_loop()
    try:
        with pytest.raises(ConnectionError, match="refused the credentials of user 'a1'"):
            node.open(loop)
    finally:
        loop.close()


def test_a_client_command_takes_auth_file_and_says_when_it_is_refused(router, tmp_path):
    """``--auth FILE`` (wire.zconf.add_zenoh_args), here on ``python -m simulator.world_cli``."""
    bad = tmp_path / "stale-manager.json5"
    acl.write_client_file(bad, UsrPwdAuth(acl.MANAGER_USER, "from-another-run"), [router.endpoint])
    proc = subprocess.run(
        [sys.executable, "-m", "simulator.world_cli", str(ROOT / "tests" / "scenarios" / "two-small.yaml"),
         "--auth", str(bad)], env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True,
        text=True, timeout=60)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        f"world: the router at {router.endpoint} refused the credentials of user 'manager' "
        "(wrong user or password, or not this router's credentials)"]


def _ask(router: SecureRouter, user: str, key: str) -> list[bytes]:
    with router.session(router.creds[user]) as s:
        return [r.ok.payload.to_bytes() for r in s.get(key, timeout=1.0) if r.ok is not None]


def test_the_manager_and_viewer_read_the_cameras_counters_and_no_robot_answers_for_it(router):
    key = stats_key(P)
    camera = router.session(router.creds[acl.CAMERA_USER])
    forger = router.session(router.creds["r1"])
    try:
        camera.declare_queryable(key, lambda q: q.reply(key, b'{"frames": 3}'))
        forger.declare_queryable(key, lambda q: q.reply(key, b'{"frames": 999}'))
        time.sleep(SETTLE_S)
        assert _ask(router, acl.MANAGER_USER, key) == [b'{"frames": 3}']
        assert _ask(router, acl.VIEWER_USER, key) == [b'{"frames": 3}']
        assert _ask(router, "r2", key) == []  # a robot has no business asking
    finally:
        forger.close()
        camera.close()
