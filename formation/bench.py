"""``formation bench``: how fast the control step, the QP and the multi-process fleet are.

Five measurements, written to ``bench.json`` and as a table (``bench.txt`` and stdout):

* **step**: one robot's full control step (:func:`agent.control.control_step`: nominal command,
  barrier rows, QP) for a robot of a 4-robot formation with 2 obstacles and 3 other formations
  in view, with its two parts (:func:`agent.control.build_rows` and the exact solve) apart.
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
  their own clocks would, so the N agents do not all wake in the same instant on this 2-core
  machine (on robots each agent has its own CPU), and one fleet runs with agents ticking on
  their own clock (``agents_clock_ticks``). Reported per fleet: achieved command rate, missed ticks, pose ->
  command latency (p50, p99) and its parts, CPU and memory (RSS) per agent, and the agents'
  stale ticks (zero commands) by the input that was stale.
* **inprocess**: simulation throughput (robot-steps per second) of ``formation sim`` on the
  warehouse scenario.

Definitions: the latency of a command is ``receive time - stamp`` of the pose it was computed
from, both on this machine's wall clock (the world stamps poses with ``time.time()``). A *missed
tick* is a pose for which no command computed from it arrived within one control period (the
robot drove a period on an older command); agents also count their own deadline overruns. CPU
is ``utime + stime`` from ``/proc/PID/stat`` over the steady run (all threads, Zenoh's included),
as a percentage of one core; memory is ``VmRSS`` of ``/proc/PID/status`` at the end of the run.

The machine's load average is recorded beside every timing: this is a shared 2-core machine, and
timings taken under other people's load are upper bounds.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import platform
import signal
import statistics
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import FrameType

from agent.barriers import Neighbour, Obstacle
from agent.control import ControlParams, FormationView, build_rows, control_step
from agent.qp import Row, qpsolvers_solver, solve_exact
from leader.ellipse import Ellipse

logger = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENARIO = ROOT / "scenarios" / "warehouse.yaml"
BACKENDS = ("osqp", "daqp", "quadprog", "clarabel")
CENTRAL_BACKENDS = ("osqp", "clarabel", "daqp", "quadprog")
CENTRAL_BUDGET_S = 3.0  # [s] a backend slower than this on one centralized solve is not repeated

# Fleets of the "agents" and "central" parts: N/4 rectangles travelling in parallel lanes.
LANE_SPACING = 2.5  # [m] between the centroids of neighbouring lanes
COLUMN_SPACING = 9.0  # [m] between formations sharing a lane
TRAVEL = 7.0  # [m] goal ahead of the start (not reached within the benchmark's duration)
FLEETS = {8: 0.02, 32: 0.02, 64: 0.05}  # agents -> control period [s] (50, 50, 20 Hz)
FLEET_DURATION = 15.0  # [s] of real time per fleet
CLOCK_FLEETS = {8: 0.02}  # the same agents ticking on their own clock, for comparison
SLOT_FLEETS = {32: 0.02, 64: 0.05}  # the world publishing one formation's poses per slot, to compare
QUICK_FLEETS = {4: 0.02}
QUICK_DURATION = 2.0  # [s]


def _load() -> float | None:
    """The 1-minute load average (None where the OS does not tell)."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def _pct(xs: Sequence[float], q: float) -> float:
    """The q-quantile (0..1) of ``xs`` by the nearest-rank method."""
    s = sorted(xs)
    return s[max(0, min(len(s) - 1, math.ceil(q * len(s)) - 1))]


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
        out[name]["ratio_vs_exact"] = out[name]["solve_us_median"] / exact
    return out


# ------------------------------------------------------------------------ one control step


def step_instance():
    """One robot of a 4-robot formation with 2 obstacles and 3 other formations in view."""
    p = ControlParams()
    pose = (0.0, 0.0, 0.0)
    goal = (5.0, 0.0)
    neighbours = [Neighbour(-0.5, 0.0, 0.2, 0.0, 0.5), Neighbour(0.0, -0.25, 0.2, 0.0, 0.25),
                  Neighbour(-0.5, -0.25, 0.2, 0.01, 0.559)]
    obstacles = [Obstacle(1.2, 0.4, 0.0, 0.0, 0.3), Obstacle(2.0, -0.8, 0.05, 0.0, 0.3)]
    others = [Ellipse(2.5, 0.3, 3.1, 0.6, 0.3, -0.2, 0.0, 0.0),
              Ellipse(1.0, -2.0, 1.5, 0.6, 0.45, 0.0, 0.2, 0.01),
              Ellipse(-2.0, 2.0, 0.0, 0.55, 0.3, 0.1, -0.1, 0.0)]
    view = FormationView(Ellipse(-0.25, -0.125, 0.0, 0.6, 0.45, 0.2, 0.0, 0.0), 4.75, -0.125)
    return p, pose, goal, neighbours, obstacles, others, view


