"""``formation goal`` and ``formation status``: the fleet manager's side of the goal interface.

``formation goal FID X Y [--heading RAD] [--via X,Y[,H] ...]`` puts a :class:`wire.navigation.GoalMsg`
on ``{prefix}/formation/FID/goal`` (stamped with this machine's clock; first it waits for the
leader's status, to count its refusals before) and waits until the
formation's leader reports that goal in its ``status`` (published about once a second, and
answered as a queryable): exit 0 and one status line. The goal is put again every
:data:`RESEND_S` until then (a leader ignores a goal equal to the one it follows), so it reaches
a leader whose subscription was not matched yet. No such status within ``--timeout``: exit 1,
saying what the leader reports instead. A goal the leader refuses (inside an obstacle, outside
its world) or one it takes but finds no route to (state ``unreachable``) exits 1 as soon as the
leader's status says so (``status`` version 2 carries the refusals and the reason).

``formation status`` asks every leader for its status and prints one line per formation.

Both connect as Zenoh clients to ``--connect`` (the endpoint ``formation run`` prints and writes
to ``DIR/endpoint``) with multicast scouting off; ``--auth FILE`` names the fleet manager's
credentials (``DIR/secure/manager.json5``). ``--run DIR`` finds both in a run's folder. A router
that wants credentials, or refuses them, is said so in one line (:func:`wire.zconf.open_session`).

``goal`` refuses at once (exit 2, one line) a goal that is not finite, lies outside the
coordinate range of every scenario (:data:`scenario.limits.COORDINATE`), or a route longer than a
plan holds (:func:`scenario.extent.goal_problem`; the leader checks the goal against its own
scenario's extent again), and a formation that no answering leader's status names (each names
every formation of its scenario: a formation whose own leader has not answered yet is known).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import queue
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import zenoh

from scenario.extent import Extent, goal_problem
from scenario.limits import COORDINATE
from wire import keys
from wire.navigation import GoalMsg, StatusMsg, decode_status, encode_nav
from wire.payloads import DecodeError
from wire.reader import decoded_replies
from wire.zconf import ZenohSettings, read_auth_file
from wire.zconf import open_session as open_zenoh

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2
RESEND_S = 1.0  # [s] the goal is put again this often until the status shows it
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
MANAGER_AUTH = Path("secure") / "manager.json5"  # in a run's folder: the fleet manager's credentials
# every scenario's coordinates lie in this square (scenario.limits); a leader narrows it to its own
ANY_WORLD = Extent(COORDINATE.lo, COORDINATE.lo, COORDINATE.hi, COORDINATE.hi)


def add_parsers(sub) -> None:
    """The ``goal`` and ``status`` subcommands, on the ``formation`` command's subparsers."""
    p = sub.add_parser("goal", help="send a formation a new goal; exit 0 once its leader shows it")
    p.add_argument("fid", help="formation id")
    p.add_argument("x", type=float, help="goal centroid x [m]")
    p.add_argument("y", type=float, help="goal centroid y [m]")
    p.add_argument("--heading", type=float, default=None, metavar="RAD",
                   help="turn the formation's goal shape to this heading [rad]")
    p.add_argument("--via", nargs="+", default=[], metavar="X,Y[,H]",
                   help="waypoints the centroid passes first, in order, each with the heading "
                        "[rad] the formation turns to there if H is given (default: none; the "
                        "leader plans its own route)")
    p.add_argument("--timeout", type=float, default=30.0, metavar="S",
                   help="give up after this many seconds without the leader's status (default 30)")
    client_args(p)
    p = sub.add_parser("status", help="one line per formation from the leaders' status")
    p.add_argument("--timeout", type=float, default=3.0, metavar="S",
                   help="wait this long for the leaders' answers (default 3)")
    client_args(p)


def client_args(p: argparse.ArgumentParser) -> None:
    """The options of a client of a running fleet (``goal``, ``status``, ``order``, ``orders``):
    where its router is and the fleet manager's credentials."""
    p.add_argument("--connect", action="append", default=[], metavar="EP",
                   help=f"Zenoh endpoint of the fleet's router (default: the --run folder's, "
                        f"else {DEFAULT_CONNECT})")
    p.add_argument("--run", default=None, metavar="DIR",
                   help="the folder of a running `formation run --hold`: its endpoint "
                        "(DIR/endpoint) and credentials (DIR/secure/manager.json5)")
    p.add_argument("--prefix", default=keys.DEFAULT_PREFIX,
                   help=f"key-space prefix (default {keys.DEFAULT_PREFIX})")
    p.add_argument("--auth", default=None, metavar="FILE",
                   help="the fleet manager's credentials: DIR/secure/manager.json5 of formation run "
                        "(default: the --run folder's)")


def parse_point(text: str) -> tuple[float, float]:
    """``X,Y`` or ``X,Y,H`` -> (x, y) (:func:`parse_via` keeps the heading); ValueError naming
    the text."""
    return parse_via(text)[0]


