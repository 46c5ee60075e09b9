"""Whether a local run's fleet fits this machine, estimated before any process starts.

A valid scenario of 13,312 robots passed ``check`` and ``run`` started agents until fork failed
(about 280 GB needed, 23 GB here). :func:`fleet_needs` estimates what a run needs from the
robots and the options that shape its processes; :func:`machine_has` reads what the machine
grants (memory available, the cgroup's memory and process limits where the run is inside one,
the file descriptor limit); :func:`refusal` compares the two and names the first limit passed,
with the options that would fit. The figures are measured (``/proc/PID/smaps_rollup`` of a
running fleet, Pss), with :data:`HEADROOM` on top.
"""

from __future__ import annotations

import math
import resource
from dataclasses import dataclass
from pathlib import Path

AGENT_PROCESS_MB = 28.0  # one agent process (thesis-6.3, Pss 27.9 MB each)
HOST_PROCESS_MB = 27.0  # an agent host's own part (16 agents: 35.3-36.2 MB, 8 agents: 31.6 MB)
HOSTED_AGENT_MB = 0.6  # each agent inside a host
FIXED_MB = 400.0  # the router, the world, the launcher with its figures
HEADROOM = 1.5  # estimates are typical figures: keep this factor free
FDS_PER_PROCESS = 4  # the launcher's pipes and log file per child
FDS_FIXED = 256
PROCESSES_FIXED = 8  # router, world, launcher, zone routers, camera


@dataclass(frozen=True)
class Needs:
    processes: int
    memory_mb: float
    fds: int


@dataclass(frozen=True)
class Machine:
    memory_mb: float  # available to the run (MemAvailable, or the cgroup's room if smaller)
    processes: int | None  # room for more processes (the cgroup's pids.max), None: no limit read
    fds: int  # this process's soft RLIMIT_NOFILE


def fleet_needs(robots: int, agents_per_process: int = 1, remote_robots: int = 0) -> Needs:
    """What a run of ``robots`` agents needs here, ``remote_robots`` of them on other hosts."""
    local = max(0, robots - remote_robots)
    k = max(1, agents_per_process)
    processes = math.ceil(local / k)
    if k == 1:
        agents_mb = local * AGENT_PROCESS_MB
    else:
        agents_mb = processes * HOST_PROCESS_MB + local * HOSTED_AGENT_MB
    return Needs(processes + PROCESSES_FIXED, (agents_mb + FIXED_MB) * HEADROOM,
                 (processes + PROCESSES_FIXED) * FDS_PER_PROCESS + FDS_FIXED)


def _read_number(path: Path) -> float | None:
    """A limit file's number; None where it is missing, unreadable or ``max``."""
    try:
        text = path.read_text(encoding="ascii").split()[0]
    except (OSError, IndexError, UnicodeDecodeError):
        return None
    try:
        return float(text)
    except ValueError:
        return None


def _mem_available_mb(proc: Path) -> float | None:
    try:
        for line in (proc / "meminfo").read_text(encoding="ascii").splitlines():
            if line.startswith("MemAvailable:"):
                return float(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_memory_room_mb(cgroup: Path) -> float | None:
    limit = _read_number(cgroup / "memory.max")  # v2
    used = _read_number(cgroup / "memory.current")
    if limit is None:
        limit = _read_number(cgroup / "memory" / "memory.limit_in_bytes")  # v1
        used = _read_number(cgroup / "memory" / "memory.usage_in_bytes")
    if limit is None or limit >= 2**60:  # v1 writes a huge number for "no limit"
        return None
    return max(0.0, limit - (used or 0.0)) / 2**20


def _cgroup_process_room(cgroup: Path) -> int | None:
    limit = _read_number(cgroup / "pids.max")
    if limit is None:
        limit = _read_number(cgroup / "pids" / "pids.max")
    if limit is None:
        return None
    used = _read_number(cgroup / "pids.current") or 0.0
    return max(0, int(limit - used))


def machine_has(proc: Path = Path("/proc"), cgroup: Path = Path("/sys/fs/cgroup")) -> Machine:
    """What this machine grants a run (the paths are parameters for tests)."""
    mem = [m for m in (_mem_available_mb(proc), _cgroup_memory_room_mb(cgroup)) if m is not None]
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    fds = soft if soft != resource.RLIM_INFINITY else 1 << 20
    return Machine(min(mem) if mem else math.inf, _cgroup_process_room(cgroup), int(fds))


def fitting_agents_per_process(robots: int, machine: Machine) -> int | None:
    """The smallest ``--agents-per-process`` whose fleet fits ``machine``, or None."""
    for k in (1, 2, 4, 8, 16, 32, 64, 128, 256):
        if refusal(robots, machine, k, suggest=False) is None:
            return k
    return None


def refusal(robots: int, machine: Machine, agents_per_process: int = 1, remote_robots: int = 0,
            suggest: bool = True) -> str | None:
    """One line naming the first limit a run would pass and the options that would fit, or None."""
    need = fleet_needs(robots, agents_per_process, remote_robots)
    if need.memory_mb > machine.memory_mb:
        why = (f"needs about {need.memory_mb / 1024:.1f} GB of memory for {robots} agents, "
               f"{machine.memory_mb / 1024:.1f} GB is available")
    elif machine.processes is not None and need.processes > machine.processes:
        why = f"needs {need.processes} processes, the cgroup allows {machine.processes} more"
    elif need.fds > machine.fds:
        why = f"needs about {need.fds} file descriptors, the limit is {machine.fds} (ulimit -n)"
    else:
        return None
    hint = "run agents on robots or other machines with --hosts INVENTORY"
    k = fitting_agents_per_process(robots, machine) if suggest and agents_per_process == 1 else None
    if k is not None:
        hint = f"--agents-per-process {k} fits, or {hint}"
    return f"this fleet does not fit this machine: it {why}; {hint}"

