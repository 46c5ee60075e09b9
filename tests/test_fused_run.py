"""``controller.localisation: fused`` over Zenoh: the world publishes every robot's wheel
odometry, each agent runs its own filter on it and the camera's poses (agent.odom_in).

* a lock-step ``formation run`` through a blind patch (alone, two formations crossing inside
  one, with a misread marker, a camera outage in a crossing) writes the robots.csv ``formation
  sim`` writes, byte for byte: the margins against another formation hold the radius its leader
  puts on its ellipse, as in process (the world publishes a frame's poses
  before its odometry, on one session, and the agent takes both on the Zenoh thread that
  received them, in that order);
* an agent over a real router drops and counts malformed odometry, drives on its estimate and
  puts its confidence radius into its ``state``;
* in real time with the camera process, the formation crosses the patch (behaviour, not timing).
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from agent.config import ZenohSettings, build_agent_configs
from agent.node import AgentNode, NodeOptions
from formation.cli import main
from leader.ellipse import Ellipse
from leader.role import ellipse_to_msg
from runtime.testing import RouterProcess, wait_for_matching
from scenario import load_scenario
from tests.same_files import assert_same
from wire import keys, zconf
from wire.odom import Odom, encode_odom, odom_key
from wire.payloads import ObstacleMsg, Obstacles, Others, Pose, State, decode_cmd, decode_state, encode

pytestmark = pytest.mark.integration  # starts processes and Zenoh sessions

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = Path(__file__).parent / "scenarios"
P = keys.DEFAULT_PREFIX
TIMEOUT_S = 10.0


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


@pytest.mark.parametrize("stem", ["blind-aisle", "blind-aisle-unicycle", "blind-misread",
                                  "blind-crossing", "blind-crossing-unicycle", "blind-outage"])
def test_a_lock_step_run_through_a_blind_patch_writes_what_formation_sim_writes(tmp_path, stem):
    scenario = SCENARIOS / f"{stem}.yaml"
    sim, run = tmp_path / "sim", tmp_path / "run"
    assert main(["sim", str(scenario), "--out", str(sim), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(scenario), "--out", str(run), "--quiet", "--no-plots",
                 "--insecure"]) == 0
    got = _summary(run)
    assert got["mode"] == "multiprocess" and got["all_reached"] and got["collisions"] == 0
    loc = got["localisation"]
    assert loc["fused"] > 0 and loc["over_limit_ticks"] == 0
    if stem == "blind-misread":  # another robot's pose, refused by the gate
        assert loc["rejected"] > 0
    elif stem == "blind-outage":  # the camera off for 5 s in a crossing
        assert loc["blind_s"] > 4.5 and loc["rejected"] == 0
    else:  # the patch crossed unseen
        assert loc["blind_s"] > 10.0 and loc["rejected"] == 0
    header = (run / "robots.csv").read_text().splitlines()[0]
    assert header.endswith("est_x,est_y,sigma_m")
    assert_same(sim / "robots.csv", run / "robots.csv")


# --- one agent over a real router ---------------------------------------------------------------


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as proc:
        yield proc
    assert proc.returncode == 0


class Peer:
    """The test's session: the world's frames and odometry, and r1's neighbours and leader."""

    def __init__(self, endpoint: str) -> None:
        conf = zconf.make_config("client", connect=[endpoint], connect_timeout_s=TIMEOUT_S)
        self.session = zenoh.open(conf)
        self.pubs: dict[str, zenoh.Publisher] = {}
        self.cmds: list[float] = []
        self.states: list[State] = []
        self.subs = [
            self.session.declare_subscriber(keys.cmd_key(P, "r1"), lambda s: self.cmds.append(
                decode_cmd(s.payload.to_bytes()).stamp)),
            self.session.declare_subscriber(keys.state_key(P, "r1"), lambda s: self.states.append(
                decode_state(s.payload.to_bytes())))]

    def put(self, key: str, payload: bytes) -> None:
        if key not in self.pubs:
            self.pubs[key] = self.session.declare_publisher(key)
        self.pubs[key].put(payload)

    def wait_subscribed(self, key: str) -> None:
        if key not in self.pubs:
            self.pubs[key] = self.session.declare_publisher(key)
        wait_for_matching(self.pubs[key], TIMEOUT_S)

    def frame(self, t: float, since: float) -> None:
        """Everything r1 needs for the tick stamped ``t``: its camera pose, then its odometry."""
        self.put(keys.obstacles_key(P), encode(Obstacles(t, (ObstacleMsg("o1", 9.0, 9.0, 0, 0, 0.3),))))
        own = ellipse_to_msg("F1", Ellipse(-3.0, 0.0, 0.0, 0.6, 0.3), t)
        other = ellipse_to_msg("F2", Ellipse(3.0, 0.3, 0.0, 0.6, 0.3), t)
        self.put(keys.others_key(P, "F1"), encode(Others("F1", t, (other,), own)))
        for rid, x, y in (("r2", -2.75, 0.125), ("r4", -3.25, -0.125), ("r3", -2.75, -0.125)):
            self.put(keys.state_key(P, rid), encode(State(x, y, 0.0, 0.0, t, 0.0, 0.01)))
        self.put(keys.pose_key(P, "r1"), encode(Pose(-3.25, 0.125, 0.0, t)))
        self.put(odom_key(P, "r1"), encode_odom(Odom(0.0, 0.0, 0.0, since, t)))

    def close(self) -> None:
        self.session.close()


