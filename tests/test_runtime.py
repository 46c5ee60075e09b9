"""The multi-process runtime under a careless user: a launcher killed or hung up leaves no
process, two runs on one port do not mix, over real processes and real Zenoh (issue 14)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
import zenoh

from runtime import lifeline
from runtime.testing import RouterProcess
from wire import zconf
from wire.zconf import ZenohSettings, make_config

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
TWO = (ROOT / "tests" / "scenarios" / "two-small.yaml").read_text(encoding="utf-8")
LONG = TWO.replace("duration: 40.0", "duration: 400.0").replace(
    "goal: [2.0, 0.0]", "goal: [40.0, 0.0]").replace(
    "goal: [2.0, 0.5]", "goal: [40.0, 0.5]").replace("goal: [1.6, 0.25]", "goal: [39.6, 0.25]")


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _start_run(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, Path]:
    scenario = tmp_path / "long.yaml"
    scenario.write_text(LONG, encoding="utf-8")
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "formation", "run", str(scenario), "--out",
                             str(out), "--quiet", "--no-plots", *extra], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)  # its own session: SIGHUP reaches it alone
    return proc, out


def _wait_running(proc: subprocess.Popen, out: Path) -> dict[str, int]:
    deadline = time.monotonic() + 60
    while not (out / "processes.json").exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    pids = json.loads((out / "processes.json").read_text())
    _wait_commands(out, [n.removeprefix("agent-") for n in pids if n.startswith("agent-")])
    assert proc.poll() is None  # well inside the run (it needs minutes)
    return pids


def _wait_commands(out: Path, robots: list[str], timeout: float = 60.0) -> None:
    """Wait until every robot's agent has published a command (the fleet is running)."""
    cfg = yaml.safe_load((out / "configs" / f"{robots[0]}.yaml").read_text())
    seen: set[str] = set()
    done = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        seen.add(str(sample.key_expr).split("/")[-2])
        if seen >= set(robots):
            done.set()

    with zenoh.open(_client_config(out, cfg["zenoh"]["connect"])) as session:
        session.declare_subscriber("warehouse/robot/*/cmd", on_sample)
        assert done.wait(timeout), f"commands only from {sorted(seen)}"


def _client_config(out: Path, connect: list[str]) -> zenoh.Config:
    """The viewer's credentials the run wrote (access control is on by default)."""
    viewer = out / "secure" / "viewer.json5"
    assert viewer.is_file()
    found = zconf.read_auth_file(viewer)
    assert list(found.connect) == connect
    return ZenohSettings(mode="client", connect=found.connect, auth=found.auth).to_config()


def _wait_gone(pids: dict[str, int], timeout: float) -> list[str]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        left = [name for name, pid in pids.items() if _alive(pid)]
        if not left:
            return []
        time.sleep(0.1)
    return [name for name, pid in pids.items() if _alive(pid)]


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGHUP])
def test_a_launcher_killed_or_hung_up_leaves_no_process_behind(tmp_path, sig):
    proc, out = _start_run(tmp_path)
    pids: dict[str, int] = {}
    try:
        pids = _wait_running(proc, out)
        assert len(pids) == 1 + 5
        os.kill(proc.pid, sig)
        proc.communicate(timeout=30)
        left = _wait_gone(pids, 20.0)  # on a loaded machine the router's own close takes a while
    finally:
        for pid in [proc.pid, *pids.values()]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        proc.wait()
    assert not left, f"still running {sig.name} after the launcher: {left}"
    # the agents stopped through their own shutdown (zero command, counters), not a kill
    assert sorted(p.stem for p in (out / "agents").glob("*.json")) == ["a1", "a2", "a3", "b1", "b2"]


