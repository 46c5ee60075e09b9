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
from pathlib import Path

EXIT_OK, EXIT_ERROR, EXIT_INVALID = 0, 1, 2


class UsageError(ValueError):
    """Invalid input detected by a subcommand: exit status 2, one line."""


def _add_sim_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--quiet", action="store_true", help="no progress display")


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
    p.add_argument("--camera", default="truth", choices=["truth", "synthetic"])
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

    from . import navcmd

    navcmd.add_parsers(sub)

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

    p = sub.add_parser("deploy", help="put agents on robots over SSH")
    p.add_argument("inventory")
    p.add_argument("scenario")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--dry-run", action="store_true")
    g.add_argument("--start", action="store_true")
    g.add_argument("--stop", action="store_true")
    g.add_argument("--status", action="store_true")
    return parser


def cmd_check(ns: argparse.Namespace) -> int:
    from scenario import load_scenario

    s = load_scenario(ns.scenario)
    n = len(s.robot_ids)
    print(f"{ns.scenario}: ok ({s.name}: {len(s.formations)} formations, {n} robots, "
          f"{len(s.obstacles)} obstacles, {len(s.shapes)} walls and shelves, {s.robot.model})")
    return EXIT_OK


def cmd_sim(ns: argparse.Namespace) -> int:
    from agent.qp import make_solver
    from scenario import load_scenario
    from simulator.inprocess import SimOptions, simulate
    from simulator.output import write_run

    scenario = load_scenario(ns.scenario)
    try:
        make_solver(ns.solver)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = Path(ns.out)
    opts = SimOptions(safety=not ns.no_safety, solver=ns.solver, topology=ns.topology)
    with Progress(f"sim {scenario.name}", quiet=ns.quiet) as progress:
        result = simulate(scenario, opts, progress=progress.update)
    write_run(result.summary, result.series, scenario, out, plots=not ns.no_plots)
    print_summary(result.summary, out)
    return EXIT_OK


def _lazy(module: str, func: str):
    def run(ns: argparse.Namespace) -> int:
        import importlib

        return importlib.import_module(module).__getattribute__(func)(ns)

    return run


COMMANDS = {
    "check": cmd_check,
    "sim": cmd_sim,
    "run": _lazy("simulator.launch", "run_command"),
    "commcost": _lazy("simulator.commcost", "commcost_command"),
    "montecarlo": _lazy("simulator.montecarlo", "montecarlo_command"),
    "bench": _lazy("formation.bench", "bench_command"),
    "deploy": _lazy("deploy.cli", "deploy_command"),
    "goal": _lazy("formation.navcmd", "goal_command"),
    "status": _lazy("formation.navcmd", "status_command"),
}


class Progress:
    """A one-line progress display on stderr (redrawn in place on a terminal).

    The bar runs against the scenario's duration; a run that ends early (every goal reached)
    closes it at full with the time it ended."""

    def __init__(self, label: str, quiet: bool = False) -> None:
        self.label = label
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self._last = -1
        self._time = 0.0

    def __enter__(self) -> Progress:
        return self

    def update(self, done: int, total: int, sim_time: float) -> None:
        self._time = sim_time
        if self.quiet or total <= 0:
            return
        pct = int(100 * done / total)
        step = 1 if self.tty else 10
        if pct // step == self._last // step and done != total:
            return
        self._last = pct
        self._draw(done / total, f"{pct:3d}%  t={sim_time:7.2f} s")

    def _draw(self, fraction: float, tail: str) -> None:
        width = 30
        fill = int(width * fraction)
        line = f"{self.label} [{'#' * fill}{'.' * (width - fill)}] {tail}"
        sys.stderr.write(("\r" + line) if self.tty else (line + "\n"))
        sys.stderr.flush()

    def __exit__(self, exc_type, *exc) -> None:
        if self.quiet:
            return
        if exc_type is None and self._last >= 0 and self._last < 100:
            self._draw(1.0, f"done  t={self._time:7.2f} s")
        if self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()


def print_summary(summary: dict, out: Path) -> None:
    ok = summary["all_reached"] and summary["collisions"] == 0
    ttg = summary["time_to_goal_s"]
    print(
        f"{summary['scenario']} ({summary['mode']}): "
        f"{'all robots reached their goals' if summary['all_reached'] else 'NOT all goals reached'}"
        f"{f' at t={ttg:.2f} s' if ttg is not None else ''}; collisions {summary['collisions']}; "
        f"max formation error {summary['formation_error_max_m']:.4f} m; "
        f"QP infeasible ticks {summary['qp']['infeasible']}/{summary['qp']['solves']}"
        + ("" if ok else "  [UNSAFE OR INCOMPLETE]")
    )
    print(f"wrote {out / 'summary.json'} and figures in {out}/")


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    ns = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if ns.verbose else logging.WARNING,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    from scenario import ScenarioError
    from wire.zconf import use_zenoh_threads

    use_zenoh_threads("relay")  # this process (world, bench); agents and routers set their own
    try:
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
