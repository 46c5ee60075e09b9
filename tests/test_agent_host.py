"""The agent host (``python -m agent.host``, ``formation run --agents-per-process K``): K agents
in one process behave as K processes of their own (real Zenoh sessions on loopback)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from agent.config import ZenohSettings, build_agent_configs, save_config
from formation.cli import main
from leader.ellipse import Ellipse
from leader.role import ellipse_to_msg
from runtime.testing import RouterProcess, wait_for_matching
from scenario import load_scenario
from tests.same_files import assert_same
from wire import keys, zconf
from wire.payloads import Cmd, ObstacleMsg, Obstacles, Others, Pose, State, decode_cmd, encode

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
TWO_SMALL = ROOT / "tests" / "scenarios" / "two-small.yaml"
THESIS = ROOT / "scenarios" / "thesis-5.2.2.yaml"
P = keys.DEFAULT_PREFIX
TIMEOUT_S = 15.0


@pytest.mark.parametrize("extra", [["--agents-per-process", "4", "--session-per-agent", "--insecure"],
                                   ["--agents-per-process", "3", "--insecure"],
                                   ["--agents-per-process", "4"]],
                         ids=["own-sessions", "shared-session", "secure-own-logins"])
def test_a_lockstep_run_with_agent_hosts_writes_the_same_robots_csv_as_the_in_process_simulation(
        tmp_path, extra):
    assert main(["sim", str(TWO_SMALL), "--out", str(tmp_path / "sim"), "--quiet",
                 "--no-plots"]) == 0
    assert main(["run", str(TWO_SMALL), "--out", str(tmp_path / "run"), "--quiet", "--no-plots",
                 *extra]) == 0
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    robots = load_scenario(TWO_SMALL).robot_ids
    k = int(extra[1])
    procs = json.loads((tmp_path / "run" / "processes.json").read_text())
    assert sorted(p for p in procs if p.startswith("host-")) == \
        [f"host-{i}" for i in range(math.ceil(len(robots) / k))]
    assert not any(p.startswith("agent-") for p in procs)
    assert run["agents_per_process"] == k
    # one session per host only without access control (secure, the default: each robot logs in)
    assert run["shared_session"] is ("--insecure" in extra and "--session-per-agent" not in extra)
    assert run["agents"]["stale"] == 0 and run["world"]["missing_cmds"] == 0
    for rid in robots:  # every hosted agent wrote its own counters
        stats = json.loads((tmp_path / "run" / "agents" / f"{rid}.json").read_text())
        assert stats["robot"] == rid and stats["ticks"] > 0 and stats["host_agents"] >= 1
    assert_same(tmp_path / "sim" / "robots.csv", tmp_path / "run" / "robots.csv")


def test_kills_and_a_bad_agents_per_process_exit_2_before_starting_anything(tmp_path):
    out = tmp_path / "o"
    assert main(["run", str(TWO_SMALL), "--out", str(out), "--agents-per-process", "0"]) == 2
    robot = load_scenario(TWO_SMALL).robot_ids[0]
    assert main(["run", str(TWO_SMALL), "--out", str(out), "--agents-per-process", "2",
                 "--kill", f"{robot}@1"]) == 2
    assert main(["run", str(TWO_SMALL), "--out", str(out), "--agents-per-process", "-3"]) == 2
    assert not (out / "processes.json").exists()


def test_the_host_refuses_a_robot_given_twice_and_a_shared_session_with_credentials(tmp_path):
    cfg = build_agent_configs(load_scenario(THESIS), zenoh=ZenohSettings(mode="client"))["r1"]
    save_config(cfg, tmp_path / "r1.yaml")
    spec = f"{tmp_path / 'r1.yaml'},{tmp_path / 'r1.json'}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for args in (["--agent", spec, "--agent", spec],
                 ["--shared-session", "--agent", spec + f",{tmp_path / 'c'}"],
                 ["--agent", "only-one-part"]):
        done = subprocess.run([sys.executable, "-m", "agent.host", *args], env=env,
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 2, done.stderr
        assert done.stderr.startswith("agent host: ") and "Traceback" not in done.stderr
        assert not (tmp_path / "r1.json").exists()


class Peer:
    """Plays the world and the robots the host does not run; records every robot's commands."""

    def __init__(self, endpoint: str, robots: list[str]) -> None:
        conf = zconf.make_config("client", connect=[endpoint], connect_timeout_s=TIMEOUT_S)
        self.session = zenoh.open(conf)
        self.pubs: dict[str, zenoh.Publisher] = {}
        self.cmds: dict[str, list[Cmd]] = {r: [] for r in robots}
        self._lock = threading.Lock()
        self.subs = [self.session.declare_subscriber(keys.cmd_key(P, r), self._on_cmd(r))
                     for r in robots]

    def _on_cmd(self, rid: str):
        def on(sample: zenoh.Sample) -> None:
            with self._lock:
                self.cmds[rid].append(decode_cmd(sample.payload.to_bytes()))
        return on

    def commands(self, rid: str) -> list[Cmd]:
        with self._lock:
            return list(self.cmds[rid])

    def put(self, key: str, payload: bytes) -> None:
        if key not in self.pubs:
            self.pubs[key] = self.session.declare_publisher(key)
            wait_for_matching(self.pubs[key], TIMEOUT_S)
        self.pubs[key].put(payload)

    def feed(self, t: float) -> None:
        """Everything members r1 and r3 of F1 need for the tick stamped ``t`` (poses last)."""
        self.put(keys.obstacles_key(P), encode(Obstacles(t, (ObstacleMsg("o1", 9.0, 9.0, 0, 0, 0.3),))))
        own = ellipse_to_msg("F1", Ellipse(-3.0, 0.0, 0.0, 0.6, 0.3), t)
        other = ellipse_to_msg("F2", Ellipse(3.0, 0.3, 0.0, 0.6, 0.3), t)
        self.put(keys.others_key(P, "F1"), encode(Others("F1", t, (other,), own)))
        self.put(keys.state_key(P, "r2"), encode(State(-2.75, 0.125, 0.2, 0.0, t)))
        self.put(keys.state_key(P, "r4"), encode(State(-3.25, -0.125, 0.2, 0.0, t)))
        self.put(keys.pose_key(P, "r1"), encode(Pose(-3.25, 0.125, 0.0, t)))
        self.put(keys.pose_key(P, "r3"), encode(Pose(-2.75, -0.125, 0.0, t)))


