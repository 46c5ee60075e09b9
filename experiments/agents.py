"""N real agent processes against the simulated world in real time (the **agents** part of
:mod:`experiments.bench`; definitions of latency, missed ticks, CPU and memory there)."""

from __future__ import annotations

import json
import logging
import statistics
import time
from pathlib import Path

from experiments.fleet_scenario import fleet_scenario
from experiments.machine import load_avg, machine_busy_s, percentile, proc_cpu_s, proc_rss_mb

logger = logging.getLogger(__name__)


def bench_agents(n: int, dt: float, duration: float, work: Path, tick_on_pose: bool = True,
                 pose_slots: int = 1, viewer: bool = False) -> dict:
    """Run ``n`` agent processes in real time against the simulated world for ``duration``
    seconds (see the module docstring); every process started here is stopped on every way out.
    ``tick_on_pose=False`` runs the agents with ``--clock-ticks`` (their own clock);
    ``pose_slots`` is the world's (:class:`simulator.world.WorldOptions`); ``viewer`` attaches
    ``formation view --connect`` to the router (the live page and Foxglove WebSocket)."""
    import zenoh

    from wire.zconf import use_zenoh_threads

    use_zenoh_threads("relay")  # as `formation bench` does, for a direct call too

    from agent.config import build_agent_configs
    from simulator.fleet import START_TIMEOUT_S, Fleet
    from simulator.world import World, WorldOptions
    from wire.ports import free_tcp_port, tcp_endpoint
    from wire.zconf import ZenohSettings

    scenario = fleet_scenario(n, dt, duration)
    for sub in ("configs", "agents", "logs"):
        (work / sub).mkdir(parents=True, exist_ok=True)
    port = free_tcp_port()
    endpoint = tcp_endpoint(port)
    load_before = load_avg()
    with Fleet(work / "logs") as fleet:
        router = fleet.start_router(endpoint, port)
        zs = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False)
        agents = fleet.start_agents(build_agent_configs(scenario, zenoh=zs), work,
                                    lambda _rid: ["--no-trace", *([] if tick_on_pose else ["--clock-ticks"])])
        if viewer:
            fleet.start("viewer", ["-m", "formation", "view", "--connect", endpoint, "--port", "0"])
        conf = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                                 connect_timeout_s=10.0).to_config()
        options = WorldOptions(realtime=True, stop_at_goal=False, record=False, pose_slots=pose_slots,
                               start_timeout=START_TIMEOUT_S + 4.0 * n)
        pids = {rid: c.proc.pid for rid, c in agents.items()}
        with zenoh.open(conf) as session:
            world = World(scenario, session, options)
            try:
                world.wait_for_agents(abort=fleet.check)
                cpu0 = {rid: proc_cpu_s(pid) for rid, pid in pids.items()}
                router_cpu0 = proc_cpu_s(router.proc.pid)
                own0 = time.process_time()
                busy0 = machine_busy_s()
                result = world.run(abort=fleet.check)
                own_cpu = time.process_time() - own0
                busy1 = machine_busy_s()
                cpu1 = {rid: proc_cpu_s(pid) for rid, pid in pids.items()}
                router_cpu1 = proc_cpu_s(router.proc.pid)
                rss = {rid: proc_rss_mb(pid) for rid, pid in pids.items()}
                router_rss = proc_rss_mb(router.proc.pid)
            finally:
                world.close()
        load_after = load_avg()
        fleet.shut_down(list(agents.values()), router)
    stats = []
    for rid in agents:
        try:
            stats.append(json.loads((work / "agents" / f"{rid}.json").read_text(encoding="utf-8")))
        except (OSError, ValueError):
            logger.warning("agent %s wrote no counters", rid)
    busy = None if busy0 is None or busy1 is None else busy1 - busy0
    entry = _agents_entry(n, dt, result, stats, cpu0, cpu1, rss, own_cpu,
                          (router_cpu0, router_cpu1, router_rss), (load_before, load_after), busy)
    entry["ticks_on"] = "pose" if tick_on_pose else "clock"
    entry["pose_slots"] = pose_slots
    return entry


def _agents_entry(n, dt, result, stats, cpu0, cpu1, rss, own_cpu, router, loads, busy) -> dict:
    from simulator.launch import sum_counts

    wall = result.wall_s
    lat = result.latency_ms
    period_ms = dt * 1e3
    poses = n * result.steps - result.camera_dropped
    in_time = sum(1 for x in lat if x <= period_ms)
    cpu_pct = [100.0 * (cpu1[r] - cpu0[r]) / wall for r in cpu0
               if cpu0[r] is not None and cpu1.get(r) is not None and wall > 0]
    rss_mb = [v for v in rss.values() if v is not None]

    def med(key: str) -> float | None:
        vals = [s[key] for s in stats if s.get(key) is not None]
        return statistics.median(vals) if vals else None

    p50 = statistics.median(lat) if lat else None
    pose_age, tick_us = med("pose_age_us_median"), med("tick_us_median")
    pose_wait = None if pose_age is None else pose_age / 1e3
    tick = None if tick_us is None else tick_us / 1e3
    transport = None
    if p50 is not None and pose_wait is not None and tick is not None:
        transport = p50 - pose_wait - tick
    r0, r1, rrss = router
    ours = sum(cpu1[r] - cpu0[r] for r in cpu0 if cpu0[r] is not None and cpu1.get(r) is not None)
    ours += own_cpu + (0.0 if r0 is None or r1 is None else r1 - r0)
    return {
        "robots": n,
        "rate_hz_target": 1.0 / dt,
        "duration_s": wall,
        "world_rate_hz": result.steps / wall if wall > 0 else None,
        "rate_hz": len(lat) / (n * wall) if wall > 0 else None,
        "poses": poses,
        "commands": len(lat),
        "missed_ticks": poses - in_time,
        "agent_overruns": sum(s.get("overruns", 0) for s in stats),
        "stale_ticks": sum(s.get("stale", 0) for s in stats),
        "stale_ticks_by_input": sum_counts(s.get("stale_why", {}) for s in stats),
        "latency_ms_p50": p50,
        "latency_ms_p99": percentile(lat, 0.99) if lat else None,
        "latency_ms_max": max(lat) if lat else None,
        "latency_parts_ms_median": {"pose_wait_for_tick": pose_wait, "tick": tick,
                                    "transport_rest": transport},
        "solve_us_median": med("solve_us_median"),
        "cpu_percent_per_agent_median": statistics.median(cpu_pct) if cpu_pct else None,
        "cpu_percent_per_agent_max": max(cpu_pct) if cpu_pct else None,
        "rss_mb_per_agent_median": statistics.median(rss_mb) if rss_mb else None,
        "rss_mb_per_agent_max": max(rss_mb) if rss_mb else None,
        "router_cpu_percent": None if r0 is None or r1 is None else 100.0 * (r1 - r0) / wall,
        "router_rss_mb": rrss,
        "world_cpu_percent": 100.0 * own_cpu / wall if wall > 0 else None,
        "load_avg_1min": {"before": loads[0], "after": loads[1]},
        "fleet_cpu_percent": 100.0 * ours / wall if wall > 0 else None,
        # other people's processes on the machine meanwhile (percent of one core; 2 cores = 200)
        "others_cpu_percent": None if busy is None or wall <= 0 else
        max(0.0, 100.0 * (busy - ours) / wall),
    }
