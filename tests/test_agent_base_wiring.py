"""An agent configured for a real TurtleBot3 drives its base: every command also goes out as the
CDR geometry_msgs Twist that zenoh-bridge-ros2dds forwards to /cmd_vel (real Zenoh, loopback)."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import threading
import time
from pathlib import Path

import pytest
import zenoh

from agent.base import decode_twist, decode_twist_stamped
from agent.config import ZenohSettings, build_agent_configs
from agent.node import AgentNode, NodeOptions
from runtime.testing import RouterProcess
from scenario import load_scenario
from wire import zconf
from wire.payloads import Cmd

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.integration
@pytest.mark.parametrize("base,decode", [("turtlebot3-humble", decode_twist),
                                         ("turtlebot3-jazzy", decode_twist_stamped)])
def test_commands_reach_the_cmd_vel_key_as_cdr_and_shutdown_sends_zero(base, decode, tmp_path):
    with RouterProcess() as router:
        zs = ZenohSettings(mode="client", connect=(router.endpoint,))
        cfg = build_agent_configs(load_scenario(ROOT / "scenarios/thesis-6.5.yaml"), zenoh=zs)["a1"]
        cfg = dataclasses.replace(cfg, base=base, cmd_vel_key="a1/cmd_vel")
        got: list[bytes] = []
        lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            with lock:
                got.append(sample.payload.to_bytes())

        peer = zenoh.open(zconf.make_config("client", connect=[router.endpoint]))
        sub = peer.declare_subscriber("a1/cmd_vel", on_sample)
        # The Jazzy robot reads a full Zenoh JSON5 file, as `formation deploy` writes it.
        conf_file = tmp_path / "zenoh.json5"
        conf_file.write_text(json.dumps({"mode": "client",
                                         "connect": {"endpoints": [router.endpoint]},
                                         "scouting": {"multicast": {"enabled": False}}}))
        options = NodeOptions(zenoh_config_file=str(conf_file) if base.endswith("jazzy") else None)
        node = AgentNode(cfg, options)
        loop = asyncio.new_event_loop()
        try:
            node.open(loop)
            time.sleep(0.5)  # let the subscription reach the router
            node.send_command(Cmd(0.1, -0.5, 0.1, 0.0, 12.25))
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and not got:
                time.sleep(0.02)
            node.close()
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and len(got) < 3:
                time.sleep(0.02)
        finally:
            loop.close()
            sub.undeclare()
            peer.close()
    with lock:
        msgs = [decode(b) for b in got]
    first = msgs[0] if base.endswith("humble") else msgs[0].twist
    assert (first.linear[0], first.angular[2]) == pytest.approx((0.1, -0.5))
    last = msgs[-1] if base.endswith("humble") else msgs[-1].twist
    assert (last.linear[0], last.angular[2]) == (0.0, 0.0)  # stopped on the way out
