"""``formation bench``: how fast the control step, the QP and the multi-process fleet are.

Eight measurements, written to ``bench.json`` and as a table (``bench.txt`` and stdout):

* **step**: one robot's full control step (:meth:`agent.control.Controller.step`: nominal command,
  barrier rows, QP) for a robot of a 4-robot formation with 2 obstacles and 3 other formations
  in view, with its two parts (:func:`agent.control.build_rows` and the exact solve) apart,
  and the same step for a single and a double integrator side by side (``by_model``).
* **solvers**: the exact solver against the qpsolvers backends on the real QP instances the
  in-process simulator posed on a scenario (default: the warehouse), interleaved in one process
  so machine noise hits them alike; medians, with the worst disagreement against the exact one.
* **central**: Robotarium-style centralized solving for comparison: one QP over every robot's
  velocity (2N variables) with the formation-edge rows coupling neighbours, a collision row for
  every pair of robots of different formations (Robotarium's barrier certificate), and each
  robot's obstacle, other-formation-ellipse and speed rows; sparse matrices for osqp/clarabel,
  dense for daqp/quadprog. Against it: the N per-robot control steps on the same snapshot.
* **agents**: N real agent processes (``python -m agent``, real time) over a Zenoh router with
  the simulated world (:class:`simulator.world.World`) publishing poses at the control rate in
  this process; N/4 four-robot formations travelling in parallel lanes, so the run is steady.
  Every pose of a tick leaves at once, as from one overhead camera frame. For comparison, the
  32- and 64-agent fleets also run with the world publishing each formation's poses in its own
  slot of the period (``agents_pose_slots``, ``pose_slots`` = N/4), as robots localising on
  their own clocks would, so the N agents do not all wake in the same instant on one shared
  machine (on robots each agent has its own CPU), and one fleet runs with agents ticking on
  their own clock (``agents_clock_ticks``). Reported per fleet: achieved command rate, missed ticks, pose ->
  command latency (p50, p99) and its parts, CPU and memory (RSS) per agent, the agents'
  stale ticks (zero commands) by the input that was stale, and where the tick goes (its parts,
  :mod:`agent.tick_times`: inbox, pose, leader, inputs, route, step, command, record, state).
* **inprocess**: simulation throughput (robot-steps per second) of ``formation sim`` on the
  warehouse scenario.
* **viewer** (:mod:`experiments.recording`): ``recording``, the same throughput without the time series,
  with it, and with ``run.mcap`` written too; ``agents_viewer``, the first fleet of **agents**
  again with ``formation view`` attached to its router (the latency a live viewer costs).
* **camera**: capture -> publish latency (p50, p99) of the real camera process at 1280x960,
  15 fps, 16 robots (:mod:`experiments.camera`).
* **scenario_loading**: validating and loading 100- and 1,000-robot fleet files
  (:mod:`scenario.bench`).

Definitions: the latency of a command is ``receive time - stamp`` of the pose it was computed
from, both on this machine's wall clock (the world stamps poses with ``time.time()``). A *missed
tick* is a pose for which no command computed from it arrived within one control period (the
robot drove a period on an older command); agents also count their own deadline overruns, and
the poses they never ticked on (``early_poses``: stamped too soon after the camera's schedule;
``superseded_poses``: replaced by a newer pose while their agent host was busy). CPU
is ``utime + stime`` from ``/proc/PID/stat`` over the steady run (all threads, Zenoh's included),
as a percentage of one core; memory is ``VmRSS`` of ``/proc/PID/status`` at the end of the run.

``formation bench --fleets N@HZ,...`` (:func:`run_fleets`) runs only the **agents** part for the
fleets asked, optionally in agent hosts (``--agents-per-process K``, :mod:`agent.host`), each fleet
``--repeat`` times, every run with its own load average.

The machine's load average is recorded beside every timing: timings taken under other load are
upper bounds.
"""