async def _eventually(predicate: Callable[[], bool]) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError("condition not met in time")
        await asyncio.sleep(0.005)


def test_an_agent_drops_malformed_odometry_counted_and_drives_on_its_estimate(router):
    zs = ZenohSettings(mode="client", connect=(router.endpoint,))
    cfg = build_agent_configs(load_scenario(ROOT / "scenarios" / "thesis-5.2.2.yaml"), zenoh=zs)["r1"]
    cfg = dataclasses.replace(cfg, localisation="fused")
    peer = Peer(router.endpoint)

    async def body() -> AgentNode:
        node = AgentNode(cfg, NodeOptions(lockstep=True, lockstep_timeout=0.3))
        stop = asyncio.Event()
        task = asyncio.create_task(node.run(stop))
        try:
            loop = asyncio.get_running_loop()
            await loop.run_in_executor(None, peer.wait_subscribed, keys.pose_key(P, "r1"))
            await loop.run_in_executor(None, peer.wait_subscribed, odom_key(P, "r1"))
            peer.put(odom_key(P, "r1"), b"\x07garbage")
            peer.put(odom_key(P, "r1"), encode_odom(Odom(0.0, 0.0, 0.0, 0.0, 0.0))[:-3])
            assert node.odom_in is not None
            await _eventually(lambda: node.odom_in.dropped["odom"] == 2)
            peer.frame(0.0, 0.0)
            await _eventually(lambda: 0.0 in peer.cmds)
            peer.frame(0.05, 0.0)
            await _eventually(lambda: 0.05 in peer.cmds)
            await _eventually(lambda: len(peer.states) >= 2)
        finally:
            stop.set()
            await asyncio.wait_for(task, TIMEOUT_S)
        return node

    try:
        node = asyncio.run(body())
    finally:
        peer.close()
    assert node.stale == 0 and node.odom_in is not None and node.odom_in.filter.fused >= 1
    assert all(s.sigma is not None and 0.0 < s.sigma < 0.25 for s in peer.states)
    loc = node.stats().localisation
    assert loc is not None and loc["dropped"]["odom"] == 2 and len(loc["trace"]) == 2


def test_a_real_time_run_with_the_camera_process_crosses_the_blind_patch(tmp_path):
    """Real time, poses from the camera process on rendered frames: the agents cross the patch
    on their odometry (behaviour only: every goal, no collision, the patch crossed unseen)."""
    out = tmp_path / "rt"
    assert main(["run", str(SCENARIOS / "blind-aisle.yaml"), "--out", str(out), "--quiet",
                 "--no-plots", "--insecure", "--realtime", "--camera", "process"]) == 0
    got = _summary(out)
    assert got["all_reached"] and got["collisions"] == 0
    loc = got["localisation"]
    assert loc["blind_s"] > 5.0 and loc["fused"] > 0 and loc["max_error_m"] < loc["radius_limit_m"]
