"""The ``formation`` command: one front end, one subcommand per job (docs/cli.md).

Exit status: 0 when the command did its work (a summary reports safety; it is not an exit code),
2 for invalid input with one line naming the culprit, 1 for anything else, with a message.
Each subcommand's work lives in its own module; this file only parses arguments and maps errors
to exit codes.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

from camera_service.cli import add_parsers as add_camera_parsers  # camera, calibrate
from formation.commands.goal import add_parsers as add_goal_parsers
from formation.commands.order import add_parsers as add_order_parsers
from formation.commands.view import add_client_args, add_serve_args
from formation.outdir import FOLDER_COMMANDS, OutputFolder, check_out
from scenario import ScenarioError
from wire.zconf import use_zenoh_threads

from .argspec import Parser
from .exits import EXIT_ERROR, EXIT_INVALID, EXIT_OK, UsageError
from .progress import Progress, print_summary

__all__ = ["EXIT_ERROR", "EXIT_INVALID", "EXIT_OK", "Progress", "UsageError", "build_parser", "main",
           "print_summary"]


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default, unless the text names it already or there is
    none to name (a flag, an option without a default)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if ("default" in text.lower() or any(action.default is v for v in (None, False, argparse.SUPPRESS))
                or action.required or not action.option_strings):
            return text
        return text + " (default: %(default)s)"


def _version() -> str:
    try:
        return version("formation-cbf")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def _add_out(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder, created if missing; a re-run replaces the previous run's "
                        "output in it")
    p.add_argument("--force", action="store_true",
                   help="write into an --out folder that holds other files (they are left as "
                        "they are)")


def _add_sim_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario YAML file, or a shipped scenario by name (formation scenarios)")
    _add_out(p)
    p.add_argument("--no-plots", action="store_true", help="skip the figures")
    p.add_argument("--quiet", action="store_true", help="no progress display")


def _add_solver(p: argparse.ArgumentParser) -> None:
    p.add_argument("--solver", default="exact", metavar="NAME",
                   help="QP solver: exact, or a qpsolvers backend (osqp, daqp, ...)")


def _add_topology(p: argparse.ArgumentParser) -> None:
    p.add_argument("--topology", default="reduced", choices=["reduced", "all-to-all"],
                   help="who hears whom: neighbours and leaders only, or every robot")


def _add_world(p: argparse.ArgumentParser) -> None:
    from scenario.world import PROFILES

    p.add_argument("--world", default=None, choices=list(PROFILES), metavar="PROFILE",
                   help=f"the simulated robots and camera: {' or '.join(PROFILES)} (default: the "
                        "scenario's world:, else ideal; docs/scenarios.md)")


def _add_engine(p: argparse.ArgumentParser) -> None:
    p.add_argument("--engine", default="kinematic", choices=["kinematic", "mujoco"],
                   help="what moves the robots: their exact kinematics, or MuJoCo's physics "
                        "(the extra formation-cbf[physics])")


def _add_bounds(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bounds", default=None, metavar="SPEC",
                   help="the controller's declared sensing and motor bounds, in place of the "
                        "scenario's controller.bounds: a world profile's name (the bounds that "
                        "match it) or NAME=VALUE,... of pose_noise, heading_noise, latency, "
                        "motor_lag (docs/scenarios.md)")


def _add_view_args(p: argparse.ArgumentParser, client: bool = False, serve: bool = True,
                   port: bool = True) -> None:
    if client:
        add_client_args(p)
    if serve:
        add_serve_args(p, port=port)


def build_parser() -> Parser:
    parser = Parser(
        prog="formation", formatter_class=_HelpFormatter,
        description="Distributed CBF formation control for warehouse robots over Zenoh.",
        epilog="Exit status: 0 the command did its work, 2 invalid input (one line naming it), "
               "1 anything else. 'formation COMMAND --help' for a command's options.",
    )
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log debug messages, and show a traceback on an unexpected error")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}",
                        help="print the installed version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                help="what to do (one of the commands below)")

    def add(name: str, text: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=text, description=text[:1].upper() + text[1:] + ".",
                              formatter_class=_HelpFormatter)

    p = add("check", "validate a scenario file, nothing else")
    p.add_argument("scenario", help="scenario YAML file, or a shipped scenario by name (formation scenarios)")

    add("scenarios", "list the shipped scenarios: a command takes one by name "
        "(formation sim thesis-5.2.2), from a checkout or a pip install")

    p = add("sim", "in-process simulation of a scenario")
    _add_sim_args(p)
    p.add_argument("--no-safety", action="store_true", help="barriers off (nominal control only)")
    _add_solver(p)
    _add_topology(p)
    _add_world(p)
    _add_bounds(p)
    _add_engine(p)

    p = add("run", "multi-process simulation over Zenoh (router, one agent per robot, world)")
    _add_sim_args(p)
    p.add_argument("--realtime", action="store_true", help="wall-clock pacing instead of lock-step")
    p.add_argument("--clock-offset-ms", type=float, default=0.0, metavar="MS",
                   help="real time: stamp poses on a camera clock this far ahead of the agents' "
                        "(negative: behind), to see what clock offset the fleet tolerates")
    p.add_argument("--pose-slots", type=int, default=1, metavar="S",
                   help="real time, --camera truth: publish the poses in S slots spread over each "
                        "period instead of all at once (default 1)")
    p.add_argument("--camera", default="truth", choices=["truth", "synthetic", "process"],
                   help="poses from the truth, from frames detected in the world (synthetic), or "
                        "from the real camera process on rendered frames (process)")
    _add_world(p)
    _add_bounds(p)
    _add_engine(p)
    _add_topology(p)
    _add_solver(p)
    p.add_argument("--drop", type=float, default=0.0, help="message loss probability")
    p.add_argument("--delay-ms", type=float, default=0.0, help="added message delay [ms]")
    p.add_argument("--fault-seed", type=int, default=0, help="seed of the message losses")
    p.add_argument("--kill", action="append", metavar="ROBOT@T[:AFTER]",
                   help="kill ROBOT's agent at simulated time T, restart it AFTER s later")
    p.add_argument("--camera-dropout", action="append", metavar="ROBOT@T:DURATION",
                   help="the camera loses ROBOT's marker from T for DURATION s")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--secure", action="store_true",
                   help="user/password authentication and the fleet's access control list "
                        "(the default; kept for old scripts)")
    g.add_argument("--insecure", action="store_true",
                   help="no authentication, no access control (anyone on the port can command)")
    p.add_argument("--agents-per-process", type=int, default=1, metavar="K",
                   help="run the agents K to a process (an agent host; default 1: one per robot)")
    p.add_argument("--session-per-agent", action="store_true",
                   help="with --agents-per-process K > 1: each agent opens its own Zenoh session "
                        "(default: one per host, with --insecure; each robot logs in as itself otherwise)")
    p.add_argument("--pose-zones", type=int, default=0, metavar="Z",
                   help="carry the poses and commands through Z zone routers of the world's "
                        "process, each agent connected to its zone's (default 0: everything "
                        "through the run's router)")
    p.add_argument("--base", default="world", choices=["world", "rmw_zenoh"],
                   help="rmw_zenoh: each agent drives its base as a ROS 2 robot on rmw_zenoh "
                        "(namespace = robot id, topic cmd_vel) and the world plays the bases")
    p.add_argument("--cmd-type", default="TwistStamped", choices=["Twist", "TwistStamped"],
                   help="--base rmw_zenoh: the command message (Twist needs --realtime)")
    p.add_argument("--ros-domain", type=int, default=0, metavar="N",
                   help="--base rmw_zenoh: the ROS domain id (default 0)")
    p.add_argument("--rmw-zenoh-release", default="jazzy",
                   choices=["humble", "humble-0.1.1", "jazzy", "jazzy-0.2.3", "kilted"],
                   help="--base rmw_zenoh: the rmw_zenoh release whose wire format to speak")
    p.add_argument("--restart", choices=("on-failure", "no"), default="on-failure",
                   help="restart an agent here that exits on its own, as systemd does on a robot "
                        "(default on-failure; an agent stopped by --kill ROBOT@T stays dead)")
    p.add_argument("--restart-limit", type=int, default=3, metavar="N",
                   help="with --restart on-failure: restarts per robot before the run aborts "
                        "(default 3)")
    p.add_argument("--no-capacity-check", action="store_true",
                   help="start the run even where the fleet's estimated memory, processes or file "
                        "descriptors exceed what this machine grants (default: refuse, exit 2)")
    p.add_argument("--no-safety", action="store_true", help="barriers off (nominal control only)")
    p.add_argument("--port", type=int, default=0, help="router TCP port on 127.0.0.1 (0: free)")
    p.add_argument("--hosts", default=None, metavar="INVENTORY",
                   help="run the agents of the robots this deploy inventory names on its hosts "
                        "(over SSH, where formation deploy installed them; the others here); the "
                        "router listens on its zenoh.router (default: every agent here)")
    p.add_argument("--dry-run", action="store_true",
                   help="check the scenario and the --hosts inventory, print where each agent "
                        "would run and the SSH commands; start, write and reach nothing")
    p.add_argument("--hold", action="store_true",
                   help="keep the fleet up after every goal (until --duration or Ctrl-C); send goals "
                        "with 'formation goal'")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="simulated seconds to run (default: the scenario's duration)")
    p.add_argument("--live", type=int, default=None, metavar="PORT",
                   help="serve the live page on http://127.0.0.1:PORT/ (and Foxglove on PORT+1)")
    _add_view_args(p, port=False)

    p = add("commcost", "communication cost of both topologies (multi-process runs)")
    p.add_argument("--formations", default="2,4,8", metavar="N,N,...",
                   help="numbers of formations to run, each with both topologies")
    _add_out(p)

    p = add("montecarlo", "random warehouse scenarios, in-process")
    p.add_argument("--n", type=int, default=40, help="number of random scenarios")
    p.add_argument("--seed", type=int, default=11, help="seed of the first scenario's layout")
    p.add_argument("--jobs", type=int, default=2, metavar="J",
                   help="runs at a time, each in its own process (results do not depend on it)")
    p.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="run on the Dask distributed cluster whose scheduler is at ADDR (e.g. "
                        "tcp://host:8786; workers started with `dask worker ADDR` from this "
                        "project's environment) instead of --jobs local processes; same results")
    p.add_argument("--draw", default="circles", choices=["circles", "warehouse", "lifelong"],
                   metavar="DRAW",
                   help="the layouts: round shelves along two aisles (circles), halls of shelf "
                        "rows, walls, pillars and forklifts with formations of 2-6 robots carrying "
                        "loads under the rigid method (warehouse), or halls with docks, racks, a "
                        "fleet and a seeded stream of orders (lifelong)")
    p.add_argument("--model", default=None,
                   choices=["single_integrator", "unicycle", "double_integrator"], metavar="MODEL",
                   help="every drawn formation's robot model: single_integrator, unicycle or "
                        "double_integrator (max_accel 0.5 m/s^2) (default: the draw's own mix)")
    p.add_argument("--localisation", default="camera", choices=["camera", "fused"],
                   metavar="MODE", help="every run's controller.localisation: camera (default) "
                   "or fused (each agent's filter over odometry and camera poses)")
    p.add_argument("--blind", type=int, default=0, metavar="N",
                   help="N blind patches of floor (3.5 x 2 m) across formations' ways per run")
    _add_world(p)
    _add_bounds(p)
    _add_out(p)

    p = add("bench", "benchmarks: solver, control step, fleet CPU")
    _add_out(p)
    p.add_argument("--quick", action="store_true", help="smoke mode (CI): small and short")
    p.add_argument("--method", default=None, metavar="M,...",
                   help="only the per-member control step on the warehouse under these "
                        "controller methods, side by side (e.g. rigid,thesis)")
    p.add_argument("--fleets", default=None, metavar="N@HZ,...",
                   help="only these agent fleets, e.g. 32@50,256@20 (real time)")
    p.add_argument("--inprocess", default=None, metavar="N,...",
                   help="only formation sim's speed on bench warehouses of these many robots, "
                        "e.g. 4,8,16,32,50,100,200 (robot-ticks per CPU second, x real time)")
    p.add_argument("--localisation", action="store_true",
                   help="only the agent's own filter (controller.localisation fused): its CPU "
                        "per tick with a late camera pose and blind")
    p.add_argument("--agents-per-process", type=int, default=1, metavar="K",
                   help="with --fleets: K agents to an agent host (default 1)")
    p.add_argument("--session-per-agent", action="store_true",
                   help="with --fleets and K > 1: each agent opens its own Zenoh session "
                        "(default: one per host)")
    p.add_argument("--repeat", type=int, default=1, metavar="R", help="with --fleets: run each R times")
    p.add_argument("--pose-slots", type=int, default=1, metavar="S",
                   help="with --fleets: the world spreads each period's poses over S slots "
                        "(at most one per formation; default 1: one camera frame)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="with --fleets: seconds of real time per run (default 15)")
    p.add_argument("--pose-zones", default="0", metavar="Z,...",
                   help="with --fleets: pose paths to run side by side in every round: 0 = every "
                        "pose and command through the one router, Z = through Z zone routers "
                        "(default 0)")
    p.add_argument("--stalls", action="store_true",
                   help="with --fleets and --agents-per-process K > 1: each agent host records "
                        "what holds its ticks back (garbage collections, heap, tick CPU, the "
                        "longest ticks' parts, the plan worker's CPU)")

    p = add("view", "the live page of a running fleet (read-only)")
    _add_view_args(p, client=True)

    p = add("record", "record a running fleet into DIR/run.mcap")
    _add_view_args(p, client=True, serve=False)
    _add_out(p)

    p = add("replay", "serve a recording (run.mcap) to the page")
    p.add_argument("recording", help="a run.mcap")
    _add_view_args(p)
    p.add_argument("--speed", type=float, default=None, help="start at this speed (default 1)")
    p.add_argument("--loop", action="store_true", help="start again at the end")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C)")

    p = add("deploy", "put agents on robots over SSH (without an option: install or update)")
    p.add_argument("inventory", help="inventory YAML file: the robots, their hosts and SSH keys")
    p.add_argument("scenario", help="scenario YAML file naming the same robots")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--dry-run", action="store_true",
                   help="check the inventory (SSH keys included) and print the plan; touch nothing")
    g.add_argument("--start", action="store_true", help="start each robot's agent")
    g.add_argument("--stop", action="store_true", help="stop each robot's agent")
    g.add_argument("--status", action="store_true", help="report each robot's agent")

    COMMANDS.update(add_camera_parsers(sub))

    add_goal_parsers(sub)
    add_order_parsers(sub)
    return parser


def _lazy(module: str, func: str):
    """A command loaded by name when it runs: one command's dependencies (matplotlib, the
    simulator, deploy's SSH) stay off the others and off ``--help``."""

    def run(ns: argparse.Namespace) -> int:
        return importlib.import_module(module).__getattribute__(func)(ns)

    return run