from __future__ import annotations

import logging
import math
import os
import platform
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from agent.barriers import Neighbour, Obstacle
from agent.control import Controller, ControlParams, FormationView, StepInput, build_rows
from agent.qp import Row, qpsolvers_solver, solve_exact
from experiments.agents import Hosts, bench_agents
from experiments.central import CENTRAL_BACKENDS, bench_central
from experiments.machine import load_avg, percentile, timed
from experiments.recording import bench_recording
from geometry.ellipse import Ellipse
from scenario.bench import QUICK_SIZES, SIZES, bench_loading, format_loading

logger = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENARIO = ROOT / "scenarios" / "warehouse.yaml"
BACKENDS = ("osqp", "daqp", "quadprog", "clarabel")
FLEETS = {8: 0.02, 32: 0.02, 64: 0.05}  # agents -> control period [s] (50, 50, 20 Hz)
FLEET_DURATION = 15.0  # [s] of real time per fleet
CLOCK_FLEETS = {8: 0.02}  # the same agents ticking on their own clock, for comparison
SLOT_FLEETS = {32: 0.02, 64: 0.05}  # the world publishing one formation's poses per slot, to compare
QUICK_FLEETS = {4: 0.02}
QUICK_DURATION = 2.0  # [s]


# ------------------------------------------------------------------------------ QP instances


