"""A run fits the machine or is refused before any process starts (simulator.capacity)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from simulator.capacity import Machine, fleet_needs, machine_has, refusal

GB = 1024.0  # MB
ROOT = Path(__file__).resolve().parent.parent


def _fake(tmp_path: Path, avail_kb: int, files: dict[str, str]) -> tuple[Path, Path]:
    proc, cg = tmp_path / "proc", tmp_path / "cg"
    proc.mkdir(parents=True)
    cg.mkdir(parents=True)
    (proc / "meminfo").write_text(f"MemTotal: 99 kB\nMemAvailable: {avail_kb} kB\n")
    for name, text in files.items():
        (cg / name).parent.mkdir(parents=True, exist_ok=True)
        (cg / name).write_text(text)
    return proc, cg


def test_the_13312_robot_fleet_is_refused_on_this_machines_size_naming_memory():
    line = refusal(13_312, Machine(23 * GB, None, 1 << 20))
    assert line is not None and "memory" in line and "13312 agents" in line and "\n" not in line
    assert "--hosts" in line


def test_a_fleet_that_fits_in_hosts_is_told_which_agents_per_process_fits():
    line = refusal(600, Machine(8 * GB, None, 1 << 20))
    assert line is not None and "--agents-per-process" in line
    k = int(line.split("--agents-per-process ")[1].split()[0])
    assert refusal(600, Machine(8 * GB, None, 1 << 20), agents_per_process=k) is None


def test_the_demo_fits():
    assert refusal(12, Machine(4 * GB, 500, 1024)) is None


@given(st.integers(1, 20_000), st.sampled_from([1, 2, 16, 64]))
def test_needs_grow_with_the_fleet(robots, k):
    a, b = fleet_needs(robots, k), fleet_needs(robots + 1, k)
    assert b.memory_mb >= a.memory_mb and b.processes >= a.processes and b.fds >= a.fds
    assert fleet_needs(robots, k, remote_robots=robots).processes == fleet_needs(0, k).processes


def test_cgroup_v2_limits_are_read_and_the_smaller_memory_wins(tmp_path):
    proc, cg = _fake(tmp_path, 16 * 2**20, {"memory.max": str(8 * 2**30), "memory.current": "0",
                                             "pids.max": "100", "pids.current": "40"})
    m = machine_has(proc, cg)
    assert m.memory_mb == 8 * GB and m.processes == 60
    line = refusal(70, m)
    assert line is not None and "processes" in line


def test_cgroup_v1_and_no_limit(tmp_path):
    proc, cg = _fake(tmp_path, 4 * 2**20, {"memory/memory.limit_in_bytes": str(2**63 - 4096),
                                           "pids.max": "max"})
    m = machine_has(proc, cg)
    assert m.memory_mb == 4 * GB and m.processes is None
    proc2, cg2 = _fake(tmp_path / "b", 4 * 2**20, {"memory/memory.limit_in_bytes": str(2**30),
                                                   "memory/memory.usage_in_bytes": str(2**29)})
    assert machine_has(proc2, cg2).memory_mb == 512.0


def test_the_file_descriptor_limit_is_named():
    line = refusal(400, Machine(1e9, None, 256), agents_per_process=1)
    assert line is not None and "ulimit -n" in line


def _huge_scenario(nf: int = 256, nr: int = 52) -> str:
    """A valid scenario of nf * nr robots (13,312: the largest under the 1 MiB file limit the
    issue met): each formation a star on its leader plus a path, rigid and leader-adjacent."""
    out = ["name: huge", "dt: 0.05",
           "robot: {model: single_integrator, max_speed: 0.22, radius: 0.105}", "formations:"]
    for f in range(nf):
        fx, fy, ids = (f % 16) * 20, (f // 16) * 20, [f"r{f * nr + r}" for r in range(nr)]
        out += [f"- name: F{f}", f"  leader: {ids[0]}", "  robots:"]
        for r, rid in enumerate(ids):
            x, y = fx + r % 8, fy + r // 8 + (r * r % 7) / 10
            out.append(f"    {rid}: {{start: [{x},{y:g}], goal: [{x + 5},{y:g}]}}")
        edges = [(ids[0], i) for i in ids[1:]] + [(ids[r], ids[r - 1]) for r in range(2, nr)]
        out.append("  edges: [" + ",".join(f"[{a},{b}]" for a, b in edges) + "]")
    return "\n".join(out) + "\n"


@pytest.mark.integration
def test_the_13312_robot_file_is_refused_by_run_before_any_agent_starts_and_check_warns(tmp_path):
    scenario = tmp_path / "huge.yaml"
    scenario.write_text(_huge_scenario())
    if refusal(13_312, machine_has()) is None:
        pytest.skip("this machine holds 13,312 agents")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "formation", "run", str(scenario), "--out",
                          str(out), "--quiet", "--no-plots"], env=env, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "13312 agents" in lines[0] and "--no-capacity-check" in lines[0]
    assert not out.exists()  # nothing started, nothing written
    check = subprocess.run([sys.executable, "-m", "formation", "check", str(scenario)], env=env,
                           capture_output=True, text=True, timeout=600)
    assert check.returncode == 0 and "warning: this fleet does not fit" in check.stderr
