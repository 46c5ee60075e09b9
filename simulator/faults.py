"""The faults of a multi-process run (docs/faults.md): the plan, its parsers, the driver that
kills and restarts agents at their simulated times, and ``faults`` of ``summary.json``.

``--drop P`` and ``--delay-ms D`` are handed to every agent, which applies them to the ``state``,
``ellipse`` and ``others`` messages it receives (seeded by ``--fault-seed``); ``--kill
ROBOT@T[:AFTER]`` SIGKILLs that robot's agent at simulated time ``T`` and, with ``AFTER``, starts
a new one ``AFTER`` seconds later (in lock-step the world waits for it to subscribe, so the
restart takes no simulated time beyond ``AFTER``); ``--camera-dropout ROBOT@T:DURATION`` makes the
world stop publishing that robot's pose. Fault runs keep the lock-step clock with short timeouts
(:data:`FAULT_AGENT_TIMEOUT_S`, :data:`FAULT_WORLD_TIMEOUT_S`): a loss is known to the receiver's
simulation at once, a silent process costs one timeout and is then not waited for until it
speaks again.
"""

from __future__ import annotations

import logging
import math
import signal
import time
from collections.abc import Sequence
from dataclasses import dataclass

from agent.faults import LinkFaults
from agent.stats import AgentStats
from wire import keys

from .fleet import Child, Fleet, signal_group
from .summary import sum_counts
from .world import World, WorldResult

logger = logging.getLogger(__name__)

FAULT_AGENT_TIMEOUT_S = 0.3  # [s] lock-step wait per input of an agent in a fault run
FAULT_WORLD_TIMEOUT_S = 1.5  # [s] lock-step wait for a tick's commands in a fault run


def restart_log_name(robot: str, incarnation: int) -> str:
    """The process (and log file) name of a robot's restarted agent: ``agent-ROBOT#N``; a robot
    name holds no ``#`` (:func:`wire.keys.name_problem`), so robot ``a1-2``'s first agent and
    robot ``a1``'s second never share a log file."""
    return f"agent-{robot}#{incarnation}"


@dataclass(frozen=True)
class Kill:
    """SIGKILL ``robot``'s agent at simulated time ``at``; restart it ``restart_after`` later."""

    robot: str
    at: float  # [s]
    restart_after: float | None = None  # [s]; None: it stays dead

    def check(self) -> None:
        """ValueError naming the robot when a time is out of range."""
        if not (math.isfinite(self.at) and self.at >= 0):
            raise ValueError(f"kill: {self.robot}: time must be >= 0, got {self.at!r}")
        after = self.restart_after
        if after is not None and not (math.isfinite(after) and after > 0):
            raise ValueError(f"kill: {self.robot}: restart delay must be > 0, got {after!r}")


@dataclass(frozen=True)
class CameraDropout:
    """The world publishes no pose of ``robot`` from ``at`` for ``duration`` seconds."""

    robot: str
    at: float  # [s]
    duration: float  # [s]

    def check(self) -> None:
        """ValueError naming the robot when a time is out of range."""
        if not (math.isfinite(self.at) and self.at >= 0 and math.isfinite(self.duration)
                and self.duration > 0):
            raise ValueError(f"camera-dropout: {self.robot}: need time >= 0 and duration > 0")