@pytest.mark.parametrize("shared", [False, True], ids=["own-sessions", "shared-session"])
def test_sigterm_to_the_host_makes_every_agent_command_zero_and_write_its_counters(tmp_path, shared):
    hosted = ["r1", "r3"]
    with RouterProcess() as router:
        zs = ZenohSettings(mode="client", connect=(router.endpoint,))
        configs = build_agent_configs(load_scenario(THESIS), zenoh=zs)
        argv = [sys.executable, "-m", "agent.host"] + (["--shared-session"] if shared else [])
        for rid in hosted:
            save_config(configs[rid], tmp_path / f"{rid}.yaml")
            argv += ["--agent", f"{tmp_path / f'{rid}.yaml'},{tmp_path / f'{rid}.json'}"]
        peer = Peer(router.endpoint, hosted)
        proc = subprocess.Popen(argv, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                                start_new_session=True)
        try:
            deadline = time.monotonic() + TIMEOUT_S
            while not all(any(math.hypot(c.ux, c.uy) > 0.05 for c in peer.commands(r))
                          for r in hosted):
                assert time.monotonic() < deadline, "no non-zero command from every agent in time"
                peer.feed(time.time())
                time.sleep(0.02)
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(TIMEOUT_S) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        time.sleep(0.3)  # the zero commands cross the router
        for rid in hosted:
            last = peer.commands(rid)[-1]
            assert (last.v, last.omega, last.ux, last.uy) == (0.0, 0.0, 0.0, 0.0)
            stats = json.loads((tmp_path / f"{rid}.json").read_text())
            assert stats["robot"] == rid and stats["solves"] > 0 and stats["host_agents"] == 2
        peer.session.close()


