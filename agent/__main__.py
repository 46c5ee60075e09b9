"""``python -m agent --config ROBOT.yaml [--lockstep] [--stats PATH]``: one robot's agent.

``--drop P --delay-ms D --fault-seed S`` inject link faults at the agent's subscribers (for
``formation run``; see docs/faults.md and :mod:`agent.faults`).

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
from agent.faults import LinkFaults
from agent.node import AgentNode, NodeOptions
from wire.acl import read_credentials
from wire.zconf import UsrPwdAuth, use_zenoh_threads

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


def build_parser(prog: str = "python -m agent", description: str = "") -> argparse.ArgumentParser:
    """The options of one agent (shared with the agent host, :mod:`agent.host`)."""
    parser = argparse.ArgumentParser(prog=prog, description=description or __doc__.split("\n")[0])
    parser.add_argument("--config", required=True, help="the robot's agent configuration (YAML)")
    parser.add_argument("--lockstep", action="store_true",
                        help="tick on pose arrival (simulated world) instead of the own clock")
    parser.add_argument("--lockstep-timeout", type=float, default=2.0, metavar="SECONDS",
                        help="longest wait for one tick's inputs in lock-step (default 2)")
    parser.add_argument("--drop", type=float, default=0.0, metavar="P",
                        help="lose each received state/ellipse/others message with probability P")
    parser.add_argument("--delay-ms", type=float, default=0.0, metavar="MS",
                        help="deliver received state/ellipse/others messages this much later")
    parser.add_argument("--fault-seed", type=int, default=0, help="seed of the losses")
    parser.add_argument("--ellipse-hold", type=float, default=10.0, metavar="SECONDS",
                        help="leader: longest use of another formation's stale ellipse, inflated")
    parser.add_argument("--zenoh-auth", type=Path, default=None, metavar="FILE",
                        help="log in to the router with the user:password in FILE (mode 0600)")
    parser.add_argument("--zenoh-config", type=Path, default=None, metavar="FILE",
                        help="a full Zenoh JSON5 configuration (as deploy writes it: client of the "
                             "router, user/password, TLS); replaces the one in --config")
    parser.add_argument("--stats", type=Path, default=None, help="write counters here (JSON) at exit")
    parser.add_argument("--no-trace", action="store_true", help="do not keep per-tick rows")
    parser.add_argument("--clock-ticks", action="store_true",
                        help="real time: tick on the own clock, not on pose arrival")
    parser.add_argument("--log-level", default="WARNING")
    return parser


def node_options(ns: argparse.Namespace, auth: UsrPwdAuth | None) -> NodeOptions:
    """The :class:`NodeOptions` of parsed agent options (ValueError on a bad value)."""
    faults = LinkFaults(drop=ns.drop, delay=ns.delay_ms / 1000.0, seed=ns.fault_seed)
    if ns.zenoh_config is not None and not ns.zenoh_config.is_file():
        raise ValueError(f"--zenoh-config: no such file {str(ns.zenoh_config)!r}")
    return NodeOptions(lockstep=ns.lockstep, lockstep_timeout=ns.lockstep_timeout,
                       trace=not ns.no_trace, faults=faults, ellipse_hold=ns.ellipse_hold,
                       auth=auth, tick_on_pose=not ns.clock_ticks,
                       zenoh_config_file=None if ns.zenoh_config is None else str(ns.zenoh_config))


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    ns = parser.parse_args(argv)
    logging.basicConfig(level=ns.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        cfg = load_config(ns.config)
        auth = None if ns.zenoh_auth is None else read_credentials(ns.zenoh_auth)
        options = node_options(ns, auth)
        node = AgentNode(cfg, options)
    except ValueError as exc:
        print(f"agent: {exc}", file=sys.stderr)
        return 2
    status = 0
    use_zenoh_threads("agent")
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