def _timed(fn: Callable[[], object], n: int) -> list[float]:
    times = []
    for _ in range(n):
        t0 = time.perf_counter_ns()
        fn()
        times.append((time.perf_counter_ns() - t0) * 1e-3)
    return times


def bench_step(n: int, backends: Sequence[str] = BACKENDS) -> dict:
    """The full step, its two parts, and the solve of the same step's QP by every backend."""
    p, pose, goal, nb, obs, others, view = step_instance()
    res = control_step(p, pose, goal, nb, obs, others, view)
    rows = build_rows(p, pose[0], pose[1], pose[2], (res.nominal_ux, res.nominal_uy), nb, obs,
                      others, view)
    qp_rows = rows.limits + list(rows.contact) + rows.hard + rows.soft
    nux, nuy = res.nominal_ux, res.nominal_uy
    full = _timed(lambda: control_step(p, pose, goal, nb, obs, others, view), n)
    build = _timed(lambda: build_rows(p, pose[0], pose[1], pose[2], (nux, nuy), nb, obs, others,
                                      view), n)
    solve = {"exact": statistics.median(_timed(lambda: solve_exact(nux, nuy, qp_rows), n))}
    for name in backends:
        try:
            fn = qpsolvers_solver(name)
        except ValueError:
            continue
        k = max(20, n // 100)
        solve[name] = statistics.median(_timed(lambda fn=fn: fn(nux, nuy, qp_rows), k))
    return {
        "step_us_median": statistics.median(full),
        "step_us_p99": _pct(full, 0.99),
        "build_rows_us_median": statistics.median(build),
        "rows": len(qp_rows),
        "status": res.status,
        "solve_us_median": solve,
    }


# -------------------------------------------------------------------------------- fleets


def fleet_scenario(n: int, dt: float, duration: float):
    """``n`` robots (a multiple of 4) as n/4 rectangles of 0.5 m x 0.25 m, in parallel lanes
    ``LANE_SPACING`` apart (up to 4 formations per lane), all travelling +x towards goals
    ``TRAVEL`` ahead, with 2 static obstacles beside the fleet: every robot has 3 neighbours,
    2 obstacles and n/4 - 1 other formations in view, and nobody is in anybody's way."""
    from scenario.load import scenario_from_dict

    if n < 4 or n % 4:
        raise ValueError(f"n: need a positive multiple of 4 robots, got {n}")
    k = n // 4
    per_lane = min(4, k)
    shape = ((-0.5, 0.125), (0.0, 0.125), (0.0, -0.125), (-0.5, -0.125))
    formations = []
    for f in range(k):
        x0, y0 = (f % per_lane) * COLUMN_SPACING, (f // per_lane) * LANE_SPACING
        robots = {}
        for i, (dx, dy) in enumerate(shape, start=1):
            robots[f"f{f}r{i}"] = {"start": [x0 + dx, y0 + dy],
                                   "goal": [x0 + dx + TRAVEL, y0 + dy]}
        r = [f"f{f}r{i}" for i in range(1, 5)]
        formations.append({"name": f"f{f}", "leader": r[1], "robots": robots,
                           "edges": [[r[0], r[1]], [r[0], r[3]], [r[1], r[2]], [r[1], r[3]],
                                     [r[2], r[3]]]})
    return scenario_from_dict({
        "name": f"bench-fleet-{n}",
        "dt": dt,
        "duration": duration,
        "robot": {"model": "single_integrator", "max_speed": 0.22, "radius": 0.105},
        "controller": {"kp": 2.0, "gamma": {"formation": 1.0, "obstacle": 0.8, "formations": 0.5},
                       "epsilon": 0.04},
        "formations": formations,
        "obstacles": [{"name": "o1", "center": [2.0, -1.5], "safe_distance": 0.35},
                      {"name": "o2", "center": [5.0, -1.5], "safe_distance": 0.35}],
    })


@dataclass(frozen=True)
class RobotInputs:
    """What one robot's control step is handed at the benchmark's snapshot."""

    pose: tuple[float, float, float]
    goal: tuple[float, float]
    neighbours: list[Neighbour]
    obstacles: list[Obstacle]
    others: list[Ellipse]
    view: FormationView


def fleet_snapshot(scenario, speed: float = 0.2) -> tuple[ControlParams, list[RobotInputs], list]:
    """Every robot's inputs with the fleet at its start, each robot moving at ``speed`` along
    +x (what the in-process simulator hands the control step); also every robot's formation
    name and the formation edges as (i, j, Df) robot indices."""
    from simulator.inprocess import FleetModel

    fleet = FleetModel.build(scenario)
    robots = scenario.robots
    ctrl = [(r.start[0], r.start[1]) for r in robots]
    vel = [(speed, 0.0)] * len(robots)
    ellipses = fleet.ellipses(ctrl, vel)
    obs = [Obstacle(*o.center, *o.velocity, o.safe_distance) for o in scenario.obstacles]
    inputs = []
    for i, r in enumerate(robots):
        fname = fleet.formation_of[i]
        nb = [Neighbour(*ctrl[j], *vel[j], df) for j, df in fleet.neighbours[i]]
        f = scenario.formation_of(r.id)
        gc = f.goal_centroid
        names = tuple(name for name in ellipses if name != fname)
        view = FormationView(ellipses[fname], gc[0], gc[1], fname, names)
        inputs.append(RobotInputs((r.start[0], r.start[1], 0.0), r.goal, nb, obs,
                                  [ellipses[name] for name in names], view))
    index = {rid: k for k, rid in enumerate(scenario.robot_ids)}
    edges = [(index[e.i], index[e.j], e.df) for f in scenario.formations for e in f.edges]
    return fleet.params, inputs, edges


# ------------------------------------------------------------------- centralized solving


def central_problem(params: ControlParams, inputs: Sequence[RobotInputs], formation_of: Sequence[str],
                    edges: Sequence[tuple[int, int, float]], nominal: Sequence[tuple[float, float]]):
    """The centralized QP ``min sum |u_i - nominal_i|^2  s.t.  G u <= h`` over u = (u_1 .. u_N)
    as sparse (P, q, G, h): every robot's speed, obstacle and ellipse rows
    (:func:`agent.control.build_rows` without neighbours), the two band rows of every formation
    edge with both robots' velocities as unknowns (eq. 4.3/4.4), and eq. 3.5 for every pair of
    robots of different formations (Robotarium's pairwise barrier certificate), at distance
    ``params.d_af``. Every row is scaled to a unit gradient per robot block."""
    import numpy as np
    from scipy import sparse

    n = len(inputs)
    rows_i: list[np.ndarray] = []
    cols_i: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    rhs: list[np.ndarray] = []
    m = 0
    # single-robot rows, by the agent's own row builder
    for i, r in enumerate(inputs):
        built = build_rows(params, r.pose[0], r.pose[1], r.pose[2], nominal[i], (), r.obstacles,
                           r.others, r.view)
        single = np.array(built.limits + list(built.contact) + built.hard, dtype=float).reshape(-1, 3)
        k = len(single)
        idx = np.arange(m, m + k)
        rows_i += [idx, idx]
        cols_i += [np.full(k, 2 * i), np.full(k, 2 * i + 1)]
        vals += [single[:, 0], single[:, 1]]
        rhs.append(single[:, 2])
        m += k
    p = np.array([r.pose[:2] for r in inputs], dtype=float)

    def coupled(a: np.ndarray, b: np.ndarray, sign: float, h: np.ndarray, gamma: float) -> None:
        """Rows  sign * (-d . u_a + d . u_b) <= gamma h  with d = (p_a - p_b) / |p_a - p_b|."""
        nonlocal m
        d = p[a] - p[b]
        norm = np.hypot(d[:, 0], d[:, 1])
        d = sign * d / norm[:, None]
        k = len(a)
        idx = np.arange(m, m + k)
        for block, s in ((a, -1.0), (b, 1.0)):
            rows_i.extend([idx, idx])
            cols_i.extend([2 * block, 2 * block + 1])
            vals.extend([s * d[:, 0], s * d[:, 1]])
        rhs.append(gamma * h / (2.0 * norm))
        m += k

    if edges:
        e = np.array(edges, dtype=float)
        a, b, df = e[:, 0].astype(int), e[:, 1].astype(int), e[:, 2]
        d2 = np.sum((p[a] - p[b]) ** 2, axis=1)
        eps = params.epsilon
        coupled(a, b, 1.0, d2 - (df - eps) ** 2, params.gamma_formation)  # eq. 4.3
        coupled(a, b, -1.0, (df + eps) ** 2 - d2, params.gamma_formation)  # eq. 4.4
    ia, ib = np.triu_indices(n, 1)
    names = np.array(formation_of)
    foreign = names[ia] != names[ib]
    a, b = ia[foreign], ib[foreign]
    if len(a):
        d2 = np.sum((p[a] - p[b]) ** 2, axis=1)
        coupled(a, b, 1.0, d2 - params.d_af ** 2, params.gamma_formations)  # eq. 3.5
    g = sparse.csc_matrix((np.concatenate(vals), (np.concatenate(rows_i), np.concatenate(cols_i))),
                          shape=(m, 2 * n))
    h = np.concatenate(rhs)
    pm = sparse.identity(2 * n, format="csc") * 2.0
    q = -2.0 * np.array(nominal, dtype=float).reshape(-1)
    return pm, q, g, h


def _solve_central(name: str, pm, q, g, h):
    """One centralized solve by qpsolvers backend ``name`` (sparse or dense as it takes)."""
    import numpy as np
    import qpsolvers

    opts: dict = {}
    if name == "osqp":
        opts = {"eps_abs": 1e-6, "eps_rel": 1e-6, "polish": True, "verbose": False}
    elif name == "clarabel":
        opts = {"verbose": False}
    if name not in getattr(qpsolvers, "sparse_solvers", ()):
        pm, g = pm.toarray(), g.toarray()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # osqp's future-default notice; answered by the check
        x = qpsolvers.solve_qp(pm, q, g, h, solver=name, **opts)
    if x is None or not np.all(np.isfinite(x)):
        return None
    return x


def bench_central(sizes: Sequence[int], backends: Sequence[str], repeat: int,
                  budget_s: float = CENTRAL_BUDGET_S) -> dict:
    """Centralized QP (build + solve per backend) against N per-robot control steps, per N."""
    import numpy as np
    import qpsolvers

    out: dict[str, dict] = {}
    for n in sizes:
        scenario = fleet_scenario(n, 0.05, 10.0)
        params, inputs, edges = fleet_snapshot(scenario)
        formation_of = [scenario.formation_of(r).name for r in scenario.robot_ids]

        def all_steps(params=params, inputs=inputs):
            return [control_step(params, r.pose, r.goal, r.neighbours, r.obstacles, r.others,
                                 r.view) for r in inputs]

        steps = all_steps()
        nominal = [(s.nominal_ux, s.nominal_uy) for s in steps]
        dist_times = _timed(all_steps, repeat)
        build_times = _timed(lambda params=params, inputs=inputs, fo=formation_of, e=edges,
                             nom=nominal: central_problem(params, inputs, fo, e, nom), repeat)
        pm, q, g, h = central_problem(params, inputs, formation_of, edges, nominal)
        entry: dict = {
            "robots": n, "variables": 2 * n, "rows": int(g.shape[0]), "nonzeros": int(g.nnz),
            "per_robot_total_us": statistics.median(dist_times),
            "per_robot_step_us": statistics.median(dist_times) / n,
            "central_build_us": statistics.median(build_times),
            "solve_us": {}, "total_us": {}, "max_violation": {}, "max_diff_vs_per_robot": {},
            "skipped": {},
        }
        u_dist = np.array([(s.ux, s.uy) for s in steps])
        for name in backends:
            if name not in qpsolvers.available_solvers:
                continue
            times = []
            x = None
            for _ in range(repeat):
                t0 = time.perf_counter_ns()
                x = _solve_central(name, pm, q, g, h)
                times.append((time.perf_counter_ns() - t0) * 1e-3)
                if times[-1] > budget_s * 1e6:
                    entry["skipped"][name] = f"one solve took {times[-1] / 1e6:.1f} s: not repeated"
                    break
            med = statistics.median(times)
            entry["solve_us"][name] = med
            entry["total_us"][name] = med + entry["central_build_us"]
            if x is None:
                entry["max_violation"][name] = None
                entry["max_diff_vs_per_robot"][name] = None
            else:
                entry["max_violation"][name] = max(0.0, float(np.max(g @ x - h)))
                entry["max_diff_vs_per_robot"][name] = float(
                    np.max(np.hypot(*(x.reshape(-1, 2) - u_dist).T)))
        out[str(n)] = entry
        logger.info("central N=%d: %s", n, entry["total_us"])
    return out


# ------------------------------------------------------------------------ agent processes


def _proc_cpu_s(pid: int) -> float | None:
    """utime + stime of a process (all its threads) [s], from /proc/PID/stat."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _proc_rss_mb(pid: int) -> float | None:
    """VmRSS of a process [MB], from /proc/PID/status."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _machine_busy_s() -> float | None:
    """CPU time every process of the machine has used since boot [s], from /proc/stat."""
    try:
        fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    except (OSError, ValueError):
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def _raise_interrupt(signum: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


def bench_agents(n: int, dt: float, duration: float, work: Path, tick_on_pose: bool = True,
                 pose_slots: int = 1) -> dict:
    """Run ``n`` agent processes in real time against the simulated world for ``duration``
    seconds (see the module docstring); every process started here is stopped on every way out.
    ``tick_on_pose=False`` runs the agents with ``--clock-ticks`` (their own clock);
    ``pose_slots`` is the world's (:class:`simulator.world.WorldOptions`)."""
    import zenoh

    from wire.zconf import use_zenoh_threads

    use_zenoh_threads("relay")  # as `formation bench` does, for a direct call too

    from agent.config import ZenohSettings, build_agent_configs, save_config
    from simulator.launch import START_TIMEOUT_S, Supervisor
    from simulator.world import World, WorldOptions
    from wire.testing import free_tcp_port, tcp_endpoint, wait_for_tcp_port
    from wire.zconf import ZenohSettings as WireZenohSettings

    scenario = fleet_scenario(n, dt, duration)
    for sub in ("configs", "agents", "logs"):
        (work / sub).mkdir(parents=True, exist_ok=True)
    port = free_tcp_port()
    endpoint = tcp_endpoint(port)
    sup = Supervisor(work / "logs")
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    load_before = _load()
    try:
        router = sup.start("router", ["-m", "wire.router", "--listen", endpoint,
                                      "--log-level", "WARNING"])
        wait_for_tcp_port(port, timeout_s=START_TIMEOUT_S)
        zs = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False)
        agents = {}
        for rid, cfg in build_agent_configs(scenario, zenoh=zs).items():
            path = work / "configs" / f"{rid}.yaml"
            save_config(cfg, path)
            agents[rid] = sup.start(f"agent-{rid}", [
                "-m", "agent", "--config", str(path), "--stats", str(work / "agents" / f"{rid}.json"),
                "--no-trace", *([] if tick_on_pose else ["--clock-ticks"])])
        conf = WireZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                                 connect_timeout_s=10.0).to_config()
        options = WorldOptions(realtime=True, stop_at_goal=False, record=False, pose_slots=pose_slots,
                               start_timeout=START_TIMEOUT_S + 4.0 * n)
        pids = {rid: c.proc.pid for rid, c in agents.items()}
        with zenoh.open(conf) as session:
            world = World(scenario, session, options)
            try:
                world.wait_for_agents(abort=sup.check)
                cpu0 = {rid: _proc_cpu_s(pid) for rid, pid in pids.items()}
                router_cpu0 = _proc_cpu_s(router.proc.pid)
                own0 = time.process_time()
                busy0 = _machine_busy_s()
                result = world.run(abort=sup.check)
                own_cpu = time.process_time() - own0
                busy1 = _machine_busy_s()
                cpu1 = {rid: _proc_cpu_s(pid) for rid, pid in pids.items()}
                router_cpu1 = _proc_cpu_s(router.proc.pid)
                rss = {rid: _proc_rss_mb(pid) for rid, pid in pids.items()}
                router_rss = _proc_rss_mb(router.proc.pid)
            finally:
                world.close()
        load_after = _load()
        sup.stop(list(agents.values()))  # agents write their counters on SIGTERM
        sup.stop([router])
    finally:
        sup.stop()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
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
    pose_wait = None if med("pose_age_us_median") is None else med("pose_age_us_median") / 1e3
    tick = None if med("tick_us_median") is None else med("tick_us_median") / 1e3
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
        "latency_ms_p99": _pct(lat, 0.99) if lat else None,
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
    load0 = _load()
    step = bench_step(2000 if quick else 20000)
    instances = collect_instances(scenario, 200 if quick else 2000, 20.0 if quick else None)
    solvers = bench_solvers(instances, repeat=3 if quick else 5, backends=BACKENDS)
    central = bench_central((8,) if quick else (8, 32, 128), CENTRAL_BACKENDS,
                            repeat=3 if quick else 15)
    inproc = bench_inprocess(scenario, 10.0 if quick else None)
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
    }


