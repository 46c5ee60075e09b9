"""N real agent processes against the simulated world in real time (the **agents** part of
:mod:`experiments.bench`; definitions of latency, missed ticks, CPU and memory there)."""

from __future__ import annotations

import json
import logging
import statistics
import time
from collections.abc import Iterable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import zenoh

from agent.config import build_agent_configs
from agent.stats import AgentStats
from agent.tick_times import TICK_PARTS
from experiments.fleet_scenario import fleet_scenario
from experiments.machine import load_avg, machine_busy_s, percentile, proc_cpu_s, proc_rss_mb
from runtime.ports import free_tcp_port, tcp_endpoint
from simulator.fleet import START_TIMEOUT_S, Fleet, unique_children
from simulator.series import WorldResult
from simulator.summary import sum_counts
from simulator.world import World, WorldOptions
from simulator.zones import PoseZones
from wire.zconf import ZenohSettings, use_zenoh_threads

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Hosts:
    """How a bench fleet's agents run: ``per_process`` K to an agent host (:mod:`agent.host`;
    1: a process each), one Zenoh session per host (``shared_session``), and with ``stalls``
    each host records what holds its ticks back (``--stalls``, :mod:`agent.stalls`)."""

    per_process: int = 1
    shared_session: bool = False
    stalls: bool = False


def bench_agents(n: int, dt: float, duration: float, work: Path, tick_on_pose: bool = True,
                 pose_slots: int = 1, viewer: bool = False, hosting: Hosts = Hosts(),
                 pose_zones: int = 0) -> dict:
    """Run ``n`` agent processes in real time against the simulated world for ``duration``
    seconds (see the module docstring); every process started here is stopped on every way out.
    ``tick_on_pose=False`` runs the agents with ``--clock-ticks`` (their own clock);
    ``pose_slots`` is the world's (:class:`simulator.world.WorldOptions`); ``viewer`` attaches
    ``formation view --connect`` to the router (the live page and Foxglove WebSocket);
    ``hosting`` (:class:`Hosts`): with K > 1 agents to an agent host, each agent's CPU and
    memory are its host's divided by the agents it runs, and with ``stalls`` the entry's
    ``stalls`` sums up the hosts' reports (:func:`stalls_summary`). ``pose_zones`` Z > 0: the
    world's poses and the agents' commands go through Z zone routers of the world's process
    (:mod:`simulator.zones`), each agent connected to its zone's; 0: everything through the one
    router (the default)."""
    use_zenoh_threads("relay")  # as `formation bench` does, for a direct call too
    per_process, shared_session = hosting.per_process, hosting.shared_session
    stalls = work / "stalls" if hosting.stalls and per_process > 1 else None
    extra = ["--no-trace", *([] if tick_on_pose else ["--clock-ticks"]),
             *([] if stalls is None else ["--stalls", str(stalls)])]
    scenario = fleet_scenario(n, dt, duration)
    for sub in ("configs", "agents", "logs"):
        (work / sub).mkdir(parents=True, exist_ok=True)
    port = free_tcp_port()
    endpoint = tcp_endpoint(port)
    load_before = load_avg()
    with Fleet(work / "logs") as fleet, ExitStack() as stack:
        router = fleet.start_router(endpoint, port)
        zs = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False)
        configs = build_agent_configs(scenario, zenoh=zs)
        if pose_zones:
            stack.enter_context(zones := PoseZones(scenario, pose_zones, endpoint, per_process))
            configs = {rid: replace(c, zenoh=replace(c.zenoh, connect=(zones.endpoint_of(rid),)))
                       for rid, c in configs.items()}
        agents = fleet.start_agents(configs, work, lambda _rid: extra,
                                    per_process=per_process, shared_session=shared_session)
        if viewer:
            fleet.start("viewer", ["-m", "formation", "view", "--connect", endpoint, "--port", "0"])
        conf = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                                 connect_timeout_s=10.0).to_config()
        options = WorldOptions(realtime=True, stop_at_goal=False, record=False, pose_slots=pose_slots,
                               start_timeout=START_TIMEOUT_S + 4.0 * n)
        hosts = unique_children(agents.values())
        pids = {h.name: h.proc.pid for h in hosts}
        share = {h.name: 1.0 / sum(1 for c in agents.values() if c is h) for h in hosts}
        with zenoh.open(conf) as session:
            world = World(scenario, session, options, zones.sessions if pose_zones else (),
                          zones.zone_of if pose_zones else None)
            try:
                world.wait_for_agents(abort=fleet.check)
                cpu0 = {name: proc_cpu_s(pid) for name, pid in pids.items()}
                router_cpu0 = proc_cpu_s(router.proc.pid)
                own0 = time.process_time()
                busy0 = machine_busy_s()
                result = world.run(abort=fleet.check)
                own_cpu = time.process_time() - own0
                busy1 = machine_busy_s()
                cpu1 = {name: proc_cpu_s(pid) for name, pid in pids.items()}
                router_cpu1 = proc_cpu_s(router.proc.pid)
                rss = {name: proc_rss_mb(pid) for name, pid in pids.items()}
                router_rss = proc_rss_mb(router.proc.pid)
            finally:
                world.close()
        load_after = load_avg()
        fleet.shut_down(hosts, router)
    stats = []
    for rid in agents:
        try:
            stats.append(AgentStats.from_json_dict(
                json.loads((work / "agents" / f"{rid}.json").read_text(encoding="utf-8"))))
        except (OSError, ValueError, TypeError):
            logger.warning("agent %s wrote no counters", rid)
    busy = None if busy0 is None or busy1 is None else busy1 - busy0
    entry = _agents_entry(n, dt, result, stats, FleetUsage(
        cpu0, cpu1, rss, share, own_cpu, (router_cpu0, router_cpu1, router_rss),
        (load_before, load_after), busy))
    entry["ticks_on"] = "pose" if tick_on_pose else "clock"
    entry["pose_slots"] = pose_slots
    entry["agents_per_process"] = per_process
    entry["shared_session"] = shared_session
    entry["pose_zones"] = pose_zones
    if stalls is not None:
        entry["stalls"] = stalls_summary(read_stalls(stalls))
    return entry


