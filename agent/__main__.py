"""``python -m agent --config ROBOT.yaml [--lockstep] [--stats PATH]``: one robot's agent.

Runs :class:`agent.node.AgentNode` until SIGINT or SIGTERM, then commands zero velocity, closes
the Zenoh session, writes its counters to ``--stats`` (JSON) and exits 0. Exit status 2 for an
invalid configuration, 1 when the session cannot be opened or the node fails.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from agent.config import load_config
from agent.node import AgentNode, NodeOptions

logger = logging.getLogger("agent")


async def serve(node: AgentNode) -> None:
    """Run ``node`` until SIGINT/SIGTERM; the handlers only set the stop event."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await node.run(stop)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)


def write_stats(node: AgentNode, path: Path) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(node.stats(), allow_nan=False), encoding="utf-8")
    tmp.replace(path)  # the launcher never reads a half-written file


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m agent", description=__doc__.split("\n")[0])
    parser.add_argument("--config", required=True, help="the robot's agent configuration (YAML)")
    parser.add_argument("--lockstep", action="store_true",
                        help="tick on pose arrival (simulated world) instead of the own clock")
    parser.add_argument("--lockstep-timeout", type=float, default=2.0, metavar="SECONDS",
                        help="longest wait for one tick's inputs in lock-step (default 2)")
    parser.add_argument("--stats", type=Path, default=None, help="write counters here (JSON) at exit")
    parser.add_argument("--no-trace", action="store_true", help="do not keep per-tick rows")
    parser.add_argument("--log-level", default="WARNING")
    ns = parser.parse_args(argv)
    logging.basicConfig(level=ns.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        cfg = load_config(ns.config)
        options = NodeOptions(lockstep=ns.lockstep, lockstep_timeout=ns.lockstep_timeout,
                              trace=not ns.no_trace)
        node = AgentNode(cfg, options)
    except ValueError as exc:
        print(f"agent: {exc}", file=sys.stderr)
        return 2
    status = 0
    try:
        asyncio.run(serve(node))
    except Exception as exc:  # noqa: BLE001 - a process front end: report and exit 1
        logger.exception("agent %s failed", cfg.robot_id)
        print(f"agent {cfg.robot_id}: {type(exc).__name__}: {exc}", file=sys.stderr)
        status = 1
    if ns.stats is not None:
        write_stats(node, ns.stats)
    return status


if __name__ == "__main__":
    sys.exit(main())
