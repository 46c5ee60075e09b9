"""``formation run``: the multi-process simulation over Zenoh (DESIGN.md, "Command line").

The launcher validates the scenario, picks a loopback port, and starts, each in its own process
group (``start_new_session``) with explicit ``tcp/127.0.0.1:PORT`` endpoints and multicast
scouting off:

* a Zenoh router (``python -m wire.router``);
* one agent per robot (``python -m agent --config DIR/configs/ROBOT.yaml``, ``--lockstep`` unless
  ``--realtime``), each writing its counters to ``DIR/agents/ROBOT.json`` when it stops.

The simulated world (:class:`simulator.world.World`) runs in the launcher's own process on a
client session, so progress is shown as it goes. When every goal is reached (or the duration is
over) the agents get SIGTERM, the launcher collects their counters and traces, and writes
``summary.json`` (``mode: "multiprocess"``), the time series and the figures with
:func:`simulator.output.write_run`. Every child is stopped (SIGTERM to its process group, SIGKILL
after a timeout) on every way out: success, Ctrl-C or SIGTERM, a crashed child, an exception.
``DIR/processes.json`` lists the children's PIDs; ``DIR/logs/`` holds their output.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import IO

import zenoh

from agent.config import ZenohSettings, build_agent_configs, save_config
from scenario import Scenario, load_scenario
from wire import keys, traffic
from wire.testing import free_tcp_port, tcp_endpoint, wait_for_tcp_port
from wire.zconf import ZenohSettings as WireZenohSettings

from .inprocess import Series
from .output import write_run
from .world import World, WorldOptions, WorldResult

logger = logging.getLogger(__name__)

REPO_ROOT = Path(__file__).resolve().parent.parent
STOP_TIMEOUT_S = 5.0  # [s] SIGTERM -> SIGKILL
START_TIMEOUT_S = 60.0  # [s] router listening, agents subscribed
INTER_ROBOT = (keys.STATE, keys.ELLIPSE, keys.OTHERS)  # classes the topology decides


class ChildFailed(RuntimeError):
    """A child process exited while the run needed it."""


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log: IO[bytes]


class Supervisor:
    """Starts children in their own process groups and stops every one of them."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.children: list[Child] = []
        self.env = dict(os.environ)
        self.env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(REPO_ROOT), self.env.get("PYTHONPATH", "")) if p)

    def start(self, name: str, argv: Sequence[str]) -> Child:
        log = (self.log_dir / f"{name}.log").open("wb")
        try:
            proc = subprocess.Popen([sys.executable, *argv], env=self.env, stdin=subprocess.DEVNULL,
                                    stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        except BaseException:
            log.close()
            raise
        child = Child(name, proc, log)
        self.children.append(child)
        return child

    def check(self) -> None:
        """Raise :class:`ChildFailed` if any child has exited."""
        for c in self.children:
            code = c.proc.poll()
            if code is not None:
                path = self.log_dir / f"{c.name}.log"
                c.log.flush()
                try:
                    tail = path.read_text(encoding="utf-8", errors="replace").strip().splitlines()[-3:]
                except OSError:
                    tail = []
                raise ChildFailed(f"{c.name} exited with status {code} (see {path})"
                                  + (": " + " | ".join(tail) if tail else ""))

    def stop(self, children: Sequence[Child] | None = None, timeout: float = STOP_TIMEOUT_S) -> None:
        """SIGTERM to each child's process group, wait, SIGKILL what is left."""
        targets = list(self.children if children is None else children)
        for c in targets:
            if c.proc.poll() is None:
                _signal_group(c.proc.pid, signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for c in targets:
            try:
                c.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                logger.warning("%s (pid %d) ignored SIGTERM; killing it", c.name, c.proc.pid)
            _signal_group(c.proc.pid, signal.SIGKILL)  # whatever is left in its group
            if c.proc.poll() is None:
                c.proc.wait(timeout)
            c.log.close()
        if children is None:
            self.children.clear()
        else:
            self.children = [c for c in self.children if c not in targets]


def _signal_group(pid: int, sig: int) -> None:
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _raise_interrupt(signum: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")


def run_command(ns: argparse.Namespace) -> int:
    """``formation run``; see the module docstring. Returns the exit status."""
    from formation.cli import EXIT_OK, Progress, UsageError, print_summary

    if ns.drop or ns.delay_ms:
        raise UsageError("--drop and --delay-ms: not yet supported by formation run")
    if ns.camera == "synthetic":
        try:
            import camera_service.service  # noqa: F401
        except ImportError:
            raise UsageError("--camera synthetic: camera_service.service is not available yet") from None
    if not 0 <= ns.port < 65536:
        raise UsageError(f"--port: {ns.port} is not a TCP port")
    scenario = load_scenario(ns.scenario)  # ScenarioError -> exit 2
    out = Path(ns.out)
    summary, series = launch(scenario, out, realtime=ns.realtime, camera=ns.camera,
                             topology=ns.topology, safety=not ns.no_safety, port=ns.port,
                             progress_factory=lambda: Progress(f"run {scenario.name}", quiet=ns.quiet))
    write_run(summary, series, scenario, out, plots=not ns.no_plots)
    print_summary(summary, out)
    return EXIT_OK


def launch(
    scenario: Scenario,
    out: Path,
    *,
    realtime: bool = False,
    camera: str = "truth",
    topology: str = "reduced",
    safety: bool = True,
    port: int = 0,
    progress_factory=None,
) -> tuple[dict, Series]:
    """Run ``scenario`` as separate processes; returns the summary and the time series."""
    out = Path(out)
    for sub in ("configs", "agents", "logs"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for old in (out / "agents").glob("*.json"):
        old.unlink()
    port = port or free_tcp_port()
    endpoint = tcp_endpoint(port)
    sup = Supervisor(out / "logs")
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        router = sup.start("router", ["-m", "wire.router", "--listen", endpoint,
                                      "--log-level", "WARNING"])
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            sup.check()
            try:
                wait_for_tcp_port(port, timeout_s=0.2)
                break
            except TimeoutError:
                if time.monotonic() > deadline:
                    raise
        zs = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False)
        configs = build_agent_configs(scenario, zenoh=zs, topology=topology, safety=safety)
        agents = []
        for rid, cfg in configs.items():
            path = out / "configs" / f"{rid}.yaml"
            save_config(cfg, path)
            argv = ["-m", "agent", "--config", str(path), "--stats", str(out / "agents" / f"{rid}.json")]
            if not realtime:
                argv.append("--lockstep")
            agents.append(sup.start(f"agent-{rid}", argv))
        (out / "processes.json").write_text(json.dumps(
            {c.name: c.proc.pid for c in sup.children}, indent=2) + "\n", encoding="utf-8")
        conf = WireZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                                 connect_timeout_s=10.0).to_config()
        options = WorldOptions(realtime=realtime, camera=camera, prefix=keys.DEFAULT_PREFIX,
                               start_timeout=START_TIMEOUT_S)
        with zenoh.open(conf) as session:
            world = World(scenario, session, options)
            try:
                world.wait_for_agents(abort=sup.check)
                if progress_factory is not None:
                    with progress_factory() as progress:
                        result = world.run(progress=progress.update, abort=sup.check)
                else:
                    result = world.run(abort=sup.check)
            finally:
                world.close()
        sup.stop(agents)  # agents write their stats on SIGTERM
        sup.stop([router])
    finally:
        sup.stop()
        signal.signal(signal.SIGTERM, previous)
    stats = [_read_stats(out / "agents" / f"{rid}.json") for rid in configs]
    return build_summary(scenario, result, stats, topology, realtime, camera, safety)


def _read_stats(path: Path) -> dict:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ChildFailed(f"agent counters {path} missing or unreadable: {exc}") from None


def build_summary(scenario: Scenario, result: WorldResult, stats: list[dict], topology: str,
                  realtime: bool, camera: str, safety: bool) -> tuple[dict, Series]:
    """``summary.json`` of a multi-process run, and the time series with the agents' traces."""
    series = merge_traces(result, stats, scenario.dt)
    n = len(scenario.robot_ids)
    sim_time = result.sim_time
    solve_us = [row[12] for s in stats for row in s["trace"] if row[12] is not None]
    relaxed = sum(s["relaxed"] for s in stats)
    fallback = sum(s["fallback"] for s in stats)
    failed = sum(s["failed"] for s in stats)
    min_h = {}
    for kind in ("formation", "obstacle", "formations"):
        vals = [s["min_h"][kind] for s in stats if s["min_h"][kind] is not None]
        min_h[kind] = min(vals) if vals else None
    snap = traffic.merge([result.traffic, *(s["traffic"] for s in stats)])
    summary = {
        "scenario": scenario.name,
        "mode": "multiprocess",
        "steps": result.steps,
        "sim_time_s": round(sim_time, 6),
        **result.monitor.summary_fields(),
        "min_h": min_h,
        "qp": {
            "solves": sum(s["solves"] for s in stats),
            "infeasible": relaxed + fallback + failed,
            "solve_us_median": statistics.median(solve_us) if solve_us else None,
            "relaxed": relaxed,
            "fallback": fallback,
            "failed": failed,
        },
        "comm": comm_summary(snap, topology, n, sim_time),
        "safety": safety,
        "solver": "exact",
        "realtime": realtime,
        "camera": camera,
        "agents": {
            "ticks": sum(s["ticks"] for s in stats),
            "overruns": sum(s["overruns"] for s in stats),
            "stale": sum(s["stale"] for s in stats),
            "waiting_for_pose": sum(s.get("waiting", 0) for s in stats),
            "lockstep_timeouts": sum(s.get("lockstep_timeouts", 0) for s in stats),
            "dropped": _sum_dicts(s["dropped"] for s in stats),
            "cpu_s": {s["robot"]: s["cpu_s"] for s in stats},
            "wall_s": max((s["wall_s"] for s in stats), default=None),
            "tick_us_median": _median([s["tick_us_median"] for s in stats]),
            "pose_age_us_median": _median([s.get("pose_age_us_median") for s in stats]),
        },
        "world": {
            "missing_cmds": result.missing_cmds,
            "malformed_cmds": result.malformed_cmds,
            "wall_s": result.wall_s,
            "latency_ms": _latency(result.latency_ms),
        },
        "collision_log": result.monitor.collision_log[:100],
    }
    return summary, series


def comm_summary(snap: dict, topology: str, n: int, sim_time: float) -> dict:
    """``comm`` of the contract, from traffic counted at publishers and subscribers.

    ``messages``/``bytes`` are the deliveries received by agents on the classes the topology
    decides (``state``, ``ellipse``, ``others``), comparable to the in-process model; ``classes``
    breaks every class down into what was put and what was received.
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
    }


def merge_traces(result: WorldResult, stats: list[dict], dt: float) -> Series:
    """The world's rows with ``status``, ``slack`` and ``h_*`` from each agent's trace entry for
    the pose the world published at that tick; leaders' ellipses become ``ellipses`` rows."""
    by_key: dict[tuple[str, float], list] = {}
    for s in stats:
        for row in s["trace"]:
            by_key[(s["robot"], row[0])] = row
    series = Series(obstacles=result.series.obstacles)
    for row in result.series.robots:
        t, rid = row[0], row[1]
        k = round(t / dt) if dt else 0
        stamp = result.stamps[k] if k < len(result.stamps) else t
        tr = by_key.get((rid, stamp))
        if tr is None:
            series.robots.append(row)
            continue
        status, slack, hf, ho, he = tr[7], tr[8], tr[9], tr[10], tr[11]
        series.robots.append((*row[:12], status, _nan(slack), _nan(hf), _nan(ho), _nan(he)))
    t_of = {stamp: k * dt for k, stamp in enumerate(result.stamps)}
    for s in stats:
        for row in s.get("ellipse_trace", []):
            t = t_of.get(row[0])
            if t is not None:
                series.ellipses.append((t, s["formation"], *row[1:]))
    series.ellipses.sort(key=lambda r: (r[0], r[1]))
    return series


def _nan(v):
    return math.nan if v is None else v


def _sum_dicts(dicts) -> dict:
    out: dict[str, int] = {}
    for d in dicts:
        for k, v in d.items():
            out[k] = out.get(k, 0) + v
    return out


def _median(vals):
    vals = [v for v in vals if v is not None]
    return statistics.median(vals) if vals else None


def _latency(ms: list[float]) -> dict | None:
    if not ms:
        return None
    xs = sorted(ms)
    return {"samples": len(xs), "median_ms": statistics.median(xs),
            "p99_ms": xs[min(len(xs) - 1, int(math.ceil(0.99 * len(xs))) - 1)], "max_ms": xs[-1]}
