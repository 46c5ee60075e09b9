"""A stream stamped 90 ms ahead (inside the clock tolerance) cannot take an input over
(wire.stamps.used_stamp), over real Zenoh in a real-time run (issue 28).

With the camera's credentials (here: ``--insecure``) a forger publishes, beside the genuine
camera, a1's pose stamped +90 ms and walked 2 cm further from a2 per message at 3x the camera's
rate, and empty obstacle lists stamped +90 ms. Recorded as they came, those stamps made every
genuine message "older": a1 and a2 collided, and robots drove into the crates."""

from __future__ import annotations

import json
import math
import threading
import time

import pytest
import zenoh

from formation.cli import main
from runtime.testing import free_tcp_port
from scenario import load_scenario
from tests.test_hostile_inputs import TWO, Attacker
from wire import keys
from wire.payloads import Obstacles, Pose, decode_pose, encode

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

P = keys.DEFAULT_PREFIX
AHEAD_S = 0.09  # [s] inside the 0.1 s clock tolerance
STEP_M = 0.02  # [m] the forged pose walks this far per message (inside the plausibility margin)


class AheadAttacker(Attacker):
    """Once a1's and a2's poses flow: forged a1 poses and empty obstacle lists, +90 ms."""

    def attack(self, session: zenoh.Session) -> None:
        lock = threading.Lock()
        latest: dict[str, Pose] = {}

        def on_pose(sample: zenoh.Sample) -> None:
            rid = str(sample.key_expr).split("/")[-2]
            try:
                pose = decode_pose(sample.payload.to_bytes())
            except ValueError:
                return
            if pose.stamp < time.time() + 0.01:  # a genuine pose, not one of ours
                with lock:
                    latest[rid] = pose

        commanding: set[str] = set()
        cmd_sub = session.declare_subscriber(
            keys.all_robots_key(P, keys.CMD),
            lambda s: commanding.add(str(s.key_expr).split("/")[-2]))
        while not self._stop.is_set() and not commanding.issuperset(self.robots):
            time.sleep(0.02)
        cmd_sub.undeclare()
        sub = session.declare_subscriber(keys.all_robots_key(P, keys.POSE), on_pose)
        pubs = {k: session.declare_publisher(k)
                for k in (keys.pose_key(P, "a1"), keys.obstacles_key(P))}
        while not self._stop.is_set() and not {"a1", "a2"} <= set(latest):
            time.sleep(0.02)
        with lock:
            a1, a2 = latest["a1"], latest["a2"]
        d = math.hypot(a1.x - a2.x, a1.y - a2.y) or 1.0
        ux, uy = (a1.x - a2.x) / d, (a1.y - a2.y) / d  # away from a2: a1 is driven towards it
        k = 0
        while not self._stop.is_set():
            k += 1
            with lock:
                g = latest["a1"]
            stamp = time.time() + AHEAD_S
            self.put(pubs, keys.pose_key(P, "a1"),
                     encode(Pose(g.x + ux * STEP_M * k, g.y + uy * STEP_M * k, g.theta, stamp)),
                     "ahead_pose")
            self.put(pubs, keys.obstacles_key(P), encode(Obstacles(stamp, ())), "ahead_empty")
            time.sleep(0.05 / 3)  # 3x the camera's 20 Hz
        sub.undeclare()


def test_a_stream_stamped_90_ms_ahead_takes_no_input_over(tmp_path):
    scenario = tmp_path / "near.yaml"
    scenario.write_text(TWO.read_text(encoding="utf-8").replace("duration: 40.0", "duration: 8.0")
                        .replace("center: [1.0, -1.0]", "center: [1.4, -0.5]"), encoding="utf-8")
    sc = load_scenario(scenario)
    port = free_tcp_port()
    with AheadAttacker(port, list(sc.robot_ids), [f.name for f in sc.formations]) as attacker:
        assert main(["run", str(scenario), "--out", str(tmp_path / "run"), "--quiet",
                     "--no-plots", "--realtime", "--insecure", "--port", str(port)]) == 0
    assert attacker.error is None
    assert min(attacker.sent.get(k, 0) for k in ("ahead_pose", "ahead_empty")) > 30
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["collisions"] == 0, run["collision_log"]
    assert run["agents"]["tick_errors"] == 0