def test_a_child_whose_launcher_is_gone_is_told_through_the_lifeline_pipe():
    env, fds = lifeline.child_env(os.environ)
    assert env[lifeline.PARENT_ENV] == str(os.getpid())
    # a child that watches its parent (this process's child: a shell in between, killed below)
    code = ("import time, sys, threading; from runtime import lifeline; ev = threading.Event(); "
            "lifeline.watch_parent(ev.set) or sys.exit(3); "
            "print('watching', flush=True); ev.wait(20) and print('told', flush=True)")
    # the parent is an intermediate python that starts the watcher with the lifeline, then dies
    parent = ("import os, subprocess, sys; from runtime import lifeline; "
              "env, fds = lifeline.child_env(os.environ); "
              f"p = subprocess.Popen([sys.executable, '-c', {code!r}], env=env, pass_fds=fds); "
              "print(p.pid, flush=True); sys.stdin.read(); os._exit(0)")
    proc = subprocess.Popen([sys.executable, "-c", parent], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                            text=True)
    child = int(proc.stdout.readline())
    assert proc.stdout.readline().strip() == "watching"
    assert _alive(child)
    proc.stdin.close()  # the intermediate parent exits: the watcher must notice
    proc.wait(10)
    assert proc.stdout.readline().strip() == "told"  # from the watcher, which shares the pipe
    proc.stdout.close()
    assert _wait_gone({"watcher": child}, 10.0) == []


def test_a_second_run_on_a_taken_port_is_refused_naming_the_port(tmp_path):
    """The first run's router serves the port; the second run must not publish into it."""
    with RouterProcess() as first:
        seen: list[str] = []
        lock = threading.Lock()
        conf = make_config("client", [first.endpoint])
        with zenoh.open(conf) as session:
            def on_sample(sample: zenoh.Sample) -> None:
                with lock:
                    seen.append(str(sample.key_expr))

            sub = session.declare_subscriber("warehouse/**", on_sample)
            scenario = tmp_path / "two.yaml"
            scenario.write_text(TWO, encoding="utf-8")
            proc = subprocess.run(
                [sys.executable, "-m", "formation", "run", str(scenario), "--out",
                 str(tmp_path / "second"), "--quiet", "--no-plots", "--port", str(first.port)],
                env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True,
                timeout=120)
            time.sleep(0.3)
            sub.undeclare()
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and f"port {first.port}" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr
    assert seen == []  # nothing of the second run reached the first


# --- fault containment: a dead leader's formation stands, the others go on ----------------------

def test_the_successor_is_the_first_member_adjacent_to_every_other():
    from leader.succession import can_lead, successor

    robots = ("r1", "r2", "r3", "r4")
    edges = [("r1", "r2"), ("r1", "r4"), ("r2", "r3"), ("r2", "r4"), ("r3", "r4")]  # thesis 5.1
    assert can_lead(robots, edges) == ("r2", "r4")
    assert successor(robots, edges, "r2") == "r4"
    fan = [("l", m) for m in "abcd"] + [("a", "b"), ("b", "c"), ("c", "d")]
    assert successor(("l", "a", "b", "c", "d"), fan, "l") is None


FAN = """\
name: fan
dt: 0.05
duration: 10.0
goal_tolerance: 0.05
robot: {model: single_integrator, max_speed: 0.22, radius: 0.105}
controller: {kp: 2.0, gamma: 1.0, epsilon: 0.05}
formations:
  - name: F
    leader: l
    robots:
      l: {start: [0.0, 0.0], goal: [1.0, 0.0]}
      a: {start: [0.5, 0.0], goal: [1.5, 0.0]}
      b: {start: [0.25, 0.433], goal: [1.25, 0.433]}
      c: {start: [-0.25, 0.433], goal: [0.75, 0.433]}
      d: {start: [-0.5, 0.0], goal: [0.5, 0.0]}
    edges: [[l, a], [l, b], [l, c], [l, d], [a, b], [b, c], [c, d]]
"""