def parse_via(text: str) -> tuple[tuple[float, float], float | None]:
    """``X,Y`` or ``X,Y,H`` -> ((x, y), heading or None); ValueError naming the text."""
    parts = text.split(",")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"--via {text!r}: expected X,Y or X,Y,HEADING (numbers)") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"--via {text!r}: not finite")
    return (values[0], values[1]), (values[2] if len(values) == 3 else None)


def run_endpoint(ns: argparse.Namespace) -> tuple[tuple[str, ...], str | None]:
    """The endpoints and credentials file to use: ``--connect``/``--auth`` when given, else those
    of the ``--run`` folder, else :data:`DEFAULT_CONNECT` and none; ValueError naming the folder."""
    connect, auth = tuple(ns.connect), ns.auth
    run = getattr(ns, "run", None)
    if run is not None:
        folder = Path(run)
        try:
            found = (folder / "endpoint").read_text(encoding="utf-8").split()
        except OSError:
            raise ValueError(f"--run {run}: no endpoint file in it (is it a `formation run "
                             f"--hold` folder, and is the fleet up?)") from None
        connect = connect or tuple(found)
        if auth is None and (folder / MANAGER_AUTH).is_file():
            auth = str(folder / MANAGER_AUTH)
    return connect or (DEFAULT_CONNECT,), auth


def open_session(ns: argparse.Namespace) -> zenoh.Session:
    """A client session to the fleet's router; ValueError for bad arguments, ConnectionError
    saying why none opened (no router there, credentials wanted or refused)."""
    connect, auth_file = run_endpoint(ns)
    auth = read_auth_file(auth_file).auth if auth_file else None
    settings = ZenohSettings(mode="client", connect=connect, multicast_scouting=False, auth=auth)
    return open_zenoh(settings, "")