def test_bench_fleets_runs_each_chosen_fleet_repeatedly_with_its_latency_parts_and_load(tmp_path):
    out = tmp_path / "bench"
    assert main(["bench", "--out", str(out), "--fleets", "4@20", "--agents-per-process", "2",
                 "--repeat", "2", "--duration", "1.5", "--stalls"]) == 0
    result = json.loads((out / "bench.json").read_text())
    assert result["agents_per_process"] == 2 and result["shared_session"] is True  # the default
    assert [(f["fleet"], f["round"]) for f in result["fleets"]] == [("4@20", 1), ("4@20", 2)]
    for f in result["fleets"]:
        assert f["robots"] == 4 and f["agents_per_process"] == 2
        assert f["commands"] > 0 and f["latency_ms_p99"] >= f["latency_ms_p50"] > 0
        assert set(f["latency_parts_ms_median"]) == {"pose_wait_for_tick", "tick", "transport_rest",
                                                     "pose_in", "cmd_back"}
        assert all(math.isfinite(v) for v in f["latency_parts_ms_median"].values())
        assert f["load_avg_1min"]["before"] is not None
        stalls = f["stalls"]  # --stalls: both hosts' reports summed up
        assert stalls["hosts"] == 2 and set(stalls["gc"]) == {"0", "1", "2"}
        assert stalls["heap_objects"] > 0 and stalls["tick_wall_ms_max"] > 0
        assert stalls["longest_ticks"] and any(r["parts_ms"] for r in stalls["longest_ticks"])
    table, parts = (out / "bench.txt").read_text().split("the tick's parts")
    rows = [line.split() for line in table.splitlines()]
    assert sum(1 for r in rows if r[:2] == ["4", "20"]) == 2  # one table row per run
    rows = [line.split() for line in parts.splitlines()]
    assert sum(1 for r in rows if r[:2] == ["4", "20"]) == 2  # and one row of its tick's parts
    assert sum(1 for r in rows if r[:1] == ["4@20"]) == 2  # and one of what held its ticks back


@pytest.mark.parametrize("args", [["--fleets", "32at50"], ["--fleets", "0@20"], ["--fleets", "8@-5"],
                                  ["--agents-per-process", "2"], ["--session-per-agent"],
                                  ["--fleets", "8@20", "--repeat", "0"], ["--pose-slots", "2"],
                                  ["--stalls"], ["--fleets", "8@20", "--stalls"]])
def test_bench_with_a_bad_fleet_option_exits_2_before_running_anything(tmp_path, args):
    assert main(["bench", "--out", str(tmp_path / "b"), *args]) == 2
    assert not (tmp_path / "b" / "bench.json").exists()


def test_a_real_time_run_with_agent_hosts_reaches_every_goal_with_every_agent_ticking(tmp_path):
    assert main(["run", str(TWO_SMALL), "--out", str(tmp_path / "rt"), "--quiet", "--no-plots",
                 "--realtime", "--agents-per-process", "4"]) == 0
    run = json.loads((tmp_path / "rt" / "summary.json").read_text())
    assert run["all_reached"] is True and run["collisions"] == 0
    assert run["realtime"] is True and run["agents_per_process"] == 4
    assert run["world"]["latency_ms"]["samples"] > 0
    for rid in load_scenario(TWO_SMALL).robot_ids:  # the host's tick thread served every robot
        stats = json.loads((tmp_path / "rt" / "agents" / f"{rid}.json").read_text())
        assert stats["solves"] > 0 and "superseded_poses" in stats
