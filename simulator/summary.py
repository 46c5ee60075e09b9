"""``summary.json`` of a run, built in one place for the in-process simulator
(:mod:`simulator.inprocess`) and the multi-process run (:mod:`simulator.launch`).

A multi-process run's summary (:func:`build_summary`) adds up every agent's counters, read back
as :class:`agent.stats.AgentStats` (:mod:`simulator.counters`), and merges the agents' traces into
the world's time series (:func:`merge_traces`); :func:`mark_aborted` notes why a run that had
started stopped early.

The key order is the file's: scenario, mode, steps, sim_time_s, the safety monitor's fields,
min_h, hard_row_unmet_ticks (also in qp), qp, motion (:mod:`simulator.motion`, when given),
comm, safety, solver, world_profile, then what only one kind of run has, then collision_log.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from agent.stats import AgentStats
from scenario import Scenario
from wire import keys, traffic
from wire.stamps import merge_counts

from .goals import first_at_goals
from .metrics import SafetyMonitor
from .motion import motion_fields
from .series import ROBOT_COLUMNS, Series, WorldResult

COLLISION_LOG_MAX = 100  # collision_log entries kept in summary.json


def qp_fields(solves: int, solve_us: Sequence[float], relaxed: int, fallback: int,
              failed: int, hard_unmet: int = 0, hard_reasons: dict[str, int] | None = None,
              **extra: int) -> dict[str, Any]:
    """``qp`` of the summary: solves, the ticks whose QP was not solved as posed (relaxed,
    fallback or failed), the median solve time [us], the ticks on which a hard row was not met
    (agent.hard_rows; relaxed formation rows are by design and not among them); ``extra``
    counts (e.g. ``escape``: ticks on which the formation stepped out of a hazard's way)
    follow."""
    return {
        "solves": solves,
        "infeasible": relaxed + fallback + failed,
        "solve_us_median": statistics.median(solve_us) if solve_us else None,
        "relaxed": relaxed,
        "fallback": fallback,
        "failed": failed,
        "hard_row_unmet_ticks": hard_unmet,
        "hard_row_unmet": dict(hard_reasons or {}),
        **extra,
    }


@dataclass(frozen=True)
class RunKind:
    """How a run ran: ``mode`` ("inprocess" or "multiprocess"), with barriers or not
    (``safety``), and the QP ``solver``."""

    mode: str
    safety: bool
    solver: str


def run_summary(scenario: Scenario, kind: RunKind, steps: int, sim_time: float,
                monitor: SafetyMonitor, min_h: dict[str, float | None], qp: dict[str, Any],
                comm: dict[str, Any], motion: dict[str, Any] | None = None,
                **extra: Any) -> dict[str, Any]:
    """The summary of a run of ``scenario`` (see the module docstring); ``extra`` goes after
    ``solver`` in the order given."""
    return {
        "scenario": scenario.name,
        "mode": kind.mode,
        "steps": steps,
        "sim_time_s": round(sim_time, 6),
        **monitor.summary_fields(),
        "min_h": min_h,
        "hard_row_unmet_ticks": qp.get("hard_row_unmet_ticks", 0),
        "qp": qp,
        **({"motion": motion} if motion is not None else {}),
        "comm": comm,
        "safety": kind.safety,
        "solver": kind.solver,
        "world_profile": scenario.world.summary(),  # the world the run had (scenario.world)
        **extra,
        "collision_log": monitor.collision_log[:COLLISION_LOG_MAX],
    }


# control traffic between robots: the classes the topology decides, and the leader's plans to
# its members (sent only when a goal arrives at run time, and then once a second)
INTER_ROBOT = (keys.STATE, keys.ELLIPSE, keys.OTHERS, keys.PLAN, keys.BEACON)


def sum_counts(dicts: Iterable[dict[str, int]]) -> dict[str, int]:
    """Counters of several agents (dicts of name -> count) added up per name."""
    out: dict[str, int] = {}
    for d in dicts:
        for k, v in d.items():
            out[k] = out.get(k, 0) + v
    return out


# --------------------------------------------------------------------------- the summary


def build_summary(scenario: Scenario, result: WorldResult, stats: Sequence[AgentStats],
                  topology: str, realtime: bool, camera: str, safety: bool,
                  solver: str = "exact") -> tuple[dict, Series]:
    """``summary.json`` of a multi-process run, and the time series with the agents' traces."""
    series = merge_traces(result, stats, scenario.dt)
    sim_time = result.sim_time
    solve_us = [row[12] for s in stats for row in s.trace if row[12] is not None]
    snap = traffic.merge([result.traffic, *(s.traffic for s in stats)])
    summary = run_summary(
        scenario, RunKind("multiprocess", safety, solver), result.steps, sim_time,
        result.monitor, _min_h(stats),
        qp_fields(sum(s.solves for s in stats), solve_us, sum(s.relaxed for s in stats),
                  sum(s.fallback for s in stats), sum(s.failed for s in stats),
                  sum(s.hard_row_unmet_ticks for s in stats),
                  sum_counts(s.hard_row_unmet for s in stats),
                  escape=sum(s.escape_ticks for s in stats)),
        comm_summary(snap, topology, len(scenario.robot_ids), sim_time),
        motion=motion_fields(series.robots, ROBOT_COLUMNS, scenario),
        realtime=realtime,
        camera=camera,
        agents=_agents_fields(stats),
        world=_world_fields(result),
        time_to_goal_by_formation_s=formation_goal_times(scenario, series,
                                                         result.monitor.time_to_goal),
        goals_by_formation=goal_counts(scenario, stats),
        **result.physics,  # --engine mujoco: the engine's contacts (simulator.physics)
    )
    return summary, series


def _min_h(stats: Sequence[AgentStats]) -> dict[str, float | None]:
    """The smallest barrier value of each kind over every agent (None where none had one)."""
    out: dict[str, float | None] = {}
    for kind in ("formation", "obstacle", "formations"):
        vals = [v for s in stats if (v := s.min_h[kind]) is not None]
        out[kind] = min(vals) if vals else None
    return out


def _agents_fields(stats: Sequence[AgentStats]) -> dict[str, Any]:
    """``agents`` of the summary: the agents' counters added up."""
    return {
        "ticks": sum(s.ticks for s in stats),
        "tick_errors": sum(s.tick_errors for s in stats),
        "overruns": sum(s.overruns for s in stats),
        "stale": sum(s.stale for s in stats),
        "waiting_for_pose": sum(s.waiting for s in stats),
        "lockstep_timeouts": sum(s.lockstep_timeouts for s in stats),
        "dropped": sum_counts(s.dropped for s in stats),
        "stale_why": sum_counts(s.stale_why for s in stats),
        "stamp_rejected": merge_counts([s.stamp_rejected for s in stats]),
        "lockstep_catch_ups": sum(s.lockstep_catch_ups for s in stats),
        "implausible": sum_counts(s.implausible for s in stats),
        "reacquired": sum(s.reacquired for s in stats),
        "obstacles_missing": sum(s.obstacles_missing for s in stats),
        "obstacle_held_ticks": sum(s.obstacle_held_ticks for s in stats),
        "obstacles_dropped_after_hold": sum(s.obstacles_dropped_after_hold for s in stats),
        "cpu_s": {s.robot: s.cpu_s for s in stats},
        "wall_s": max((s.wall_s for s in stats), default=None),
        "tick_us_median": _median([s.tick_us_median for s in stats]),
        "pose_age_us_median": _median([s.pose_age_us_median for s in stats]),
    }


def _world_fields(result: WorldResult) -> dict[str, Any]:
    """``world`` of the summary: what the world counted."""
    return {
        "missing_cmds": result.missing_cmds,
        "zero_cmds": result.zero_cmds,
        "malformed_cmds": result.malformed_cmds,
        "stamp_rejected": result.stamp_rejected,
        "clock_offset_s": result.clock_offset,  # real time: the camera's clock ahead
        "wall_s": result.wall_s,
        "latency_ms": _latency(result.latency_ms),
    }


def goal_counts(scenario: Scenario, stats: Sequence[AgentStats]) -> dict[str, dict[str, Any]]:
    """``goals_by_formation``: per formation the goals its leader took at run time (``taken``),
    refused (``refused``: at the door, as stale or inside an obstacle; the count on its
    ``status``) and why it refused the last one (``last_refusal``, null if none), from its
    agents' counters added up (a leader's reason first, then any other agent's)."""
    out: dict[str, dict[str, Any]] = {}
    for f in scenario.formations:
        mine = sorted((s for s in stats if s.formation == f.name), key=lambda s: not s.leader)
        why = next((s.goal_refusal for s in mine if s.goal_refusal), None)
        out[f.name] = {
            "taken": sum(s.nav.get("goals", 0) for s in mine),
            "refused": sum(s.nav.get("rejected", 0) + s.nav.get("goals_refused", 0) for s in mine),
            "last_refusal": why,
        }
    return out


def formation_goal_times(scenario: Scenario, series: Series,
                         all_reached_at: float | None = None) -> dict[str, float | None]:
    """When each formation first had every robot within ``goal_tolerance`` of its goal (None
    if never): with a dead leader one formation stands still while the others go on. The
    series ends with the state the last tick started from, so a formation first seen there
    when every robot reached (``all_reached_at``, the run's end) gets that time."""
    goal = {r.id: r.goal for r in scenario.robots}
    out: dict[str, float | None] = {}
    for f in scenario.formations:
        first = first_at_goals(series, goal, scenario.goal_tolerance, f.robot_ids)
        if first is not None:
            first = round(first, 6)
        elif all_reached_at is not None:
            first = round(all_reached_at, 6)
        out[f.name] = first
    return out


def comm_summary(snap: dict, topology: str, n: int, sim_time: float) -> dict:
    """``comm`` of the contract, from traffic counted at publishers and subscribers.

    ``messages``/``bytes`` are the deliveries received by agents on the classes the topology
    decides (``state``, ``ellipse``, ``others``), comparable to the in-process model; ``classes``
    breaks every class down into what was put and what was received; ``orders`` sums the order,
    bid and order-status classes per side (:func:`wire.traffic.orders_line`).
    """
    recv = snap["recv"]
    messages = sum(recv[c]["messages"] for c in INTER_ROBOT)
    nbytes = sum(recv[c]["bytes"] for c in INTER_ROBOT)
    per = n * sim_time
    return {
        "topology": topology,
        "messages": messages,
        "bytes": nbytes,
        "messages_per_robot_per_s": messages / per if per > 0 else 0.0,
        "bytes_per_robot_per_s": nbytes / per if per > 0 else 0.0,
        "source": "counted",
        "counted": "deliveries received of " + "+".join(INTER_ROBOT),
        "classes": {cls: {side: snap[side][cls] for side in traffic.SIDES}
                    for cls in keys.KEY_CLASSES},
        traffic.ORDERS: traffic.orders_line(snap),
    }


def merge_traces(result: WorldResult, stats: Sequence[AgentStats], dt: float) -> Series:
    """The world's rows with ``status``, ``slack`` and ``h_*`` from each agent's trace entry for
    the pose the world published at that tick; leaders' ellipses become ``ellipses`` rows.

    With pose slots each robot's pose of a tick goes out with its own slot's stamp
    (``result.robot_stamps``), which is the stamp its agent's trace is keyed by."""
    by_key: dict[tuple[str, float], list] = {}
    for s in stats:
        for entry in s.trace:
            by_key[(s.robot, entry[0])] = entry
    index: dict[str, int] = {}
    series = dataclasses.replace(result.series, robots=[], ellipses=[])  # the world's obstacles
    for row in result.series.robots:
        t, rid = row[0], row[1]
        k = round(t / dt) if dt else 0
        i = index.setdefault(rid, len(index))
        tr = by_key.get((rid, _stamp_of(result, k, i, t)))
        if tr is None:
            series.robots.append(row)
            continue
        status, slack, hf, ho, he = tr[7], tr[8], tr[9], tr[10], tr[11]
        series.robots.append((*row[:12], status, _nan(slack), _nan(hf), _nan(ho), _nan(he),
                              *row[len(ROBOT_COLUMNS):]))  # double integrators: ax, ay
    series.ellipses.extend(_ellipse_rows(result, stats, dt))
    return series


def _ellipse_rows(result: WorldResult, stats: Sequence[AgentStats], dt: float) -> list[tuple]:
    """The leaders' ellipses at the time of the pose stamp each was estimated from."""
    t_of = {stamp: k * dt for k, stamp in enumerate(result.stamps)}
    for k, sent in enumerate(result.robot_stamps):
        t_of.update((stamp, k * dt) for stamp in sent if math.isfinite(stamp))
    rows = []
    for s in stats:
        for row in s.ellipse_trace:
            t = t_of.get(row[0])
            if t is not None:
                rows.append((t, s.formation, *row[1:]))
    rows.sort(key=lambda r: (r[0], r[1]))
    return rows


def _stamp_of(result: WorldResult, k: int, i: int, t: float) -> float:
    """The stamp of robot ``i``'s pose at tick ``k`` (the tick's, or its slot's)."""
    if k < len(result.robot_stamps) and i < len(result.robot_stamps[k]):
        return result.robot_stamps[k][i]
    return result.stamps[k] if k < len(result.stamps) else t


def _nan(v):
    return math.nan if v is None else v


def _median(vals):
    vals = [v for v in vals if v is not None]
    return statistics.median(vals) if vals else None


def _latency(ms: list[float]) -> dict | None:
    if not ms:
        return None
    xs = sorted(ms)
    return {"samples": len(xs), "median_ms": statistics.median(xs),
            "p99_ms": xs[min(len(xs) - 1, int(math.ceil(0.99 * len(xs))) - 1)], "max_ms": xs[-1]}


def world_summary(result: WorldResult) -> dict:
    """What the world alone (``python -m simulator.world_cli``) reports of its run."""
    return {
        "steps": result.steps,
        "sim_time_s": round(result.sim_time, 6),
        **result.monitor.summary_fields(),
        "missing_cmds": result.missing_cmds,
        "zero_cmds": result.zero_cmds,
        "malformed_cmds": result.malformed_cmds,
        "stamp_rejected": result.stamp_rejected,
        "traffic": result.traffic,
        "wall_s": result.wall_s,
        "latency_ms": result.latency_ms,
    }


# --------------------------------------------------------------------------- an early end


def abort_reason(exc: BaseException) -> str:
    """``aborted`` of summary.json: why the run stopped early, in one line."""
    if isinstance(exc, KeyboardInterrupt):
        return f"interrupted ({exc.args[0] if exc.args else 'Ctrl-C'})"
    return f"{exc}".splitlines()[0] if str(exc) else type(exc).__name__


def mark_aborted(summary: dict, stats: Sequence[AgentStats], exc: BaseException) -> None:
    """``aborted`` (why) and ``aborted_counters_lost`` (the agents that wrote no counters)."""
    summary["aborted"] = abort_reason(exc)
    lost = sorted(s.robot for s in stats if s.counters_lost)
    if lost:
        summary["aborted_counters_lost"] = lost
