"""What the leader role is configured with (built by :func:`agent.config.build_agent_configs`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LeaderSettings:
    """What the leader role needs to estimate and exchange its formation's ellipse."""

    members: tuple[str, ...]  # every member, leader included, in reference order
    offsets: tuple[tuple[float, float], ...]  # reference offsets of the members' control points
    alpha0: float  # [rad] principal-axis angle of the reference shape
    axes: tuple[float, float]  # semi-axes (a, b) [m]
    other_formations: tuple[str, ...]  # formations whose ellipses this leader subscribes to
