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
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from formation.cli import main

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent

TWO_FORMATIONS = (ROOT / "tests" / "scenarios" / "two-small.yaml").read_text(encoding="utf-8")

LONG = TWO_FORMATIONS.replace("duration: 40.0", "duration: 400.0").replace(
    "goal: [2.0, 0.0]", "goal: [40.0, 0.0]").replace(
    "goal: [2.0, 0.5]", "goal: [40.0, 0.5]").replace("goal: [1.6, 0.25]", "goal: [39.6, 0.25]")


@pytest.fixture
def two(tmp_path) -> Path:
    """tests/scenarios/two-small.yaml, as the test's own file."""
    path = tmp_path / "two.yaml"
    path.write_text(TWO_FORMATIONS, encoding="utf-8")
    return path


@pytest.fixture
def long(tmp_path) -> Path:
    """two-small with goals 38 m further: a run that needs minutes (to interrupt it)."""
    path = tmp_path / "long.yaml"
    path.write_text(LONG, encoding="utf-8")
    return path


def run_cli(command: str, scenario: Path, out: Path, *options: str, plots: bool = False) -> int:
    """``formation COMMAND SCENARIO --out OUT --quiet [--no-plots] OPTIONS`` in this process."""
    return main([command, str(scenario), "--out", str(out), "--quiet",
                 *(() if plots else ("--no-plots",)), *options])


def run_args(scenario: Path, out: Path, *options: str) -> list[str]:
    """``formation run SCENARIO --out OUT --quiet --no-plots OPTIONS`` as a child's command line."""
    return [sys.executable, "-m", "formation", "run", str(scenario), "--out", str(out), "--quiet",
            "--no-plots", *options]


CHILD_ENV = dict(os.environ, PYTHONPATH=str(ROOT))  # the child imports this tree


@contextmanager
def running(scenario: Path, out: Path, *options: str) -> Iterator[subprocess.Popen]:
    """``formation run`` as a child process (pipes for its output); killed if the test leaves
    it running."""
    proc = subprocess.Popen(run_args(scenario, out, *options), env=CHILD_ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def wait_for_file(proc: subprocess.Popen, path: Path, timeout_s: float) -> None:
    """Until the run writes ``path``; fails with the run's output if it ends first."""
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, f"no {path.name} after {timeout_s} s"
        time.sleep(0.05)


def test_run_reaches_every_goal_safely_and_as_fast_as_the_in_process_simulation(tmp_path, two):
    assert run_cli("sim", two, tmp_path / "sim") == 0
    assert run_cli("run", two, tmp_path / "run") == 0
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


def test_an_invalid_scenario_or_an_invalid_fault_option_exits_2_before_starting_anything(tmp_path,
                                                                                         two):
    bad = tmp_path / "bad.yaml"
    bad.write_text(TWO_FORMATIONS.replace("goal_tolerance", "goal_tolerence"), encoding="utf-8")
    out = tmp_path / "o"
    assert run_cli("run", bad, out, plots=True) == 2
    for option in (["--drop", "1.5"], ["--kill", "z9@1:2"], ["--camera-dropout", "a1@1"],
                   ["--pose-slots", "0"], ["--pose-slots", "2"]):  # (slots: not in lock-step)
        assert main(["run", str(two), "--out", str(out), *option]) == 2, option
    assert not (out / "processes.json").exists()


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


def test_a_run_interrupted_with_sigint_leaves_no_child_process_alive(tmp_path, long):
    out = tmp_path / "run"
    with running(long, out) as proc:
        wait_for_file(proc, out / "processes.json", 60)
        time.sleep(0.5)
        pids = json.loads((out / "processes.json").read_text())
        assert len(pids) == 1 + 5  # router and one agent per robot
        time.sleep(2.0)  # well inside the run (it needs minutes)
        assert proc.poll() is None
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130, err
    assert not [name for name, pid in pids.items() if _alive(pid)]
    # each child led its own session: nothing of theirs (grandchildren) is left either
    assert not set(pids.values()) & _sessions()


@pytest.mark.slow
def test_run_in_real_time_reaches_every_goal(tmp_path, two):
    assert run_cli("run", two, tmp_path / "rt", "--realtime") == 0
    run = json.loads((tmp_path / "rt" / "summary.json").read_text())
    assert run["all_reached"] is True and run["collisions"] == 0
    assert run["realtime"] is True
    assert run["world"]["latency_ms"]["samples"] > 0
    assert "pose_slots" not in run  # whole frames


@pytest.mark.slow
def test_run_in_real_time_with_poses_in_slots_reaches_every_goal_and_merges_the_agents_traces(
        tmp_path, two):
    """Issue 12: with pose slots every robot's pose goes out with its slot's own stamp; the
    agents' trace rows (status, slack, h_*) and the leaders' ellipses are keyed by it, so the
    merge must use it (it used the tick's first stamp: blank columns, no ellipses, and the safety
    figure failed on the empty series)."""
    out = tmp_path / "rt"
    assert run_cli("run", two, out, "--realtime", "--pose-slots", "4", plots=True) == 0
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


def test_a_second_sigint_only_hurries_the_shutdown_and_the_run_is_still_written(tmp_path, long):
    out = tmp_path / "run"
    with running(long, out, "--realtime") as proc:
        wait_for_file(proc, out / "endpoint", 120)  # every agent up, the world running
        proc.send_signal(signal.SIGINT)
        for _ in range(6):  # a hurried operator's further Ctrl-Cs over 0.3 s (the attack)
            time.sleep(0.05)
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err
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


def test_a_run_onto_a_disk_too_small_is_refused_before_it_starts(two, small_disk):
    out = small_disk / "run"
    proc = subprocess.run(run_args(two, out), env=CHILD_ENV, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "MB free" in lines[0] and "--out" in lines[0]
    assert not (out / "processes.json").exists() and not list(small_disk.rglob("*.tmp"))


def test_a_member_killed_mid_run_is_restarted_and_the_run_reaches_every_goal(tmp_path, two):
    out = tmp_path / "run"
    with running(two, out) as proc:
        wait_for_file(proc, out / "endpoint", 120)  # every agent up, the world running
        pids = json.loads((out / "processes.json").read_text())
        member = next(n for n in sorted(pids) if n.startswith("agent-"))
        os.kill(pids[member], signal.SIGKILL)  # a crash, not a stop: no counters, no zero cmd
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
    summary = json.loads((out / "summary.json").read_text())
    robot = member.removeprefix("agent-")
    assert summary["restarts"] == {robot: 1}
    assert summary["all_reached"] is True and summary["collisions"] == 0
    assert (out / "logs" / f"{member}#2.log").is_file()


@pytest.mark.parametrize("options, culprit", [
    (["--realtime", "--pose-slots", "2"], "--pose-slots"),
    (["--pose-zones", "1"], "--pose-zones"),
])
def test_a_fleet_with_options_lifelong_runs_lack_is_refused_in_one_line_before_anything_starts(
        tmp_path, capsys, options, culprit):
    out = tmp_path / "run"
    path = ROOT / "tests" / "scenarios" / "lifelong-one-pallet.yaml"
    assert main(["run", str(path), "--out", str(out), "--quiet", "--no-plots", *options]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fleet" in err[0] and culprit in err[0]
    assert not (out / "processes.json").exists()