@dataclass(frozen=True)
class FaultPlan:
    """Every fault of one run; the default is none (the run equals ``formation sim``)."""

    drop: float = 0.0  # probability
    delay_ms: float = 0.0  # [ms]
    seed: int = 0
    kills: tuple[Kill, ...] = ()
    camera_dropouts: tuple[CameraDropout, ...] = ()
    ellipse_hold: float = 10.0  # [s] see agent.node.NodeOptions

    def __post_init__(self) -> None:
        LinkFaults(self.drop, self.delay_ms / 1000.0, self.seed)  # ValueError naming the field
        for kill in self.kills:
            kill.check()
        for dropout in self.camera_dropouts:
            dropout.check()

    @property
    def active(self) -> bool:
        return bool(self.drop or self.delay_ms or self.kills or self.camera_dropouts)

    @property
    def link(self) -> LinkFaults:
        return LinkFaults(self.drop, self.delay_ms / 1000.0, self.seed)

    def check_robots(self, robots: Sequence[str]) -> None:
        """ValueError naming a fault that names an unknown robot."""
        for name, items in (("kill", self.kills), ("camera-dropout", self.camera_dropouts)):
            for item in items:
                if item.robot not in robots:
                    raise ValueError(f"{name}: unknown robot {item.robot!r}")

    def agent_args(self) -> list[str]:
        """What every agent of a fault run is started with (none without faults)."""
        if not self.active:
            return []
        return ["--drop", repr(self.drop), "--delay-ms", repr(self.delay_ms),
                "--fault-seed", str(self.seed), "--ellipse-hold", repr(self.ellipse_hold),
                "--lockstep-timeout", repr(FAULT_AGENT_TIMEOUT_S)]