def read_stalls(folder: Path) -> list[dict]:
    """Every host's ``--stalls`` report in ``folder`` (one that is missing or unreadable is
    left out, with a warning)."""
    reports = []
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        try:
            reports.append(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError) as exc:
            logger.warning("stalls report %s: %s", path, exc)
    return reports


def stalls_summary(reports: Sequence[dict]) -> dict:
    """The hosts' ``--stalls`` reports (:mod:`agent.stalls`) in one: per generation the
    collections a minute per host, their longest pause and how many fell inside a tick; the heap
    (median over the hosts); the ticks' CPU 99th percentile (median over the hosts) and longest
    wall time; the three longest ticks of all; the route-plan workers' CPU seconds."""
    gens: dict[str, dict] = {}
    for g in ("0", "1", "2"):
        rows = [r["gc"][g] for r in reports if g in r.get("gc", {})]
        pauses = [x["wall_ms_max"] for x in rows if x.get("wall_ms_max") is not None]
        gens[g] = {"per_minute_per_host": _median(x.get("per_minute") for x in rows),
                   "cpu_ms_median": _median(x.get("cpu_ms_median") for x in rows),
                   "wall_ms_max": max(pauses) if pauses else None,
                   "in_ticks": sum(x.get("in_ticks", 0) for x in rows)}
    ticks = [r.get("ticks", {}) for r in reports]
    walls = [t["wall_ms_max"] for t in ticks if t.get("wall_ms_max") is not None]
    longest = sorted((row for r in reports for row in r.get("longest_ticks", [])),
                     key=lambda row: -row["wall_ms"])[:3]
    return {
        "hosts": len(reports), "gc": gens,
        "heap_objects": _median(r.get("heap_objects") for r in reports),
        "frozen_objects": _median(r.get("frozen_objects") for r in reports),
        "modules": _median(r.get("modules") for r in reports),
        "tick_cpu_ms_p99": _median(t.get("cpu_ms_p99") for t in ticks),
        "tick_wall_ms_max": max(walls) if walls else None,
        "longest_ticks": longest,
        "plan_worker_cpu_s": round(sum(sum(r.get("children_cpu_s", {}).values())
                                       for r in reports), 3),
    }


@dataclass(frozen=True)
class FleetUsage:
    """What a fleet's processes used over a run: ``cpu0``/``cpu1`` [s] (CPU time before and
    after) and ``rss`` [MB] per agent process (or host), ``share`` the part of each that one
    agent counts as its own (1/K for a host of K), ``own_cpu`` [s] the world's process's CPU
    time, ``router`` its (CPU before, CPU after, RSS), ``loads`` the load average before and
    after, ``busy`` [s] the machine's busy time meanwhile (None if unknown)."""

    cpu0: dict[str, float | None]
    cpu1: dict[str, float | None]
    rss: dict[str, float | None]
    share: dict[str, float]
    own_cpu: float
    router: tuple[float | None, float | None, float | None]
    loads: tuple[Any, Any]
    busy: float | None

    def cpu_used(self) -> dict[str, float]:
        """CPU time [s] each agent process (or host) used over the run, where both are known."""
        out: dict[str, float] = {}
        for r, before in self.cpu0.items():
            after = self.cpu1.get(r)
            if before is not None and after is not None:
                out[r] = after - before
        return out


