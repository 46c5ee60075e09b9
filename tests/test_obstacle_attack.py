"""A second source on the obstacle list over real Zenoh, in a real-time run of thesis 5.1.2: for
every genuine list the world publishes, a forger puts an empty one stamped 90 ms ahead (inside
the clock tolerance). The lists disagree, so the robots avoid what both report; the crate
driving at the formation stays an obstacle, where stopping left the robots in its way.

By hand, beside two CPU hogs, five times:
``for i in 1 2 3 4 5; do pytest -q tests/test_obstacle_attack.py; done``."""

from __future__ import annotations

import json
import queue
import time
from pathlib import Path

import pytest
import zenoh

from formation.cli import main
from runtime.testing import free_tcp_port
from scenario import load_scenario
from tests.test_hostile_inputs import Attacker
from wire import keys
from wire.payloads import Obstacles, decode_obstacles, encode

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
THESIS = ROOT / "scenarios" / "thesis-5.1.2.yaml"
P = keys.DEFAULT_PREFIX
AHEAD_S = 0.09  # [s] inside the 0.1 s clock tolerance


class EmptyListForger(Attacker):
    """Once every robot commands: after each genuine obstacle list, an empty one stamped
    :data:`AHEAD_S` ahead of the clock."""

    def attack(self, session: zenoh.Session) -> None:
        genuine: queue.Queue[float] = queue.Queue()

        def on_list(sample: zenoh.Sample) -> None:
            try:
                msg = decode_obstacles(sample.payload.to_bytes())
            except ValueError:
                return
            if msg.obstacles:  # the world's (ours are empty)
                genuine.put(msg.stamp)

        commanding: set[str] = set()
        cmd_sub = session.declare_subscriber(
            keys.all_robots_key(P, keys.CMD),
            lambda s: commanding.add(str(s.key_expr).split("/")[-2]))
        while not self._stop.is_set() and not commanding.issuperset(self.robots):
            time.sleep(0.02)
        cmd_sub.undeclare()
        pubs = {keys.obstacles_key(P): session.declare_publisher(keys.obstacles_key(P))}
        sub = session.declare_subscriber(keys.obstacles_key(P), on_list)
        while not self._stop.is_set():
            try:
                genuine.get(timeout=0.1)
            except queue.Empty:
                continue
            self.put(pubs, keys.obstacles_key(P), encode(Obstacles(time.time() + AHEAD_S, ())),
                     "ahead_empty")
        sub.undeclare()


def test_an_empty_list_stamped_ahead_for_every_genuine_one_leaves_the_crate_an_obstacle(
        tmp_path):
    scenario = tmp_path / "thesis-5.1.2.yaml"
    scenario.write_text(THESIS.read_text(encoding="utf-8").replace("duration: 120.0",
                                                                   "duration: 60.0"),
                        encoding="utf-8")
    sc = load_scenario(scenario)
    port = free_tcp_port()
    with EmptyListForger(port, list(sc.robot_ids), [f.name for f in sc.formations]) as forger:
        assert main(["run", str(scenario), "--out", str(tmp_path / "run"), "--quiet",
                     "--no-plots", "--realtime", "--insecure", "--port", str(port)]) == 0
    assert forger.error is None
    assert forger.sent.get("ahead_empty", 0) > 100
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["collisions"] == 0, run["collision_log"]
    assert run["all_reached"]
    agents = run["agents"]
    # the genuine lists came stamped before the forged ones they disagree with: second sources,
    # counted; the robots avoided their crate beside the empty lists, and stopped for none
    assert agents["implausible"]["obstacles"] > 0 and agents["obstacle_held_ticks"] > 0
    assert agents["stale_why"].get("contested", 0) == 0
    assert agents["tick_errors"] == 0
