"""``formation run``: the whole system as separate processes (router, one agent per robot, the
simulated world) on loopback, compared with ``formation sim`` on the same scenario."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from formation.cli import main

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent

TWO_FORMATIONS = (ROOT / "tests" / "scenarios" / "two-small.yaml").read_text(encoding="utf-8")

LONG = TWO_FORMATIONS.replace("duration: 40.0", "duration: 400.0").replace(
    "goal: [2.0, 0.0]", "goal: [40.0, 0.0]").replace(
    "goal: [2.0, 0.5]", "goal: [40.0, 0.5]").replace("goal: [1.6, 0.25]", "goal: [39.6, 0.25]")


def run_cli(args: list[str]) -> int:
    return main(args)


def test_run_reaches_every_goal_safely_and_as_fast_as_the_in_process_simulation(tmp_path, capsys):
    scenario = tmp_path / "two.yaml"
    scenario.write_text(TWO_FORMATIONS, encoding="utf-8")
    assert run_cli(["sim", str(scenario), "--out", str(tmp_path / "sim"), "--quiet",
                    "--no-plots"]) == 0
    assert run_cli(["run", str(scenario), "--out", str(tmp_path / "run"), "--quiet",
                    "--no-plots"]) == 0
    sim = json.loads((tmp_path / "sim" / "summary.json").read_text())
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["mode"] == "multiprocess"
    assert run["all_reached"] is True
    assert run["collisions"] == 0
    assert run["formation_error_max_m"] <= 1.5 * 0.05
    assert sim["time_to_goal_s"] is not None
    assert abs(run["time_to_goal_s"] - sim["time_to_goal_s"]) <= 0.15 * sim["time_to_goal_s"]
    for field in ("scenario", "steps", "sim_time_s", "min_clearance_m", "min_h", "qp", "comm"):
        assert field in run
    assert run["qp"]["solves"] == sim["qp"]["solves"]
    comm = run["comm"]
    assert comm["topology"] == "reduced"
    assert comm["messages"] > 0 and comm["bytes"] > 0
    assert comm["messages_per_robot_per_s"] > 0 and comm["bytes_per_robot_per_s"] > 0
    assert comm["classes"]["state"]["recv"]["messages"] > 0
    assert run["agents"]["stale"] == 0 and run["world"]["missing_cmds"] == 0
    assert run["agents"]["tick_errors"] == 0  # a tick that raised is a bug, never hidden
    assert (tmp_path / "run" / "robots.csv").read_text() == (tmp_path / "sim" / "robots.csv").read_text()


def test_an_invalid_scenario_or_an_invalid_fault_option_exits_2_before_starting_anything(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(TWO_FORMATIONS.replace("goal_tolerance", "goal_tolerence"), encoding="utf-8")
    assert run_cli(["run", str(bad), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    good = tmp_path / "good.yaml"
    good.write_text(TWO_FORMATIONS, encoding="utf-8")
    assert run_cli(["run", str(good), "--out", str(tmp_path / "o"), "--drop", "1.5"]) == 2
    assert run_cli(["run", str(good), "--out", str(tmp_path / "o"), "--kill", "z9@1:2"]) == 2
    assert run_cli(["run", str(good), "--out", str(tmp_path / "o"), "--camera-dropout", "a1@1"]) == 2
    assert run_cli(["run", str(good), "--out", str(tmp_path / "o"), "--pose-slots", "0"]) == 2
    assert run_cli(["run", str(good), "--out", str(tmp_path / "o"), "--pose-slots", "2"]) == 2  # lock-step
    assert not (tmp_path / "o" / "processes.json").exists()


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _sessions() -> set[int]:
    """Session ids of every live process."""
    out = set()
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                out.add(int(fields[3]))
    return out


def test_a_run_interrupted_with_sigint_leaves_no_child_process_alive(tmp_path):
    scenario = tmp_path / "long.yaml"
    scenario.write_text(LONG, encoding="utf-8")
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "formation", "run", str(scenario), "--out",
                             str(out), "--quiet", "--no-plots"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while not (out / "processes.json").exists():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.05)
        time.sleep(0.5)
        pids = json.loads((out / "processes.json").read_text())
        assert len(pids) == 1 + 5  # router and one agent per robot
        time.sleep(2.0)  # well inside the run (it needs minutes)
        assert proc.poll() is None
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not [name for name, pid in pids.items() if _alive(pid)]
    # each child led its own session: nothing of theirs (grandchildren) is left either
    assert not set(pids.values()) & _sessions()


@pytest.mark.slow
def test_run_in_real_time_reaches_every_goal(tmp_path):
    scenario = tmp_path / "two.yaml"
    scenario.write_text(TWO_FORMATIONS, encoding="utf-8")
    assert run_cli(["run", str(scenario), "--out", str(tmp_path / "rt"), "--quiet", "--no-plots",
                    "--realtime"]) == 0
    run = json.loads((tmp_path / "rt" / "summary.json").read_text())
    assert run["all_reached"] is True and run["collisions"] == 0
    assert run["realtime"] is True
    assert run["world"]["latency_ms"]["samples"] > 0
    assert "pose_slots" not in run  # whole frames


@pytest.mark.slow
def test_run_in_real_time_with_poses_in_slots_reaches_every_goal_and_merges_the_agents_traces(
        tmp_path):
    """Issue 12: with pose slots every robot's pose goes out with its slot's own stamp; the
    agents' trace rows (status, slack, h_*) and the leaders' ellipses are keyed by it, so the
    merge must use it (it used the tick's first stamp: blank columns, no ellipses, and the safety
    figure failed on the empty series)."""
    scenario = tmp_path / "two.yaml"
    scenario.write_text(TWO_FORMATIONS, encoding="utf-8")
    out = tmp_path / "rt"
    assert run_cli(["run", str(scenario), "--out", str(out), "--quiet",
                    "--realtime", "--pose-slots", "4"]) == 0
    run = json.loads((out / "summary.json").read_text())
    assert run["all_reached"] is True and run["collisions"] == 0
    assert run["world"]["latency_ms"]["samples"] > 0
    assert run["pose_slots"] == 4
    with (out / "robots.csv").open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    traced = [r for r in rows if r["status"]]
    # real time: a pose an agent skipped (it ticked a newer one) has no trace row of its own
    assert len(traced) >= 0.9 * len(rows)
    solved = [r for r in traced if r["status"] != "stale"]
    assert solved and all(r["slack"] != "" and r["h_formation"] != "" and r["h_obstacle"] != ""
                          for r in solved)
    assert {r["robot"] for r in solved} == {"a1", "a2", "a3", "b1", "b2"}
    with (out / "ellipses.csv").open(encoding="utf-8") as fh:
        ellipses = list(csv.DictReader(fh))
    assert {e["formation"] for e in ellipses} == {"A", "B"}
    assert len(ellipses) >= 0.9 * 2 * len({r["t"] for r in rows})
    assert (out / "safety.png").stat().st_size > 0 and (out / "trajectories.png").stat().st_size > 0


def test_a_second_sigint_only_hurries_the_shutdown_and_the_run_is_still_written(tmp_path):
    scenario = tmp_path / "long.yaml"
    scenario.write_text(LONG, encoding="utf-8")
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "formation", "run", str(scenario), "--out",
                             str(out), "--quiet", "--no-plots", "--realtime"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not (out / "endpoint").exists():  # every agent up, the world running
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        for _ in range(6):  # a hurried operator's further Ctrl-Cs over 0.3 s (the attack)
            time.sleep(0.05)
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["aborted"]
    assert (out / "robots.csv").is_file() and (out / "run.mcap").is_file()


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MB tmpfs (needs root and mount permission; skipped otherwise)."""
    where = tmp_path / "small"
    where.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(where)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=False)


