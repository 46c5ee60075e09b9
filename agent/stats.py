"""An agent's counters: one dataclass, written by the agent and read by the launcher and the summary.

The agent writes its :class:`AgentStats` as JSON (``--stats FILE``) when it stops; the launcher reads
every robot's file back with :meth:`AgentStats.from_json_dict` and the summary adds them up by
attribute. The JSON keys are the field names, in field order; a key a file lacks takes the
field's default (an older agent, or one that died before it could write everything), and a key
the dataclass does not know is refused, so a renamed counter cannot be read as zero unnoticed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

#: trace columns (agent.tick.TRACE_COLUMNS) travel with the trace, so a reader needs no import.
Trace = list[list[Any]]


@dataclass
class AgentStats:
    """Every counter of one agent over a run (see docs/outputs.md, "agents/ROBOT.json").

    Over 20 fields on purpose: it is the agent's JSON file, one field per key, flat so that a
    reader finds each counter by its name in the file and a renamed one is refused."""

    robot: str
    formation: str
    leader: bool = False  # by configuration (see takeovers)
    acting_leader: bool = False  # a successor leading for a dead leader at the end
    lockstep: bool = False
    ticks: int = 0
    overruns: int = 0
    deadline_ticks: int = 0
    early_poses: int = 0
    stale: int = 0
    waiting: int = 0
    lockstep_timeouts: int = 0
    stale_why: dict[str, int] = field(default_factory=dict)
    stamp_rejected: dict[str, dict[str, int]] = field(default_factory=dict)
    lockstep_catch_ups: int = 0
    implausible: dict[str, int] = field(default_factory=dict)
    reacquired: int = 0  # poses taken as the new kept pose after a jump (marker re-acquire)
    obstacles_missing: int = 0
    obstacles_dropped_after_hold: int = 0
    obstacle_held_ticks: int = 0
    hard_row_unmet_ticks: int = 0
    hard_row_unmet: dict[str, int] = field(default_factory=dict)
    inflated: int = 0  # leader ticks that used another formation's stale ellipse, inflated
    standing: int = 0  # leader ticks that used a dead formation's standing body (leader.succession)
    listening: list[str] = field(default_factory=list)  # formations a leader heard every tick
    listen_changes: int = 0
    takeovers: int = 0
    acting_leader_ticks: int = 0
    nav: dict[str, int] = field(default_factory=dict)
    goal_refusal: str = ""  # leader: why it refused the last goal it refused ("": none)
    fault_dropped: dict[str, int] = field(default_factory=dict)
    fault_delayed: int = 0
    solves: int = 0
    tick_errors: int = 0  # ticks that raised (caught, answered with the zero command)
    escape_ticks: int = 0
    relaxed: int = 0
    fallback: int = 0
    failed: int = 0
    solve_us_median: float | None = None
    tick_us_median: float | None = None
    # the tick's parts (agent.tick_times.TICK_PARTS) -> median [us] over the ticks it ran in
    tick_parts_us_median: dict[str, float | None] = field(default_factory=dict)
    pose_age_us_median: float | None = None
    pose_in_us_median: float | None = None
    stats_window: int = 0  # the medians above are over the newest ticks
    min_h: dict[str, float | None] = field(
        default_factory=lambda: {"formation": None, "obstacle": None, "formations": None})
    dropped: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    received: dict[str, int] = field(default_factory=dict)
    subscriptions: list[str] = field(default_factory=list)
    traffic: dict[str, Any] = field(default_factory=dict)
    cpu_s: float | None = None
    wall_s: float = 0.0
    trace_columns: list[str] = field(default_factory=list)
    trace: Trace = field(default_factory=list)
    ellipse_trace: Trace = field(default_factory=list)
    # controller.localisation fused: the filter's counters and its trace (agent.odom_in)
    localisation: dict[str, Any] | None = None
    # a fleet robot's lifelong part: its errands and its order traffic (agent.lifepart)
    lifelong: dict[str, Any] | None = None
    # an agent host's agents (agent.host)
    host_agents: int | None = None
    superseded_poses: int | None = None
    # set by the launcher, never by an agent
    killed: bool = False
    counters_lost: bool = False

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON object an agent writes: every field, host-only ones only when set."""
        out = dataclasses.asdict(self)
        for name in ("host_agents", "superseded_poses", "localisation", "lifelong"):
            if out[name] is None:
                del out[name]
        for name in ("killed", "counters_lost"):
            if not out[name]:
                del out[name]
        return out

    @classmethod
    def from_json_dict(cls, data: dict[str, Any]) -> AgentStats:
        """Read back what :meth:`to_json_dict` wrote; ``ValueError`` on an unknown key or a
        missing robot or formation."""
        if not isinstance(data, dict):
            raise ValueError("agent counters: not a JSON object")
        unknown = sorted(set(data) - _FIELDS)
        if unknown:
            raise ValueError(f"agent counters: unknown keys {unknown[:5]}")
        for name in ("robot", "formation"):
            if not isinstance(data.get(name), str):
                raise ValueError(f"agent counters: {name!r} missing or not a string")
        return cls(**data)


_FIELDS = {f.name for f in dataclasses.fields(AgentStats)}