def test_check_warns_about_a_formation_nobody_can_take_over(tmp_path, capsys):
    from formation.cli import main

    path = tmp_path / "fan.yaml"
    path.write_text(FAN, encoding="utf-8")
    assert main(["check", str(path)]) == 0
    err = capsys.readouterr().err
    assert "warning: formation 'F' has no member adjacent to every other member" in err
    assert main(["check", str(ROOT / "scenarios" / "thesis-5.2.2.yaml")]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.slow
def test_when_a_leader_dies_for_good_its_successor_leads_and_the_other_formation_reaches_its_goals(
        tmp_path):
    """thesis-5.2.2 (F1 led by r2, F2 by s2), r2 killed at 5 s and never restarted: r4 takes over
    F1, which stands still; F2 passes it and reaches every goal (at 45.05 s under the rigid
    default, 36.35 s under the old per-member rules; the duration is cut to 60 s here to keep
    the test short)."""
    from formation.cli import main

    text = (ROOT / "scenarios" / "thesis-5.2.2.yaml").read_text(encoding="utf-8")
    path = tmp_path / "thesis-5.2.2.yaml"
    path.write_text(text.replace("duration: 150.0", "duration: 60.0"), encoding="utf-8")
    out = tmp_path / "run"
    assert main(["run", str(path), "--kill", "r2@5", "--out", str(out), "--quiet",
                 "--no-plots"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["collisions"] == 0 and s["min_clearance_m"]["robot"] > 0
    assert s["time_to_goal_by_formation_s"]["F2"] is not None
    assert s["time_to_goal_by_formation_s"]["F1"] is None  # its load hangs on the dead robot
    assert s["faults"]["leader_takeovers"] == {"r4": 1}
    assert s["faults"]["inflated_ellipse_ticks"] <= 20  # F1's ellipse came back within a second


# --- lost runs: a stalled router is counted (a full disk: tests/test_output_lost.py) ------

def test_a_router_stalled_for_two_seconds_shows_up_as_missing_commands(tmp_path):
    """Real time: SIGSTOP of the router for 2 s; every robot got no command for about 40 ticks,
    and the summary must say so (it said missing_cmds: 0)."""
    scenario = tmp_path / "two.yaml"
    scenario.write_text(TWO, encoding="utf-8")
    out = tmp_path / "rt"
    proc = subprocess.Popen([sys.executable, "-m", "formation", "run", str(scenario), "--out",
                             str(out), "--quiet", "--no-plots", "--realtime"],
                            env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        pids = _wait_running(proc, out)
        os.kill(pids["router"], signal.SIGSTOP)
        time.sleep(2.0)
        os.kill(pids["router"], signal.SIGCONT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["world"]["missing_cmds"] >= 5 * 25, s["world"]  # 5 robots, most of 40 ticks each
    assert s["collisions"] == 0


@pytest.mark.parametrize("victim", ["router", "agent-a2"])
def test_a_run_whose_router_or_agent_is_killed_still_writes_its_summary_saying_aborted(
        tmp_path, victim):
    # --restart no: a crashed agent is otherwise restarted and the run carries on
    # (test_faults shows that); here the run must end and still write what it measured
    proc, out = _start_run(tmp_path, "--restart", "no")
    try:
        pids = _wait_running(proc, out)
        time.sleep(1.0)  # some ticks to measure
        os.kill(pids[victim], signal.SIGKILL)
        err = proc.communicate(timeout=60)[1].decode()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1, err
    assert f"aborted: {victim} exited" in err and "Traceback" not in err, err
    s = json.loads((out / "summary.json").read_text())
    assert s["aborted"].startswith(f"{victim} exited with status -9")
    assert s["steps"] > 0 and s["sim_time_s"] > 0 and s["collisions"] == 0
    assert (out / "robots.csv").read_text().count("\n") > 5 * s["steps"] // 2
    if victim == "router":  # every agent outlived it and wrote its counters
        assert "aborted_counters_lost" not in s
    else:
        assert s["aborted_counters_lost"] == ["a2"]
    assert _wait_gone(pids, 10.0) == []