def _f(v, fmt: str = ".1f", none: str = "-") -> str:
    return none if v is None else format(v, fmt)


def format_table(result: dict) -> str:
    """The human-readable table of a :func:`run_bench` result."""
    st = result["step"]
    lines = [
        f"control step (4-robot formation, 2 obstacles, 3 other formations, {st['rows']} rows): "
        f"median {st['step_us_median']:.1f} us, p99 {st['step_us_p99']:.1f} us; "
        f"build_rows {st['build_rows_us_median']:.1f} us",
        "  same QP solved alone: " + ", ".join(f"{k} {v:.1f} us"
                                                 for k, v in st["solve_us_median"].items()),
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
    lines.append(f"{'N':>4}{'Hz':>5}{'slots':>6}{'rate':>7}{'missed':>8}{'overrun':>8}{'p50 ms':>8}"
                 f"{'p99 ms':>8}{'wait':>7}{'tick':>7}{'net':>7}{'cpu %':>7}{'rss MB':>8}"
                 f"{'all %':>7}{'other %':>8}")
    fleets = [(n, a) for n, a in result["agents"].items()]
    fleets += [(f"{n}s", a) for n, a in result.get("agents_pose_slots", {}).items()]
    fleets += [(f"{n}c", a) for n, a in result.get("agents_clock_ticks", {}).items()]
    for n, a in fleets:
        parts = a["latency_parts_ms_median"]
        lines.append(
            f"{n:>4}{a['rate_hz_target']:>5.0f}{a.get('pose_slots', 1):>6}{_f(a['rate_hz']):>7}"
            f"{a['missed_ticks']:>8}"
            f"{a['agent_overruns']:>8}{_f(a['latency_ms_p50'], '.2f'):>8}"
            f"{_f(a['latency_ms_p99'], '.2f'):>8}{_f(parts['pose_wait_for_tick'], '.2f'):>7}"
            f"{_f(parts['tick'], '.2f'):>7}{_f(parts['transport_rest'], '.2f'):>7}"
            f"{_f(a['cpu_percent_per_agent_median']):>7}{_f(a['rss_mb_per_agent_median']):>8}"
            f"{_f(a.get('fleet_cpu_percent'), '.0f'):>7}{_f(a.get('others_cpu_percent'), '.0f'):>8}")
    lines.append("  slots: 1 = every pose of a tick at once (one camera frame); Ns: the world publishes "
                 "each formation's poses in its own slot of the period")
    if result.get("agents_clock_ticks"):
        lines.append("  Nc: agents ticking on their own clock (--clock-ticks); the others tick on pose "
                     "arrival")
    lines.append("  wait: pose received -> tick starts; tick: tick start -> command put; net: the rest "
                 "(router both ways, Zenoh and Python threads, CPU queueing); medians")
    lines.append("  cpu %: per agent (median), of one core; all %: agents + router + world; other %: "
                 "other people's processes meanwhile (2 cores = 200)")
    ip = result["inprocess"]
    lines.append("")
    lines.append(f"in-process simulation, {ip['scenario']} ({ip['robots']} robots, {ip['ticks']} "
                 f"ticks): {ip['robot_steps_per_s']:.0f} robot-steps/s wall, "
                 f"{_f(ip['robot_steps_per_cpu_s'], '.0f')} per CPU second")
    lines.append(f"machine: {result['machine']['cpus']} CPUs, load average "
                 f"{_f(result['machine']['load_avg_1min_at_start'])} at start")
    return "\n".join(lines)


def bench_command(ns: argparse.Namespace) -> int:
    """``formation bench --out DIR [--quick]``."""
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    result = run_bench(quick=ns.quick)
    (out / "bench.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    table = format_table(result)
    (out / "bench.txt").write_text(table + "\n", encoding="utf-8")
    print(table)
    print(f"wrote {out / 'bench.json'}")
    sys.stdout.flush()
    return 0