def _agents_entry(n: int, dt: float, result: WorldResult, stats: Sequence[AgentStats],
                  usage: FleetUsage) -> dict:
    """One fleet's figures (see :class:`FleetUsage`)."""
    rss, share, router, loads, busy = usage.rss, usage.share, usage.router, usage.loads, usage.busy
    used = usage.cpu_used()
    wall = result.wall_s
    lat = result.latency_ms
    period_ms = dt * 1e3
    poses = n * result.steps - result.camera_dropped
    in_time = sum(1 for x in lat if x <= period_ms)
    cpu_pct = [100.0 * share[r] * u / wall for r, u in used.items() if wall > 0]
    rss_mb = [share[r] * v for r, v in rss.items() if v is not None]

    p50 = statistics.median(lat) if lat else None
    pose_age = _median(s.pose_age_us_median for s in stats)
    tick_us = _median(s.tick_us_median for s in stats)
    pose_in_us = _median(s.pose_in_us_median for s in stats)
    pose_wait = None if pose_age is None else pose_age / 1e3
    tick = None if tick_us is None else tick_us / 1e3
    pose_in = None if pose_in_us is None else pose_in_us / 1e3
    transport = cmd_back = None
    if p50 is not None and pose_wait is not None and tick is not None:
        transport = p50 - pose_wait - tick
        if pose_in is not None:
            cmd_back = transport - pose_in
    r0, r1, rrss = router
    ours = sum(used.values())
    ours += usage.own_cpu + (0.0 if r0 is None or r1 is None else r1 - r0)
    return {
        "robots": n,
        "rate_hz_target": 1.0 / dt,
        "duration_s": wall,
        "world_rate_hz": result.steps / wall if wall > 0 else None,
        "rate_hz": len(lat) / (n * wall) if wall > 0 else None,
        "poses": poses,
        "commands": len(lat),
        "missed_ticks": poses - in_time,
        "agent_overruns": sum(s.overruns for s in stats),
        # poses never ticked on: stamped too soon after the camera's schedule
        # (agent.schedule.pose_due), or replaced by a newer one while an agent host was busy
        "early_poses": sum(s.early_poses for s in stats),
        "superseded_poses": sum(s.superseded_poses or 0 for s in stats),
        "stale_ticks": sum(s.stale for s in stats),
        "stale_ticks_by_input": sum_counts(s.stale_why for s in stats),
        "latency_ms_p50": p50,
        "latency_ms_p99": percentile(lat, 0.99) if lat else None,
        "latency_ms_max": max(lat) if lat else None,
        "latency_parts_ms_median": {"pose_wait_for_tick": pose_wait, "tick": tick,
                                    "transport_rest": transport,
                                    # transport_rest split: pose stamp -> agent received, and the
                                    # rest (command put -> world received)
                                    "pose_in": pose_in, "cmd_back": cmd_back},
        # the world's one thread: tick start -> its last pose put (median over ticks)
        "world_publish_ms_median": (statistics.median(result.publish_ms)
                                    if result.publish_ms else None),
        "solve_us_median": _median(s.solve_us_median for s in stats),
        "tick_parts_ms_median": tick_parts(stats),
        "cpu_percent_per_agent_median": statistics.median(cpu_pct) if cpu_pct else None,
        "cpu_percent_per_agent_max": max(cpu_pct) if cpu_pct else None,
        "rss_mb_per_agent_median": statistics.median(rss_mb) if rss_mb else None,
        "rss_mb_per_agent_max": max(rss_mb) if rss_mb else None,
        "router_cpu_percent": None if r0 is None or r1 is None else 100.0 * (r1 - r0) / wall,
        "router_rss_mb": rrss,
        "world_cpu_percent": 100.0 * usage.own_cpu / wall if wall > 0 else None,
        "load_avg_1min": {"before": loads[0], "after": loads[1]},
        "fleet_cpu_percent": 100.0 * ours / wall if wall > 0 else None,
        # other people's processes on the machine meanwhile (percent of one core)
        "others_cpu_percent": None if busy is None or wall <= 0 else
        max(0.0, 100.0 * (busy - ours) / wall),
    }


def tick_parts(stats: Sequence[AgentStats]) -> dict[str, float | None]:
    """Per part of the tick (:data:`agent.tick_times.TICK_PARTS`): the median over the agents of
    each agent's median [ms] (a part an agent never ran, e.g. ``leader`` on a member, is left
    out of that part's median)."""
    parts = [s.tick_parts_us_median for s in stats]
    out: dict[str, float | None] = {}
    for name in TICK_PARTS:
        us = _median(p.get(name) for p in parts)
        out[name] = None if us is None else us / 1e3
    return out


def _median(values: Iterable[float | None]) -> float | None:
    """The median of the agents' figures that are known (None if none is)."""
    known = [v for v in values if v is not None]
    return statistics.median(known) if known else None