COMMANDS = {
    "check": _lazy("formation.commands.check", "cmd_check"),
    "scenarios": _lazy("formation.commands.scenarios", "scenarios_command"),
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
    "order": _lazy("formation.commands.order", "order_command"),
    "orders": _lazy("formation.commands.order", "orders_command"),
}


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    ns = parser.parse_args(argv)
    # no argv: this call is the program (the console script, python -m formation), which ends
    # when the command does (formation.commands.run.LaterInterruptsWait)
    ns.whole_process = argv is None
    logging.basicConfig(
        level=logging.DEBUG if ns.verbose else logging.WARNING,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    use_zenoh_threads("relay")  # this process (world, bench); agents and routers set their own
    try:
        check_out(ns.command, getattr(ns, "out", None))  # a bad --out: exit 2 before any work
        if ns.command not in FOLDER_COMMANDS:
            return COMMANDS[ns.command](ns)
        # the run owns its --out: locked, the previous run's output replaced (formation.outdir)
        with OutputFolder(ns.out, force=ns.force) as folder:
            ns.out_folder = folder
            return COMMANDS[ns.command](ns)
    except (ScenarioError, UsageError) as exc:
        print(f"formation {ns.command}: error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    except KeyboardInterrupt:
        print(f"formation {ns.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # the front end turns any failure into a message
        if ns.verbose:
            raise
        print(f"formation {ns.command}: {failure_words(exc, getattr(ns, 'out', None))}",
              file=sys.stderr)
        return EXIT_ERROR


def failure_words(exc: Exception, out: str | None) -> str:
    """A failure in one line: a full disk named as such, with the file (or ``--out``) it hit
    (an OSError from deep inside says neither), anything else by its type and message."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        where = exc.filename or out
        return f"disk full: cannot write {where}" if where else "disk full"
    return f"{type(exc).__name__}: {exc}"


if __name__ == "__main__":
    sys.exit(main())