def session_for(ns: argparse.Namespace, command: str) -> zenoh.Session | int:
    """:func:`open_session`, or the exit code after one line saying why none opened (bad
    arguments: usage; no router or credentials refused: failure)."""
    try:
        return open_session(ns)
    except ValueError as exc:
        print(f"formation {command}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except ConnectionError as exc:
        print(f"formation {command}: cannot open a Zenoh session: {exc}", file=sys.stderr)
        return EXIT_FAIL


def check_goal(goal: GoalMsg) -> None:
    """ValueError (one line) for a goal no scenario could hold (:func:`scenario.extent.goal_problem`)."""
    problem = goal_problem(goal.x, goal.y, goal.heading, goal.waypoints, ANY_WORLD)
    if problem is not None:
        raise ValueError(problem)


def unknown_formation(session: zenoh.Session, prefix: str, fid: str, timeout: float) -> str | None:
    """Why ``fid`` is not a formation of the fleet, or None. A leader's status names every
    formation of its scenario (``fleet``, status version 2), so one answer is enough: a formation
    whose own leader has not answered yet (a fleet starting, a busy leader) is still known. Only
    where no answer says so (older leaders) do the formations that answered stand for the fleet."""
    found = query_status(session, prefix, timeout=timeout)
    if not found:
        return None  # none answered yet (a fleet starting): wait for it as before
    said = [s.fleet for s in found if s.fleet]
    known = sorted(set().union(*said)) if said else [s.formation for s in found]
    if fid in known:
        return None
    return f"no formation {fid!r} in the fleet (known: {', '.join(known)})"


def shows(status: StatusMsg, goal: GoalMsg) -> bool:
    """Whether the leader's status follows ``goal`` (its centroid, and heading if one was set)."""
    if abs(status.gx - goal.x) > 1e-9 or abs(status.gy - goal.y) > 1e-9:
        return False
    return goal.heading is None or (
        status.heading is not None and abs(status.heading - goal.heading) <= 1e-9)


def status_line(s: StatusMsg) -> str:
    heading = "" if s.heading is None else f" heading {s.heading:.3f}"
    why = f" ({s.reason})" if s.reason else ""
    refused = f", {s.refused} goal(s) refused, the last: {s.refusal}" if s.refused else ""
    return (f"{s.formation}: {s.state}{why} goal ({s.gx:.3f}, {s.gy:.3f}){heading} "
            f"to go {s.distance:.2f} m, waypoint {s.waypoint + 1}/{s.waypoints} "
            f"({s.wx:.2f}, {s.wy:.2f}), leader {s.leader}, stamp {s.stamp:.2f}{refused}")


def verdict(s: StatusMsg, goal: GoalMsg, refused_before: int | None) -> int | None:
    """What a status says about ``goal``: EXIT_OK once the leader follows it, EXIT_FAIL when
    it follows it but no route reaches it (``unreachable``) or when the leader counts a refusal
    more than before the goal was sent; None while neither."""
    if shows(s, goal):
        return EXIT_FAIL if s.state == "unreachable" else EXIT_OK
    if refused_before is not None and s.refused > refused_before:
        return EXIT_FAIL
    return None


def query_status(session: zenoh.Session, prefix: str, fid: str = "*",
                 timeout: float = 3.0) -> list[StatusMsg]:
    """Every status the leaders answer for ``{prefix}/formation/{fid}/status``."""
    out: dict[str, StatusMsg] = {}
    selector = f"{keys.validate_prefix(prefix)}/formation/{fid}/status"
    for s in decoded_replies(session, selector, decode_status, timeout):  # every leader's
        if s.formation not in out or s.stamp > out[s.formation].stamp:
            out[s.formation] = s
    return [out[k] for k in sorted(out)]


def goal_command(ns: argparse.Namespace) -> int:
    try:
        via = [parse_via(v) for v in ns.via]
        goal = GoalMsg(keys.validate_id(ns.fid, "formation"), ns.x, ns.y, ns.heading,
                       tuple(p for p, _h in via), time.time(), tuple(h for _p, h in via))
        check_goal(goal)
        if not (math.isfinite(ns.timeout) and ns.timeout > 0):
            raise ValueError("--timeout must be a positive number")
    except ValueError as exc:
        print(f"formation goal: {exc}", file=sys.stderr)
        return EXIT_USAGE
    session = session_for(ns, "goal")
    if isinstance(session, int):
        return session
    try:
        unknown = unknown_formation(session, ns.prefix, goal.formation, min(ns.timeout, 2.0))
        if unknown is not None:
            print(f"formation goal: {unknown}", file=sys.stderr)
            return EXIT_USAGE
        return _send_and_wait(session, ns, goal)
    finally:
        session.close()


def _first_status(session: zenoh.Session, prefix: str, fid: str,
                  seen: queue.SimpleQueue[StatusMsg], deadline: float) -> StatusMsg | None:
    """The leader's first status (asked for, or published meanwhile), or None by ``deadline``."""
    while time.monotonic() < deadline:
        found = query_status(session, prefix, fid,
                             timeout=max(0.05, min(deadline - time.monotonic(), 1.0)))
        with contextlib.suppress(queue.Empty):
            found.append(seen.get_nowait())
        if found:
            return found[0]
    return None


def _send_and_wait(session: zenoh.Session, ns: argparse.Namespace, goal: GoalMsg) -> int:
    status_key = keys.status_key(ns.prefix, goal.formation)
    seen: queue.SimpleQueue[StatusMsg] = queue.SimpleQueue()

    def on_status(sample: zenoh.Sample) -> None:
        try:
            seen.put(decode_status(sample.payload.to_bytes()))
        except DecodeError:
            pass

    sub = session.declare_subscriber(status_key, on_status)
    pub = session.declare_publisher(keys.goal_key(ns.prefix, goal.formation))
    payload = encode_nav(goal)
    deadline = time.monotonic() + ns.timeout
    # the leader's refusals before this goal went out: one more afterwards is this goal's. The
    # goal goes out only once the leader has answered: sent before, a busy leader's first
    # answer could count its refusal already, and the goal went again (two refused)
    last = _first_status(session, ns.prefix, goal.formation, seen, deadline)
    refused_before = last.refused if last is not None else None
    try:
        while time.monotonic() < deadline:
            pub.put(payload)
            for s in query_status(session, ns.prefix, goal.formation, timeout=0.5):
                seen.put(s)
            until = time.monotonic() + RESEND_S
            while time.monotonic() < min(until, deadline):
                try:
                    s = seen.get(timeout=0.05)
                except queue.Empty:
                    continue
                last = s
                if refused_before is None:
                    refused_before = s.refused
                code = verdict(s, goal, refused_before)
                if code == EXIT_OK:
                    print(status_line(s))
                    return EXIT_OK
                if code == EXIT_FAIL:
                    said = ("no route reaches it" if shows(s, goal)
                            else f"its leader refused it: {s.refusal}")
                    print(f"formation goal: formation {goal.formation!r}: {said} "
                          f"({status_line(s)})", file=sys.stderr)
                    return EXIT_FAIL
    finally:
        sub.undeclare()
        pub.undeclare()
    what = status_line(last) if last is not None else "no status from its leader"
    print(f"formation goal: formation {goal.formation!r} did not take the goal within "
          f"{ns.timeout:g} s ({what})", file=sys.stderr)
    return EXIT_FAIL


def status_command(ns: argparse.Namespace) -> int:
    session = session_for(ns, "status")
    if isinstance(session, int):
        return session
    try:
        found = query_status(session, ns.prefix, timeout=ns.timeout)
    finally:
        session.close()
    if not found:
        print("formation status: no leader answered", file=sys.stderr)
        return EXIT_FAIL
    for s in found:
        print(status_line(s))
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="formation")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parsers(sub)
    ns = parser.parse_args(argv)
    return goal_command(ns) if ns.command == "goal" else status_command(ns)