def _number(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{what}: {text!r} is not a finite number")
    return v


def parse_kill(text: str) -> Kill:
    """``ROBOT@T`` or ``ROBOT@T:RESTART_AFTER`` (seconds of simulated time)."""
    robot, sep, rest = text.partition("@")
    if not sep or not robot:
        raise ValueError(f"kill: {text!r} is not ROBOT@T[:RESTART_AFTER]")
    at, sep, after = rest.partition(":")
    return Kill(robot, _number(at, "kill"), _number(after, "kill") if sep else None)


def parse_camera_dropout(text: str) -> CameraDropout:
    """``ROBOT@T:DURATION`` (seconds of simulated time)."""
    robot, sep, rest = text.partition("@")
    at, sep2, duration = rest.partition(":")
    if not (sep and sep2 and robot):
        raise ValueError(f"camera-dropout: {text!r} is not ROBOT@T:DURATION")
    return CameraDropout(robot, _number(at, "camera-dropout"), _number(duration, "camera-dropout"))


class FaultDriver:
    """Kills and restarts agents at their simulated times (``World.run(on_tick=...)``)."""

    def __init__(self, plan: FaultPlan, fleet: Fleet, world: World, agents: dict[str, Child],
                 dt: float, realtime: bool, restart_limit: int = 0) -> None:
        self.fleet = fleet
        self.world = world
        self.agents = agents
        self.argv = fleet.agent_argv
        self.realtime = realtime
        self.log: list[dict] = []
        # (tick, order, action, robot): kills before restarts within a tick
        self.events: list[tuple[int, int, str, str]] = []
        for k in plan.kills:
            self.events.append((math.ceil(k.at / dt - 1e-9), 0, "kill", k.robot))
            if k.restart_after is not None:
                self.events.append((math.ceil((k.at + k.restart_after) / dt - 1e-9), 1,
                                    "restart", k.robot))
        self.events.sort()
        self.incarnation = dict.fromkeys(agents, 1)
        self.restart_limit = restart_limit  # crashes restarted per robot (--restart on-failure)
        self.restarts: dict[str, int] = {}  # robot -> crashed agents restarted
        self.t = 0.0  # [s] the simulated time of the latest tick

    def recover(self) -> bool:
        """An agent here exited on its own (a crash): restart it as systemd would on a robot,
        at most ``restart_limit`` times per robot (counted, logged). False when none was
        restarted (none crashed, or its limit is reached): the run then aborts."""
        crashed = [rid for rid, c in self.agents.items()
                   if not c.where and c.proc.poll() is not None]
        if not crashed or any(self.restarts.get(r, 0) >= self.restart_limit for r in crashed):
            return False
        for rid in crashed:
            child = self.agents.pop(rid)
            code = child.proc.returncode
            self.fleet.stop([child])  # reaps it, closes its log
            self.restarts[rid] = self.restarts.get(rid, 0) + 1
            logger.warning("agent %s exited with status %s at t=%.2f s: restarting it (%d of %d)",
                           rid, code, self.t, self.restarts[rid], self.restart_limit)
            self.log.append({"event": "crash", "robot": rid, "t_s": round(self.t, 6),
                             "status": code})
            self.restart(rid, self.t, missed_frame=True)
        return True

    def on_tick(self, k: int, t: float) -> None:
        self.t = t
        while self.events and self.events[0][0] <= k:
            _, _, action, rid = self.events.pop(0)
            if action == "kill":
                self.kill(rid, t)
            else:
                self.restart(rid, t)

    def kill(self, rid: str, t: float) -> None:
        child = self.agents.pop(rid, None)
        if child is None:
            logger.warning("kill %s at t=%.2f s: its agent is not running", rid, t)
            return
        signal_group(child.proc.pid, signal.SIGKILL)
        self.fleet.stop([child])  # reaps it, closes its log
        gone = self.world.wait_unsubscribed(rid)
        logger.info("killed agent %s at t=%.2f s (router saw it go: %s)", rid, t, gone)
        self.log.append({"event": "kill", "robot": rid, "t_s": round(t, 6)})

    def restart(self, rid: str, t: float, missed_frame: bool = False) -> None:
        """Start ``rid``'s agent again at simulated time ``t``. ``missed_frame``: the world's
        wait for this tick's commands is under way (a crash found while waiting), so the new
        agent never saw this tick's poses: the world does not wait for its command of this tick,
        only from the next one (the neighbours that waited for it give up first)."""
        if rid in self.agents:
            logger.warning("restart %s at t=%.2f s: its agent is still running", rid, t)
            return
        self.incarnation[rid] += 1
        wall0 = time.monotonic()
        argv = self.argv[rid] + ([] if self.realtime else ["--sim-start", repr(t)])
        self.agents[rid] = self.fleet.start(restart_log_name(rid, self.incarnation[rid]), argv)
        if not self.realtime:  # lock-step: the restart takes no simulated time
            self.world.wait_for_agents(abort=self.fleet.check, robots=[rid], grace=False)
            if missed_frame:
                self.world.inbox.excuse(rid)
            else:
                self.world.inbox.expect(rid)  # and waits for its commands from the first tick
        self.log.append({"event": "restart", "robot": rid, "t_s": round(t, 6),
                         "start_wall_s": round(time.monotonic() - wall0, 3)})


def fault_summary(plan: FaultPlan, result: WorldResult, stats: Sequence[AgentStats],
                  log: list[dict]) -> dict:
    """``faults`` of ``summary.json``: what was injected and what it did."""
    dropped = sum_counts(s.fault_dropped for s in stats)
    return {
        "drop": plan.drop,
        "delay_ms": plan.delay_ms,
        "seed": plan.seed,
        "applies_to": [keys.STATE, keys.ELLIPSE, keys.OTHERS],  # what agent.faults affects
        "dropped_messages": sum(dropped.values()),
        "dropped": dropped,
        "delayed_messages": sum(s.fault_delayed for s in stats),
        "kills": [{"robot": k.robot, "at_s": k.at, "restart_after_s": k.restart_after}
                  for k in plan.kills],
        "camera_dropouts": [{"robot": c.robot, "at_s": c.at, "duration_s": c.duration}
                            for c in plan.camera_dropouts],
        "events": log,
        "camera_dropped_poses": result.camera_dropped,
        "zero_commands_applied": result.missing_cmds,
        "world_cmd_timeouts": result.cmd_timeouts,
        "agent_lockstep_timeouts": sum(s.lockstep_timeouts for s in stats),
        "stale_ticks": sum(s.stale for s in stats),
        "stale_ticks_by_input": sum_counts(s.stale_why for s in stats),
        "stale_ticks_by_robot": {s.robot: s.stale for s in stats},
        "inflated_ellipse_ticks": sum(s.inflated for s in stats),
        "standing_body_ticks": sum(s.standing for s in stats),
        "leader_takeovers": {s.robot: s.takeovers for s in stats if s.takeovers},
        "acting_leader_ticks": sum(s.acting_leader_ticks for s in stats),
        "counters_lost_with_killed_agents": bool(plan.kills),
    }
