"""An agent under ``controller.localisation: fused`` behind a ROS 2 base (zenoh-bridge-ros2dds,
or rmw_zenoh) hears the base's ``odom`` topic: a fake base puts nav_msgs/Odometry CDR on
``a1/odom`` (on rmw_zenoh, the topic's data key) and the
camera a pose on the agent's pose key, over real Zenoh on loopback (a router on an explicit
tcp/127.0.0.1 port, scouting off); the agent's filter starts on the pose and moves with the
odometry, its radius grows, a malformed sample and a jump are dropped and counted."""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from agent.config import ZenohSettings, build_agent_configs
from agent.node import AgentNode, NodeOptions
from runtime.testing import RouterProcess, wait_for_matching
from scenario import load_scenario
from wire import keys, zconf
from wire.payloads import Pose, encode
from wire.rmw_zenoh import RmwSettings, encode_odometry, odom_data_key

ROOT = Path(__file__).resolve().parent.parent
DT = 0.05
STEPS = 10
STEP_M = 0.01  # [m] per odometry message: 0.2 m/s, within the burger's limit


def wait_until(done: Callable[[], bool], what: str, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.005)


RMW = RmwSettings(namespace="a1")


@pytest.mark.integration
@pytest.mark.parametrize("rmw,odom_key", [(None, "a1/odom"), (RMW, odom_data_key(RMW, "jazzy"))])
def test_the_base_odometry_moves_the_fused_estimate(rmw, odom_key):
    with RouterProcess() as router:
        zs = ZenohSettings(mode="client", connect=(router.endpoint,))
        cfg = build_agent_configs(load_scenario(ROOT / "scenarios/thesis-6.5.yaml"), zenoh=zs)["a1"]
        cfg = dataclasses.replace(cfg, base="turtlebot3-jazzy", cmd_vel_key="a1/cmd_vel",
                                  localisation="fused", rmw=rmw)
        node = AgentNode(cfg, NodeOptions())
        loc = node.odom_in
        assert loc is not None and loc.odom_key == odom_key
        peer = zenoh.open(zconf.make_config("client", connect=[router.endpoint]))
        odom = peer.declare_publisher(odom_key)
        camera = peer.declare_publisher(keys.pose_key(cfg.prefix, "a1"))
        loop = asyncio.new_event_loop()
        try:
            node.open(loop)
            wait_for_matching(odom)
            wait_for_matching(camera)
            t0 = math.floor(time.time())
            x0, y0, th0 = 1.0, -2.0, 0.5  # the camera's pose of the robot
            odom.put(encode_odometry(t0, (5.0, 5.0, 0.0)))  # the reference, in the odom frame
            wait_until(lambda: loc.last_odom == pytest.approx(t0, abs=1e-6), "the reference odometry")
            camera.put(encode(Pose(x0, y0, th0, t0)))
            wait_until(lambda: len(loc.pending) == 1, "the camera pose")
            odom.put(encode_odometry(t0 + DT, (5.0, 5.0, 0.0)))
            wait_until(lambda: loc.filter.estimate() is not None, "the filter to start")
            radius = loc.radius
            for k in range(1, STEPS + 1):  # straight ahead along the odom frame's x
                odom.put(encode_odometry(t0 + (k + 1) * DT, (5.0 + k * STEP_M, 5.0, 0.0)))
            end = t0 + (STEPS + 1) * DT
            wait_until(lambda: loc.last_odom == pytest.approx(end, abs=1e-6), "the odometry's last sample")
            est = loc.filter.estimate()
            odom.put(b"\x00\x01\x00\x00 not an odometry")
            wait_until(lambda: loc.dropped["odom"] == 1, "the malformed sample to be counted")
            odom.put(encode_odometry(end + DT, (0.0, 0.0, 0.0)))  # a reset of the base's odometry
            wait_until(lambda: loc.stats()["odom_jumps"] == 1, "the jump to be counted")
        finally:
            node.close()
            loop.close()
            peer.close()
    assert est is not None
    (x, y, th), r = est
    travelled = STEPS * STEP_M  # along the robot's heading th0 on the floor
    assert (x, y) == pytest.approx((x0 + travelled * math.cos(th0), y0 + travelled * math.sin(th0)),
                                   abs=0.02)
    assert th == pytest.approx(th0, abs=0.01)
    assert r > radius > 0.0  # odometry alone since the pose: the uncertainty grows
    assert loc.last_odom == pytest.approx(end, abs=1e-6)  # neither the malformed sample nor the jump fed it
