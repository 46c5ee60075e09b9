"""``formation deploy`` for robots on rmw_zenoh (inventory ``transport: rmw_zenoh``): the
inventory keys, the files each robot gets, and, over real Zenoh on loopback, the fleet router's
access control as deploy writes it with a stand-in for the robot's ``rmw_zenohd`` linked to it:
the agent's commands reach the robot's subscriber with their attachment, the robot's tokens reach
the fleet, and ``--status`` finds the base's subscription token."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
import zenoh

from agent.base import decode_cmd, make_base
from agent.config import config_from_dict
from deploy import rmw_status
from deploy.deployer import BRIDGE_FILE, CONFIG_FILE, ZENOH_FILE, make_plan
from deploy.inventory import InventoryError, load_inventory
from deploy.rmw_zenoh import ROUTER_FILE, SESSION_FILE, USERS_FILE
from runtime.testing import free_tcp_port, tcp_endpoint, wait_for_tcp_port
from scenario import load_scenario
from wire import rmw_zenoh as rmw

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios/thesis-6.5.yaml"  # robots a1, a2, b1, b2


def inventory(router: str = "tcp/192.168.0.10:7447", **a1: object) -> dict:
    return {
        "base": "turtlebot3-jazzy",
        "zenoh": {"router": router, "mode": "client"},
        "defaults": {"user": "ubuntu", "key": "id_ed25519"},
        "robots": [{"id": "a1", "host": "10.0.0.1", "transport": "rmw_zenoh",
                    "ros_namespace": "a1", **a1},
                   {"id": "a2", "host": "10.0.0.2"}, {"id": "b1", "host": "10.0.0.3"},
                   {"id": "b2", "host": "10.0.0.4"}],
    }


def write(tmp_path: Path, data: dict) -> Path:
    (tmp_path / "id_ed25519").write_text("key\n")
    p = tmp_path / "inv.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


def test_inventory_keys_and_defaults(tmp_path):
    inv = load_inventory(write(tmp_path, inventory(ros_domain=4, cmd_type="Twist",
                                                   rmw_zenoh_release="jazzy-0.2.3")))
    a1, a2 = inv.robot("a1"), inv.robot("a2")
    assert a1.rmw == rmw.RmwSettings(release="jazzy-0.2.3", cmd_type="Twist", namespace="a1",
                                     domain=4)
    assert a2.rmw is None  # transport bridge, the default
    plain = load_inventory(write(tmp_path, inventory())).robot("a1").rmw
    assert plain == rmw.RmwSettings(namespace="a1")


@pytest.mark.parametrize("change,message", [
    ({"transport": "dds"}, "robots[0] (a1).transport: 'dds' is not one of bridge, rmw_zenoh"),
    ({"cmd_type": "Twist3"}, "robots[0] (a1).cmd_type"),
    ({"ros_domain": 300}, "robots[0] (a1).ros_domain: ROS domain id must be an integer"),
    ({"ros_domain": "0"}, "robots[0] (a1).ros_domain"),
    ({"ros_namespace": "a-1"}, "robots[0] (a1).ros_namespace"),
    ({"rmw_zenoh_release": "iron"}, "robots[0] (a1).rmw_zenoh_release: 'iron' is not one of"),
    ({"transport": "bridge"}, "robots[0] (a1).ros_namespace: only for transport rmw_zenoh"),
])
def test_invalid_rmw_keys_name_the_culprit(tmp_path, change, message):
    with pytest.raises(InventoryError) as err:
        load_inventory(write(tmp_path, inventory(**change)))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_rmw_zenoh_needs_a_ros_base(tmp_path):
    data = inventory()
    data["base"] = "world"
    with pytest.raises(InventoryError, match=r"\(a1\).transport: rmw_zenoh needs base"):
        load_inventory(write(tmp_path, data))


def test_plan_gives_the_rmw_robot_its_router_file_and_no_bridge(tmp_path):
    inv = load_inventory(write(tmp_path, inventory()))
    plan = make_plan(inv, load_scenario(SCENARIO), wheel="w.whl", write_secrets=False)
    files = {rp.robot.id: rp.files for rp in plan.robots}
    assert ROUTER_FILE in files["a1"] and BRIDGE_FILE not in files["a1"]
    modes = {rp.robot.id: rp.modes for rp in plan.robots}["a1"]
    # client mode: access control by default, so the robot's own user logs in everywhere
    assert {modes[n] for n in (ROUTER_FILE, SESSION_FILE, USERS_FILE)} == {0o600}
    user, password = files["a1"][USERS_FILE].decode().strip().split(":")
    session = json.loads(files["a1"][SESSION_FILE].decode().split("\n", 2)[2])
    assert session["transport"]["auth"]["usrpwd"] == {
        "user": "a1", "password": password,
        "dictionary_file": "/home/ubuntu/formation-cbf/rmw_zenoh_users.txt"} and user == "a1"
    assert BRIDGE_FILE in files["a2"] and ROUTER_FILE not in files["a2"]
    router = json.loads(files["a1"][ROUTER_FILE].decode().split("\n", 2)[2])
    assert router["mode"] == "router" and router["connect"]["endpoints"] == [inv.zenoh.router]
    cfg = config_from_dict(yaml.safe_load(files["a1"][CONFIG_FILE]))
    assert cfg.rmw == rmw.RmwSettings(namespace="a1") and cfg.base == "turtlebot3-jazzy"
    assert "rmw" not in yaml.safe_load(files["a2"][CONFIG_FILE])  # bridge robots: as before


def _wait(predicate, timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


class RobotStandIn:
    """The robot: its rmw_zenohd (a router session with deploy's rmw_zenohd.json5, listening
    on a free loopback port) and a ROS node on it with an rmw_zenoh subscription to cmd_vel."""

    def __init__(self, files: dict[str, bytes], folder: Path, key: str, sub_token: str,
                 node_token: str) -> None:
        conf = zenoh.Config.from_json5(files[ROUTER_FILE].decode())
        port = free_tcp_port()  # not 7447: this machine may run a real one
        conf.insert_json5("listen/endpoints", json.dumps([tcp_endpoint(port)]))
        if USERS_FILE in files:  # the install dir on the robot: here, the test's folder
            (folder / USERS_FILE).write_bytes(files[USERS_FILE])
            conf.insert_json5("transport/auth/usrpwd/dictionary_file",
                              json.dumps(str(folder / USERS_FILE)))
        self.rmw_zenohd = zenoh.open(conf)
        node_conf = zenoh.Config.from_json5(files[SESSION_FILE].decode())
        node_conf.insert_json5("connect/endpoints", json.dumps([tcp_endpoint(port)]))
        if USERS_FILE in files:
            node_conf.insert_json5("transport/auth/usrpwd/dictionary_file",
                                   json.dumps(str(folder / USERS_FILE)))
        self.node = zenoh.open(node_conf)
        self.got: list[tuple[bytes, bytes | None]] = []
        self._lock = threading.Lock()
        self.sub = self.node.declare_subscriber(key, self._on)
        self.tokens = [self.node.liveliness().declare_token(t) for t in (node_token, sub_token)]

    def _on(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        with self._lock:
            self.got.append((sample.payload.to_bytes(), None if att is None else att.to_bytes()))

    def samples(self) -> list[tuple[bytes, bytes | None]]:
        with self._lock:
            return list(self.got)

    def close(self) -> None:
        self.node.close()
        self.rmw_zenohd.close()


def test_deployed_acl_lets_the_agent_drive_the_rmw_robot_and_status_sees_its_base(tmp_path):
    port = free_tcp_port()
    data = inventory(router=tcp_endpoint(port))
    data["zenoh"]["access_control"] = True
    inv = load_inventory(write(tmp_path, data))
    plan = make_plan(inv, load_scenario(SCENARIO), wheel="w.whl")
    files = {rp.robot.id: rp.files for rp in plan.robots}["a1"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    router = subprocess.Popen(
        [sys.executable, "-m", "runtime.router", "--listen", tcp_endpoint(port), "--config",
         str(inv.zenoh.secrets / "router.json5"), "--log-level", "WARNING"],
        env=env, stdin=subprocess.DEVNULL)
    cfg = config_from_dict(yaml.safe_load(files[CONFIG_FILE]))
    rel, type_name = rmw.resolve(cfg.rmw, "jazzy")
    key = rmw.topic_key(0, "/a1/cmd_vel", type_name, rel)
    sub = rmw.Entity(0, "1234abcd", 0, 3, rmw.SUBSCRIPTION, "/", "/a1", "turtlebot3_node",
                     "/a1/cmd_vel", rmw.dds_type_name(type_name), rmw.type_hash(type_name, rel),
                     "1:2:1,10:,:,:,,")
    node = rmw.Entity(0, "1234abcd", 0, 0, rmw.NODE, "/", "/a1", "turtlebot3_node")
    robot = agent = viewer = None
    try:
        wait_for_tcp_port(port, timeout_s=15.0)
        assert rmw_status.status_lines(inv, rmw_status.viewer_file(inv)) == [
            f"{'a1':10s} rmw_zenoh base: NO cmd_vel subscriber (is the robot's bringup running?)"]
        robot = RobotStandIn(files, tmp_path, key, rmw.token(sub), rmw.token(node))
        viewer = zenoh.open(zenoh.Config.from_file(str(rmw_status.viewer_file(inv))))
        _wait(lambda: any(True for r in viewer.liveliness().get(rmw.token(sub), timeout=1.0)
                          if r.ok is not None))
        assert rmw_status.status_lines(inv, rmw_status.viewer_file(inv)) == [
            f"{'a1':10s} rmw_zenoh base: cmd_vel subscriber present (/a1/turtlebot3_node)"]
        # the agent, as deploy configured it (its own user, from zenoh.json5)
        agent = zenoh.open(zenoh.Config.from_json5(files[ZENOH_FILE].decode()))
        base = make_base(cfg, agent)
        _wait(lambda: bool(base.publisher.matching_status.matching))
        base.send(0.1, 0.2, 5.0)
        _wait(lambda: len(robot.samples()) >= 1)
        tokens = [str(r.ok.key_expr) for r in viewer.liveliness().get(
            rmw.liveliness_selector(0), timeout=2.0) if r.ok is not None]
        assert base.spec.publisher_token in tokens and rmw.token(sub) in tokens
    finally:
        for s in (agent, viewer):
            if s is not None:
                s.close()
        if robot is not None:
            robot.close()
        router.terminate()
        router.wait(10)
    payload, att = robot.samples()[0]
    got = rmw.decode_attachment(att or b"", rel.attachment)
    assert got.sequence_number == 1 and got.gid == base.spec.gid
    assert decode_cmd(type_name, payload) == pytest.approx((0.1, 0.2, 5.0))


def test_acl_rights_for_rmw_robots_only():
    from wire import acl
    fleet = {"a1": "F1", "a2": "F1"}
    plain = acl.fleet_acl(fleet, {"F1": "a1"})
    assert acl.add_rmw_zenoh(acl.fleet_acl(fleet, {"F1": "a1"}), {}) == plain  # bridge fleets
    got = acl.add_rmw_zenoh(acl.fleet_acl(fleet, {"F1": "a1"}),
                            {"a1": rmw.RmwSettings(namespace="a1", domain=3)})
    rules = {r["id"]: r for r in got["rules"]}
    policies = {p["id"]: p["rules"] for p in got["policies"]}
    assert rules["a1-rmw-tokens"]["key_exprs"] == ["@ros2_lv/3/*/*/*/*/*/%a1/**"]
    assert "a1-rmw-tokens" in policies["a1-policy"]
    assert not any("rmw" in r for r in policies["a2-policy"])  # a2 keeps the bridge's rights
    assert rules["viewer-rmw-read"]["key_exprs"] == ["3/**"]
