"""The ``formation`` command: one front end, one subcommand per job (DESIGN.md, "Command line").

Exit status: 0 when the command did its work (a summary reports safety; it is not an exit code),
2 for invalid input with one line naming the culprit, 1 for anything else, with a message.
Each subcommand's work lives in its own module; this file only parses arguments and maps errors
to exit codes.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from .exits import EXIT_ERROR, EXIT_INVALID, EXIT_OK, UsageError
from .progress import Progress, print_summary

__all__ = ["EXIT_ERROR", "EXIT_INVALID", "EXIT_OK", "Progress", "UsageError", "build_parser", "main",
           "print_summary"]


def _add_sim_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--quiet", action="store_true", help="no progress display")


def _add_view_args(p: argparse.ArgumentParser, client: bool = False, serve: bool = True,
                   port: bool = True) -> None:
    from formation.commands.view import add_client_args, add_serve_args

    if client:
        add_client_args(p)
    if serve:
        add_serve_args(p, port=port)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="formation",
        description="Distributed CBF formation control for warehouse robots over Zenoh.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("check", help="validate a scenario file, nothing else")
    p.add_argument("scenario")

    p = sub.add_parser("sim", help="in-process simulation of a scenario")
    _add_sim_args(p)
    p.add_argument("--no-safety", action="store_true", help="barriers off (nominal control only)")
    p.add_argument("--solver", default="exact",
                   help="QP solver: exact (default) or a qpsolvers backend (osqp, daqp, ...)")
    p.add_argument("--topology", default="reduced", choices=["reduced", "all-to-all"])

    p = sub.add_parser("run", help="multi-process simulation over Zenoh")
    _add_sim_args(p)
    p.add_argument("--realtime", action="store_true", help="wall-clock pacing instead of lock-step")
    p.add_argument("--pose-slots", type=int, default=1, metavar="S",
                   help="real time, --camera truth: publish the poses in S slots spread over each "
                        "period instead of all at once (default 1)")
    p.add_argument("--camera", default="truth", choices=["truth", "synthetic", "process"],
                   help="poses from the truth, from frames detected in the world (synthetic), or "
                        "from the real camera process on rendered frames (process)")
    p.add_argument("--topology", default="reduced", choices=["reduced", "all-to-all"])
    p.add_argument("--drop", type=float, default=0.0, help="message loss probability")
    p.add_argument("--delay-ms", type=float, default=0.0, help="added message delay [ms]")
    p.add_argument("--fault-seed", type=int, default=0, help="seed of the message losses")
    p.add_argument("--kill", action="append", metavar="ROBOT@T[:AFTER]",
                   help="kill ROBOT's agent at simulated time T, restart it AFTER s later")
    p.add_argument("--camera-dropout", action="append", metavar="ROBOT@T:DURATION",
                   help="the camera loses ROBOT's marker from T for DURATION s")
    p.add_argument("--secure", action="store_true",
                   help="user/password authentication and the fleet's access control list")
    p.add_argument("--no-safety", action="store_true")
    p.add_argument("--port", type=int, default=0, help="router TCP port on 127.0.0.1 (0: free)")
    p.add_argument("--hold", action="store_true",
                   help="keep the fleet up after every goal (until --duration or Ctrl-C); send goals "
                        "with 'formation goal'")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="simulated seconds to run (default: the scenario's duration)")
    p.add_argument("--live", type=int, default=None, metavar="PORT",
                   help="serve the live page on http://127.0.0.1:PORT/ (and Foxglove on PORT+1)")
    _add_view_args(p, port=False)

    p = sub.add_parser("commcost", help="communication cost of both topologies")
    p.add_argument("--formations", default="2,4,8")
    p.add_argument("--out", required=True)

    p = sub.add_parser("montecarlo", help="random warehouse scenarios, in-process")
    p.add_argument("--n", type=int, default=40)
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--out", required=True)

    p = sub.add_parser("bench", help="benchmarks")
    p.add_argument("--out", required=True)
    p.add_argument("--quick", action="store_true", help="smoke mode (CI)")

    p = sub.add_parser("view", help="the live page of a running fleet (read-only)")
    _add_view_args(p, client=True)
    p = sub.add_parser("record", help="record a running fleet into DIR/run.mcap")
    _add_view_args(p, client=True, serve=False)
    p.add_argument("--out", required=True)
    p = sub.add_parser("replay", help="serve a recording (run.mcap) to the page")
    p.add_argument("recording", help="a run.mcap")
    _add_view_args(p)
    p.add_argument("--speed", type=float, default=None, help="start at this speed (default 1)")
    p.add_argument("--loop", action="store_true", help="start again at the end")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C)")

    p = sub.add_parser("deploy", help="put agents on robots over SSH")
    p.add_argument("inventory")
    p.add_argument("scenario")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--dry-run", action="store_true")
    g.add_argument("--start", action="store_true")
    g.add_argument("--stop", action="store_true")
    g.add_argument("--status", action="store_true")

    from camera_service.cli import add_parsers as add_camera_parsers  # camera, calibrate
    COMMANDS.update(add_camera_parsers(sub))

    from formation.commands.goal import add_parsers as add_goal_parsers

    add_goal_parsers(sub)
    return parser


def _lazy(module: str, func: str):
    def run(ns: argparse.Namespace) -> int:
        import importlib

        return importlib.import_module(module).__getattribute__(func)(ns)

    return run


COMMANDS = {
    "check": _lazy("formation.commands.check", "cmd_check"),
    "sim": _lazy("formation.commands.sim", "cmd_sim"),
    "run": _lazy("formation.commands.run", "run_command"),
    "commcost": _lazy("formation.commands.commcost", "commcost_command"),
    "montecarlo": _lazy("formation.commands.montecarlo", "montecarlo_command"),
    "bench": _lazy("formation.commands.bench", "bench_command"),
    "deploy": _lazy("formation.commands.deploy", "deploy_command"),
    "view": _lazy("formation.commands.view", "view_command"),
    "record": _lazy("formation.commands.view", "record_command"),
    "replay": _lazy("formation.commands.view", "replay_command"),
    "goal": _lazy("formation.commands.goal", "goal_command"),
    "status": _lazy("formation.commands.goal", "status_command"),
}


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    ns = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if ns.verbose else logging.WARNING,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    from formation.outdir import check_out
    from scenario import ScenarioError
    from wire.zconf import use_zenoh_threads

    use_zenoh_threads("relay")  # this process (world, bench); agents and routers set their own
    try:
        check_out(ns.command, getattr(ns, "out", None))  # a bad --out: exit 2 before any work
        return COMMANDS[ns.command](ns)
    except (ScenarioError, UsageError) as exc:
        print(f"formation {ns.command}: error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    except KeyboardInterrupt:
        print(f"formation {ns.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the front end turns any failure into a message
        if ns.verbose:
            raise
        print(f"formation {ns.command}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":
    sys.exit(main())