def collect_instances(scenario_path: Path, limit: int,
                      duration: float | None = None) -> list[tuple[float, float, list[Row]]]:
    """Every full QP (first solve of a tick) the simulator posed, up to ``limit``, evenly spread;
    ``duration`` cuts the scenario's simulated time short."""
    from scenario import load_scenario
    from simulator.inprocess import SimOptions, simulate

    seen: list[tuple[float, float, list[Row]]] = []

    def recording(ux: float, uy: float, rows: Sequence[Row], tol: float = 1e-9):
        seen.append((ux, uy, list(rows)))
        return solve_exact(ux, uy, rows, tol)

    scenario = load_scenario(scenario_path)
    if duration is not None:
        scenario = replace(scenario, duration=min(duration, scenario.duration))
    simulate(scenario, SimOptions(record=False, solve_fn=recording))
    step = max(1, len(seen) // limit)
    return seen[::step][:limit]


def time_solver(solve: Callable, instances, repeat: int) -> tuple[list[float], list]:
    """Best-of-``repeat`` wall time [us] of ``solve`` on each instance, and its answers."""
    times, results = [], []
    for ux, uy, rows in instances:
        best = math.inf
        for _ in range(repeat):
            t0 = time.perf_counter_ns()
            out = solve(ux, uy, rows)
            best = min(best, time.perf_counter_ns() - t0)
        times.append(best * 1e-3)
        results.append(out)
    return times, results


def bench_solvers(instances, repeat: int, backends: Sequence[str]) -> dict:
    """The exact solver and each available qpsolvers backend on the same instances."""
    solvers: dict[str, Callable] = {"exact": solve_exact}
    for name in backends:
        try:
            solvers[f"qpsolvers-{name}"] = qpsolvers_solver(name)
        except ValueError:
            continue
    # Interleave: one block of instances per solver in turn, a few rounds.
    rounds = 3
    chunk = max(1, len(instances) // rounds)
    times: dict[str, list[float]] = {k: [] for k in solvers}
    results: dict[str, list] = {k: [] for k in solvers}
    for r in range(rounds):
        block = instances[r * chunk:(r + 1) * chunk] if r < rounds - 1 else instances[r * chunk:]
        for name, solve in solvers.items():
            t, res = time_solver(solve, block, repeat if name == "exact" else 1)
            times[name] += t
            results[name] += res
    out = {}
    for name in solvers:
        diffs = [math.dist(a, b) for a, b in zip(results["exact"], results[name], strict=True)
                 if a is not None and b is not None]
        out[name] = {
            "solve_us_median": statistics.median(times[name]),
            "solve_us_p90": sorted(times[name])[int(0.9 * (len(times[name]) - 1))],
            "max_diff_vs_exact": max(diffs) if diffs else None,
            "infeasible": sum(r is None for r in results[name]),
        }
    exact = out["exact"]["solve_us_median"]
    for name in out:
        out[name]["ratio_vs_exact"] = out[name]["solve_us_median"] / exact  # type: ignore[operator]
    return out


# ------------------------------------------------------------------------ one control step


def step_instance() -> tuple[ControlParams, StepInput]:
    """One robot of a 4-robot formation with 2 obstacles and 3 other formations in view."""
    p = ControlParams()
    neighbours = [Neighbour(-0.5, 0.0, 0.2, 0.0, 0.5), Neighbour(0.0, -0.25, 0.2, 0.0, 0.25),
                  Neighbour(-0.5, -0.25, 0.2, 0.01, 0.559)]
    obstacles = [Obstacle(1.2, 0.4, 0.0, 0.0, 0.3), Obstacle(2.0, -0.8, 0.05, 0.0, 0.3)]
    others = [Ellipse(2.5, 0.3, 3.1, 0.6, 0.3, -0.2, 0.0, 0.0),
              Ellipse(1.0, -2.0, 1.5, 0.6, 0.45, 0.0, 0.2, 0.01),
              Ellipse(-2.0, 2.0, 0.0, 0.55, 0.3, 0.1, -0.1, 0.0)]
    view = FormationView(Ellipse(-0.25, -0.125, 0.0, 0.6, 0.45, 0.2, 0.0, 0.0), 4.75, -0.125)
    return p, StepInput(pose=(0.0, 0.0, 0.0), goal=(5.0, 0.0), neighbours=neighbours,
                        obstacles=obstacles, others=others, view=view)


def bench_step(n: int, backends: Sequence[str] = BACKENDS) -> dict:
    """The full step, its two parts, and the solve of the same step's QP by every backend."""
    p, inp = step_instance()
    controller = Controller(p, clock=time.perf_counter_ns)  # made once, as the agent's loop does
    res = controller.step(inp)
    point, theta = inp.pose[:2], inp.pose[2]
    nux, nuy = res.nominal_ux, res.nominal_uy
    rows = build_rows(p, point, theta, (nux, nuy), inp)
    qp_rows = rows.limits + list(rows.contact) + rows.hard + rows.soft
    full = timed(lambda: controller.step(inp), n)
    build = timed(lambda: build_rows(p, point, theta, (nux, nuy), inp), n)
    solve = {"exact": statistics.median(timed(lambda: solve_exact(nux, nuy, qp_rows), n))}
    for name in backends:
        try:
            fn = qpsolvers_solver(name)
        except ValueError:
            continue
        k = max(20, n // 100)
        solve[name] = statistics.median(timed(lambda fn=fn: fn(nux, nuy, qp_rows), k))  # type: ignore[misc]
    return {
        "step_us_median": statistics.median(full),
        "step_us_p99": percentile(full, 0.99),
        "build_rows_us_median": statistics.median(build),
        "rows": len(qp_rows),
        "status": res.status,
        "solve_us_median": solve,
        "by_model": bench_step_models(n),
    }


DI_ACCEL = 1.0  # [m/s^2] the double integrator's acceleration limit in the step benchmark
DI_VELOCITY = (0.2, 0.0)  # [m/s] ... and its velocity (the formation's, as in step_instance)


def bench_step_models(n: int, rounds: int = 10) -> dict:
    """The same step (:func:`step_instance`) for a single integrator and a double integrator
    (max_accel DI_ACCEL, moving at DI_VELOCITY), timed in alternating rounds so machine noise
    hits both alike: medians [us] side by side."""
    p, inp = step_instance()
    inp = inp._replace(last_u=DI_VELOCITY)
    single = Controller(p)
    double = Controller(replace(p, double_integrator=True, max_accel=DI_ACCEL))
    times: dict[str, list[float]] = {"single_integrator": [], "double_integrator": []}
    k = max(1, n // rounds)
    for _ in range(rounds):
        times["single_integrator"] += timed(lambda: single.step(inp), k)
        times["double_integrator"] += timed(lambda: double.step(inp), k)
    out: dict = {m: statistics.median(t) for m, t in times.items()}
    out["double_over_single"] = out["double_integrator"] / out["single_integrator"]
    out["double_integrator_status"] = double.step(inp).status
    return out


# ------------------------------------------------------------------- in-process throughput


def bench_inprocess(scenario_path: Path, duration: float | None) -> dict:
    """Robot-steps per second of the in-process simulator (no recording) on a scenario."""
    from scenario import load_scenario
    from simulator.inprocess import SimOptions, simulate

    scenario = load_scenario(scenario_path)
    if duration is not None:
        scenario = replace(scenario, duration=min(duration, scenario.duration))
    cpu0, t0 = time.process_time(), time.perf_counter()
    res = simulate(scenario, SimOptions(record=False))
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    steps = res.summary["steps"] * len(scenario.robot_ids)
    return {"scenario": scenario.name, "robots": len(scenario.robot_ids),
            "ticks": res.summary["steps"], "robot_steps": steps, "wall_s": wall, "cpu_s": cpu,
            "robot_steps_per_s": steps / wall, "robot_steps_per_cpu_s": steps / cpu if cpu else None}


# ---------------------------------------------------------------------------- the command


def run_bench(quick: bool = False, scenario: Path = DEFAULT_SCENARIO,
              work: Path | None = None) -> dict:
    """Every measurement of the module docstring; ``quick`` is the CI smoke mode (< 60 s)."""
    load0 = load_avg()
    step = bench_step(2000 if quick else 20000)
    instances = collect_instances(scenario, 200 if quick else 2000, 20.0 if quick else None)
    solvers = bench_solvers(instances, repeat=3 if quick else 5, backends=BACKENDS)
    central = bench_central((8,) if quick else (8, 32, 128), CENTRAL_BACKENDS,
                            repeat=3 if quick else 15)
    inproc = bench_inprocess(scenario, 10.0 if quick else None)
    loading = bench_loading(QUICK_SIZES if quick else SIZES, repeat=1 if quick else 5)
    fleets = QUICK_FLEETS if quick else FLEETS
    duration = QUICK_DURATION if quick else FLEET_DURATION
    agents = {}
    with tempfile.TemporaryDirectory(prefix="bench-agents-") as tmp:
        base = Path(work) if work is not None else Path(tmp)
        for n, dt in fleets.items():
            agents[str(n)] = bench_agents(n, dt, duration, base / f"agents-{n}")
        slots = {str(n): bench_agents(n, dt, duration, base / f"slots-{n}", pose_slots=n // 4)
                 for n, dt in ({} if quick else SLOT_FLEETS).items()}
        clock = {str(n): bench_agents(n, dt, duration, base / f"clock-{n}", tick_on_pose=False)
                 for n, dt in ({} if quick else CLOCK_FLEETS).items()}
        # the first fleet again with the live viewer attached to its router
        n, dt = next(iter(fleets.items()))
        watched = {str(n): bench_agents(n, dt, duration, base / f"viewer-{n}", viewer=True)}
    from experiments.camera import bench_camera

    camera = bench_camera(frames=30 if quick else 450)
    return {
        "machine": {"python": platform.python_version(), "processor": platform.processor() or
                    platform.machine(), "cpus": os.cpu_count(), "quick": quick,
                    "load_avg_1min_at_start": load0},
        "instances": {"scenario": scenario.name, "count": len(instances),
                      "rows_median": statistics.median(len(r) for _, _, r in instances)},
        "step_us_median": step["step_us_median"],
        "step": step,
        "solvers": solvers,
        "central": central,
        "agents": agents,
        "agents_pose_slots": slots,
        "agents_clock_ticks": clock,
        "inprocess": inproc,
        "scenario_loading": loading,
        "agents_viewer": watched,
        "camera": camera,
        "recording": bench_recording(scenario, 10.0 if quick else None, rounds=1 if quick else 3),
    }


def parse_fleets(text: str) -> list[tuple[int, float]]:
    """``N@HZ,N@HZ,...`` (e.g. ``32@50,256@20``) -> [(agents, control period [s]), ...];
    ValueError naming the bad item."""
    fleets = []
    for item in text.split(","):
        n, sep, hz = item.strip().partition("@")
        try:
            agents, rate = int(n), float(hz)
        except ValueError:
            agents, rate = 0, 0.0
        if not sep or agents < 1 or not (math.isfinite(rate) and 0 < rate <= 1000):
            raise ValueError(f"--fleets: {item.strip()!r} is not AGENTS@HZ (e.g. 32@50)")
        fleets.append((agents, 1.0 / rate))
    return fleets


def run_fleets(fleets: Sequence[tuple[int, float]], per_process: int = 1,
               shared_session: bool = False, repeat: int = 1,
               duration: float = FLEET_DURATION, work: Path | None = None,
               pose_slots: int = 1, pose_zones: Sequence[int] = (0,), stalls: bool = False
               ) -> dict:
    """Only the **agents** part, for the fleets asked (``formation bench --fleets``): each fleet
    ``repeat`` times in a row, every run with its own load average and latency parts;
    ``pose_slots`` is the world's (capped at one slot per formation). Each of ``pose_zones``
    (0: every pose and command through the one router; Z: Z zone routers,
    :mod:`simulator.zones`) runs in every round, one after the other, so the machine's load
    hits the pose paths alike. ``stalls``: every agent host records what holds its ticks back
    (:mod:`agent.stalls`), summed up per run."""
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench-fleets-") as tmp:
        base = Path(work) if work is not None else Path(tmp)
        for n, dt in fleets:
            for r in range(repeat):
                for z in pose_zones:
                    entry = bench_agents(n, dt, duration,
                                         base / f"fleet-{n}-{round(1 / dt)}-z{z}-{r}",
                                         hosting=Hosts(per_process, shared_session, stalls),
                                         pose_slots=max(1, min(pose_slots, n // 4)),
                                         pose_zones=z)
                    entry["fleet"] = f"{n}@{1 / dt:g}"
                    entry["round"] = r + 1
                    runs.append(entry)
    return {
        "machine": {"python": platform.python_version(), "processor": platform.processor() or
                    platform.machine(), "cpus": os.cpu_count(), "quick": False,
                    "load_avg_1min_at_start": runs[0]["load_avg_1min"]["before"] if runs else None},
        "agents_per_process": per_process,
        "shared_session": shared_session,
        "pose_slots": pose_slots,
        "pose_zones": list(pose_zones),
        "fleets": runs,
        "pose_zones_compared": compare_zones(runs) if len(set(pose_zones)) > 1 else [],
    }


def compare_zones(runs: Sequence[dict]) -> list[dict]:
    """Per fleet and pose path: the medians over its rounds of missed ticks, p50 and p99, and
    their ratio to the first pose path's (``pose_zones`` of the first run of that fleet)."""
    out = []
    for fleet in dict.fromkeys(a["fleet"] for a in runs):
        mine = [a for a in runs if a["fleet"] == fleet]
        ref = None
        for z in dict.fromkeys(a.get("pose_zones", 0) for a in mine):
            sel = [a for a in mine if a.get("pose_zones", 0) == z]
            row = {"fleet": fleet, "pose_zones": z, "rounds": len(sel)}
            for key in ("missed_ticks", "latency_ms_p50", "latency_ms_p99"):
                vals = [a[key] for a in sel if a.get(key) is not None]
                row[key] = statistics.median(vals) if vals else None
            ref = ref or row
            for key in ("missed_ticks", "latency_ms_p50", "latency_ms_p99"):
                row[f"{key}_ratio"] = (None if row[key] is None or not ref[key]
                                       else row[key] / ref[key])
            out.append(row)
    return out


def format_fleets(result: dict) -> str:
    """The table of a :func:`run_fleets` result, one row per run, with the load average."""
    k = result["agents_per_process"]
    lines = [f"agent fleets in real time (pose published -> command received), "
             f"{k} agent(s) per process" + (", one Zenoh session per host"
                                            if result["shared_session"] else ""),
             FLEET_HEADER + f"{'load':>11}{'zones':>6}{'pose in':>8}{'cmd back':>9}"
             f"{'publish':>9}"]
    for a in result["fleets"]:
        load = a["load_avg_1min"]
        parts = a["latency_parts_ms_median"]
        lines.append(_fleet_row(str(a["robots"]), a)
                     + f"{_f(load['before']):>5}->{_f(load['after']):<5}"
                     + f"{a.get('pose_zones', 0):>6}{_f(parts.get('pose_in'), '.2f'):>8}"
                     + f"{_f(parts.get('cmd_back'), '.2f'):>9}"
                     + f"{_f(a.get('world_publish_ms_median'), '.2f'):>9}")
    lines.append("  wait: pose received -> tick starts; tick: tick start -> command put; net: the rest "
                 "(pose in: pose stamp -> agent received, cmd back: the rest of net); publish: the "
                 "world's stamp -> its last pose put; medians. load: 1-minute load average before "
                 "-> after the run. zones: 0 = one router, Z = Z zone routers")
    compared = result.get("pose_zones_compared") or []
    if compared:
        lines.append("pose paths side by side (medians over rounds; ratio to the first path):")
        for c in compared:
            lines.append(f"  {c['fleet']:>7} zones {c['pose_zones']:>2}: missed "
                         f"{_f(c['missed_ticks'], '.0f')} ({_f(c['missed_ticks_ratio'], '.2f')}x), "
                         f"p50 {_f(c['latency_ms_p50'], '.2f')} ms "
                         f"({_f(c['latency_ms_p50_ratio'], '.2f')}x), p99 "
                         f"{_f(c['latency_ms_p99'], '.2f')} ms ({_f(c['latency_ms_p99_ratio'], '.2f')}x)")
    lines += format_tick_parts(result["fleets"])
    lines += format_stalls(result["fleets"])
    lines.append(f"machine: {result['machine']['cpus']} CPUs")
    return "\n".join(lines)


def format_stalls(runs: Sequence[dict]) -> list[str]:
    """What held the agent hosts' ticks back (``--stalls``), one row per run that recorded it."""
    rows = [a for a in runs if a.get("stalls")]
    if not rows:
        return []
    lines = ["what holds the ticks back (--stalls; per host: garbage collections a minute by "
             "generation with the longest pause [ms] and those inside a tick; heap objects "
             "tracked / frozen; tick CPU p99 [ms], longest tick [ms]; plan workers' CPU [s]):"]
    for a in rows:
        st = a["stalls"]
        gcs = "  ".join(f"g{g} {_f(v['per_minute_per_host'], '.0f')}/min "
                        f"max {_f(v['wall_ms_max'], '.2f')} in {v['in_ticks']}"
                        for g, v in st["gc"].items())
        lines.append(f"  {a['fleet']:>7} zones {a.get('pose_zones', 0):>2}: {gcs}  heap "
                     f"{_f(st['heap_objects'], '.0f')} / {_f(st['frozen_objects'], '.0f')}  tick p99 "
                     f"{_f(st['tick_cpu_ms_p99'], '.3f')} max {_f(st['tick_wall_ms_max'], '.2f')}"
                     f"  plan {_f(st['plan_worker_cpu_s'], '.2f')}")
    return lines


def format_tick_parts(runs: Sequence[dict]) -> list[str]:
    """Where the agents' tick goes, one row per run (medians over the agents of each agent's
    median per part, ms; :mod:`agent.tick_times`); nothing for agents that do not time them."""
    from agent.tick_times import TICK_PARTS

    timed = [a for a in runs if any(v is not None for v in (a.get("tick_parts_ms_median") or {})
                                    .values())]
    if not timed:
        return []
    lines = ["the tick's parts [ms] (medians; leader: the leaders' ticks only):",
             f"{'N':>4}{'Hz':>5}{'zones':>6}{'tick':>7}" + "".join(f"{p:>8}" for p in TICK_PARTS)]
    for a in timed:
        parts = a["tick_parts_ms_median"]
        lines.append(f"{a['robots']:>4}{a['rate_hz_target']:>5.0f}{a.get('pose_zones', 0):>6}"
                     f"{_f(a['latency_parts_ms_median']['tick'], '.3f'):>7}"
                     + "".join(f"{_f(parts.get(p), '.3f'):>8}" for p in TICK_PARTS))
    lines.append("  inbox: samples drained, decoded and checked; pose: the pose checked and carried; "
                 "leader: ellipse and others put; inputs: freshness, obstacles, neighbours, the "
                 "step's inputs; route: the route walked; step: the control step (QP included); "
                 "command, state: encoded and put; record: counters and diagnostics")
    return lines


def _f(v, fmt: str = ".1f", none: str = "-") -> str:
    return none if v is None else format(v, fmt)


FLEET_HEADER = (f"{'N':>4}{'Hz':>5}{'slots':>6}{'rate':>7}{'missed':>8}{'overrun':>8}{'p50 ms':>8}"
                f"{'p99 ms':>8}{'wait':>7}{'tick':>7}{'net':>7}{'cpu %':>7}{'rss MB':>8}"
                f"{'all %':>7}{'other %':>8}")


def _fleet_row(label: str, a: dict) -> str:
    parts = a["latency_parts_ms_median"]
    return (f"{label:>4}{a['rate_hz_target']:>5.0f}{a.get('pose_slots', 1):>6}{_f(a['rate_hz']):>7}"
            f"{a['missed_ticks']:>8}"
            f"{a['agent_overruns']:>8}{_f(a['latency_ms_p50'], '.2f'):>8}"
            f"{_f(a['latency_ms_p99'], '.2f'):>8}{_f(parts['pose_wait_for_tick'], '.2f'):>7}"
            f"{_f(parts['tick'], '.2f'):>7}{_f(parts['transport_rest'], '.2f'):>7}"
            f"{_f(a['cpu_percent_per_agent_median']):>7}{_f(a['rss_mb_per_agent_median']):>8}"
            f"{_f(a.get('fleet_cpu_percent'), '.0f'):>7}{_f(a.get('others_cpu_percent'), '.0f'):>8}")


def format_table(result: dict) -> str:
    """The human-readable table of a :func:`run_bench` result."""
    st = result["step"]
    lines = [
        f"control step (4-robot formation, 2 obstacles, 3 other formations, {st['rows']} rows): "
        f"median {st['step_us_median']:.1f} us, p99 {st['step_us_p99']:.1f} us; "
        f"build_rows {st['build_rows_us_median']:.1f} us",
        "  same QP solved alone: " + ", ".join(f"{k} {v:.1f} us"
                                                 for k, v in st["solve_us_median"].items()),
        f"  by robot model, same step: single integrator "
        f"{st['by_model']['single_integrator']:.1f} us, double integrator "
        f"{st['by_model']['double_integrator']:.1f} us (x{st['by_model']['double_over_single']:.2f})",
        f"QP instances: {result['instances']['count']} from {result['instances']['scenario']} "
        f"(median {result['instances']['rows_median']} rows)",
        f"{'solver':<22}{'median us':>11}{'p90 us':>10}{'x exact':>9}{'max |du|':>12}",
    ]
    for name, s in result["solvers"].items():
        diff = "-" if s["max_diff_vs_exact"] is None else f"{s['max_diff_vs_exact']:.1e}"
        lines.append(f"{name:<22}{s['solve_us_median']:>11.1f}{s['solve_us_p90']:>10.1f}"
                     f"{s['ratio_vs_exact']:>9.1f}{diff:>12}")
    lines.append("")
    lines.append("centralized QP over all robots (build + solve) vs N per-robot control steps [us]")
    backends = sorted({b for c in result["central"].values() for b in c["total_us"]})
    lines.append(f"{'N':>4}{'rows':>7}{'per-robot':>11}{'build':>9}"
                 + "".join(f"{b:>11}" for b in backends))
    for n, c in result["central"].items():
        lines.append(f"{n:>4}{c['rows']:>7}{c['per_robot_total_us']:>11.0f}"
                     f"{c['central_build_us']:>9.0f}"
                     + "".join(f"{_f(c['total_us'].get(b), '.0f'):>11}" for b in backends))
    lines.append("")
    lines.append("agent processes in real time (pose published -> command received)")
    lines.append(FLEET_HEADER)
    fleets = [(n, a) for n, a in result["agents"].items()]
    fleets += [(f"{n}s", a) for n, a in result.get("agents_pose_slots", {}).items()]
    fleets += [(f"{n}c", a) for n, a in result.get("agents_clock_ticks", {}).items()]
    fleets += [(f"{n}v", a) for n, a in result.get("agents_viewer", {}).items()]
    for n, a in fleets:
        lines.append(_fleet_row(str(n), a))
    lines.append("  slots: 1 = every pose of a tick at once (one camera frame); Ns: the world publishes "
                 "each formation's poses in its own slot of the period")
    if result.get("agents_clock_ticks"):
        lines.append("  Nc: agents ticking on their own clock (--clock-ticks); the others tick on pose "
                     "arrival")
    lines.append("  Nv: the first fleet again with `formation view` attached to the router")
    lines.append("  wait: pose received -> tick starts; tick: tick start -> command put; net: the rest "
                 "(router both ways, Zenoh and Python threads, CPU queueing); medians")
    lines.append("  cpu %: per agent (median), of one core; all %: agents + router + world; other %: "
                 "other people's processes meanwhile (2 cores = 200)")
    ip = result["inprocess"]
    lines.append("")
    lines.append(f"in-process simulation, {ip['scenario']} ({ip['robots']} robots, {ip['ticks']} "
                 f"ticks): {ip['robot_steps_per_s']:.0f} robot-steps/s wall, "
                 f"{_f(ip['robot_steps_per_cpu_s'], '.0f')} per CPU second")
    rec = result.get("recording")
    if rec:
        r = rec["robot_steps_per_s"]
        lines.append(f"  {rec['scenario']}, robot-steps/s: loop alone {r['loop_only']:.0f}, with the "
                     f"time series {r['with_series']:.0f}, with run.mcap written too "
                     f"{r['with_mcap']:.0f} ({rec['record_ms_per_tick']:.2f} ms and "
                     f"{rec['mcap_bytes_per_tick'] / 1e3:.1f} kB per tick of recording)")
    if result.get("camera"):
        from experiments.camera import format_camera

        lines += ["", *format_camera(result["camera"])]
    if "scenario_loading" in result:
        lines.append(format_loading(result["scenario_loading"]))
    lines.append(f"machine: {result['machine']['cpus']} CPUs, load average "
                 f"{_f(result['machine']['load_avg_1min_at_start'])} at start")
    return "\n".join(lines)