def test_a_run_onto_a_disk_too_small_is_refused_before_it_starts(tmp_path, small_disk):
    scenario = tmp_path / "two.yaml"
    scenario.write_text(TWO_FORMATIONS, encoding="utf-8")
    out = small_disk / "run"
    proc = subprocess.run([sys.executable, "-m", "formation", "run", str(scenario), "--out",
                           str(out), "--quiet", "--no-plots"],
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "MB free" in lines[0] and "--out" in lines[0]
    assert not (out / "processes.json").exists() and not list(small_disk.rglob("*.tmp"))


def test_a_member_killed_mid_run_is_restarted_and_the_run_reaches_every_goal(tmp_path):
    scenario = tmp_path / "two.yaml"
    scenario.write_text(TWO_FORMATIONS, encoding="utf-8")
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "formation", "run", str(scenario), "--out",
                             str(out), "--quiet", "--no-plots"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not (out / "endpoint").exists():  # every agent up, the world running
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.05)
        pids = json.loads((out / "processes.json").read_text())
        member = next(n for n in sorted(pids) if n.startswith("agent-"))
        os.kill(pids[member], signal.SIGKILL)  # a crash, not a stop: no counters, no zero cmd
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    summary = json.loads((out / "summary.json").read_text())
    robot = member.removeprefix("agent-")
    assert summary["restarts"] == {robot: 1}
    assert summary["all_reached"] is True and summary["collisions"] == 0
    assert (out / "logs" / f"{member}#2.log").is_file()
