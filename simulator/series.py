"""What a run measured: the time series (robots.csv's columns), and the world process's result.

Shared by the in-process simulator, the world, the summary, the figures and the files; a leaf of
the simulator package, so the summary reads them without importing the simulators that import it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from .metrics import SafetyMonitor

if TYPE_CHECKING:
    from scenario import Scenario

ROBOT_COLUMNS = (
    "t", "robot", "formation", "x", "y", "theta", "px", "py", "ux", "uy", "v", "omega",
    "status", "slack", "h_formation", "h_obstacle", "h_formations",
)
#: robots.csv gains these [m/s^2] (the certified acceleration) only in a run of double
#: integrators, so every other run's file stays as it was, byte for byte
ACCEL_COLUMNS = ("ax", "ay")
#: and these (the agent's own estimate and its 95 % radius) only under
#: ``controller.localisation: fused`` (:mod:`simulator.fused`)
LOCALISATION_COLUMNS = ("est_x", "est_y", "sigma_m")


def robot_columns(scenario: Scenario) -> tuple[str, ...]:
    """robots.csv's columns for a run of ``scenario``."""
    cols: tuple[str, ...] = ROBOT_COLUMNS
    if scenario.robot.is_double_integrator:
        cols += ACCEL_COLUMNS
    if scenario.controller.localisation == "fused":
        cols += LOCALISATION_COLUMNS
    return cols


@dataclass
class Series:
    """Time series of a run, in long form (one row per robot per tick)."""

    robots: list[tuple] = field(default_factory=list)  # ROBOT_COLUMNS
    ellipses: list[tuple] = field(default_factory=list)  # t, formation, Ellipse fields
    obstacles: list[tuple] = field(default_factory=list)  # t, name, x, y, safe_distance


@dataclass
class WorldResult:
    steps: int
    sim_time: float
    monitor: SafetyMonitor
    series: Series
    traffic: dict
    missing_cmds: int = 0  # robot-ticks without a command (lock-step: not in time; real time:
    # none fresher than stale_after): the robot got zero velocity
    zero_cmds: int = 0  # robot-ticks whose applied command was zero (the agent stopped it)
    malformed_cmds: int = 0
    stamp_rejected: dict = field(default_factory=dict)  # commands refused by the stamp check
    clock_offset: float = 0.0  # [s] real time: the camera's clock ahead of the agents'
    cmd_timeouts: int = 0  # lock-step: waits for a command that timed out
    camera_dropped: int = 0  # poses not published (camera dropout)
    latency_ms: list[float] = field(default_factory=list)  # real time: pose put -> cmd received
    publish_ms: list[float] = field(default_factory=list)  # real time, one frame a period: the
    # tick's stamp -> its last pose put (how long the world takes to publish a frame)
    stamps: list[float] = field(default_factory=list)  # pose stamp published at tick k
    # pose slots > 1: the stamp each robot's pose of tick k went out with (its slot's); else empty
    robot_stamps: list[list[float]] = field(default_factory=list)
    wall_s: float = 0.0
    physics: dict = field(default_factory=dict)  # what the engine adds to summary.json (mujoco)
