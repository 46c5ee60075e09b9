"""The agents' counters of a multi-process run, read back as :class:`agent.stats.AgentStats`.

Every agent writes ``DIR/agents/ROBOT.json`` when it stops; a killed agent that was not
restarted wrote none, nor did one that died with an aborted run: they get empty counters marked
``killed`` or ``counters_lost``. A module of its own, not in :mod:`simulator.summary`: reading
can fail as :class:`simulator.output.OutputError` (a full disk), and :mod:`simulator.output`
imports the in-process simulator, which imports the summary.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from agent.config import AgentConfig
from agent.stats import AgentStats
from wire import traffic

from .fleet import ChildFailed
from .output import OutputError


def read_agent_stats(path: Path) -> AgentStats:
    """The counters an agent wrote when it stopped (``DIR/agents/ROBOT.json``); a missing or
    unreadable file fails the run (:class:`ChildFailed`), or says the disk is full."""
    try:
        return AgentStats.from_json_dict(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError, TypeError) as exc:
        if _disk_full(path.parent):
            raise OutputError(f"disk full: {path.parent} has no room for the agents' counters "
                              f"({path.name} missing; run output not saved)") from None
        raise ChildFailed(f"agent counters {path} missing or unreadable: {exc}") from None


def _disk_full(folder: Path, room: int = 256 * 1024) -> bool:
    """Whether the file system of ``folder`` has less than ``room`` bytes free."""
    try:
        return shutil.disk_usage(folder).free < room
    except OSError:
        return False


def dead_stats(cfg: AgentConfig, *, killed: bool = True) -> AgentStats:
    """Counters of a robot whose agent wrote none: killed and not restarted (``killed``), or
    lost with an aborted run (``counters_lost``)."""
    return AgentStats(robot=cfg.robot_id, formation=cfg.formation, leader=cfg.leader is not None,
                      killed=killed, counters_lost=not killed, traffic=traffic.empty_snapshot(),
                      cpu_s=None, wall_s=0.0)


def agent_stats(path: Path, cfg: AgentConfig, *, running: bool, lost_ok: bool,
                lost: list[dict[str, str]] | None = None) -> AgentStats:
    """An agent's counters: none for an agent no longer ``running`` (killed); in an aborted run
    (``lost_ok``) an agent that wrote none (it died with the run) counts as lost instead of
    failing the summary. With ``lost``, counters a full disk kept the agent from writing count
    as lost too and are added to it (``{file, error}``, for ``summary.json``'s ``lost_files``):
    the run's summary is still written."""
    if not running:
        return dead_stats(cfg)
    if lost_ok and not path.is_file():
        return dead_stats(cfg, killed=False)
    try:
        return read_agent_stats(path)
    except OutputError:
        if lost is None:
            raise
        lost.append({"file": f"{path.parent.name}/{path.name}", "error": "disk full"})
        return dead_stats(cfg, killed=False)
