"""``formation goal`` and ``formation status``: the fleet manager's side of the goal interface.

``formation goal FID X Y [--heading RAD] [--via X,Y ...]`` puts a :class:`wire.payloads.GoalMsg`
on ``{prefix}/formation/FID/goal`` (stamped with this machine's clock) and waits until the
formation's leader reports that goal in its ``status`` (published about once a second, and
answered as a queryable): exit 0 and one status line. The goal is put again every
:data:`RESEND_S` until then (a leader ignores a goal equal to the one it follows), so it reaches
a leader whose subscription was not matched yet. No such status within ``--timeout``: exit 1,
saying what the leader reports instead (a goal inside an obstacle is refused by the leader).

``formation status`` asks every leader for its status and prints one line per formation.

Both connect as Zenoh clients to ``--connect`` (the endpoint ``formation run`` prints and writes
to ``DIR/endpoint``) with multicast scouting off; ``--auth FILE`` starts from a Zenoh
configuration fragment holding the fleet manager's credentials.
"""

from __future__ import annotations

import argparse
import math
import queue
import sys
import time
from collections.abc import Sequence

import zenoh

from wire import keys
from wire.payloads import DecodeError, GoalMsg, StatusMsg, decode_status, encode_nav
from wire.zconf import ZenohSettings

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2
RESEND_S = 1.0  # [s] the goal is put again this often until the status shows it
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"


def add_parsers(sub) -> None:
    """The ``goal`` and ``status`` subcommands, on the ``formation`` command's subparsers."""
    p = sub.add_parser("goal", help="send a formation a new goal; exit 0 once its leader shows it")
    p.add_argument("fid", help="formation id")
    p.add_argument("x", type=float, help="goal centroid x [m]")
    p.add_argument("y", type=float, help="goal centroid y [m]")
    p.add_argument("--heading", type=float, default=None, metavar="RAD",
                   help="turn the formation's goal shape to this heading [rad]")
    p.add_argument("--via", nargs="+", default=[], metavar="X,Y",
                   help="waypoints the centroid passes first, in order (default: none; the "
                        "leader plans its own route)")
    p.add_argument("--timeout", type=float, default=30.0, metavar="S",
                   help="give up after this many seconds without the leader's status (default 30)")
    _common(p)
    p = sub.add_parser("status", help="one line per formation from the leaders' status")
    p.add_argument("--timeout", type=float, default=3.0, metavar="S",
                   help="wait this long for the leaders' answers (default 3)")
    _common(p)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--connect", action="append", default=[], metavar="EP",
                   help=f"Zenoh endpoint of the fleet's router (default {DEFAULT_CONNECT})")
    p.add_argument("--prefix", default=keys.DEFAULT_PREFIX,
                   help=f"key-space prefix (default {keys.DEFAULT_PREFIX})")
    p.add_argument("--auth", default=None, metavar="FILE",
                   help="Zenoh configuration fragment with the fleet manager's credentials")


def parse_point(text: str) -> tuple[float, float]:
    """``X,Y`` -> (x, y); ValueError naming the text."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        raise ValueError(f"--via {text!r}: expected X,Y (two numbers)") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"--via {text!r}: not finite")
    return (x, y)


def open_session(ns: argparse.Namespace) -> zenoh.Session:
    settings = ZenohSettings(mode="client", connect=tuple(ns.connect or [DEFAULT_CONNECT]),
                             multicast_scouting=False, config_file=ns.auth)
    return zenoh.open(settings.to_config())


def shows(status: StatusMsg, goal: GoalMsg) -> bool:
    """Whether the leader's status follows ``goal`` (its centroid, and heading if one was set)."""
    if abs(status.gx - goal.x) > 1e-9 or abs(status.gy - goal.y) > 1e-9:
        return False
    return goal.heading is None or (
        status.heading is not None and abs(status.heading - goal.heading) <= 1e-9)


def status_line(s: StatusMsg) -> str:
    heading = "" if s.heading is None else f" heading {s.heading:.3f}"
    return (f"{s.formation}: {s.state} goal ({s.gx:.3f}, {s.gy:.3f}){heading} "
            f"to go {s.distance:.2f} m, waypoint {s.waypoint + 1}/{s.waypoints} "
            f"({s.wx:.2f}, {s.wy:.2f}), leader {s.leader}, stamp {s.stamp:.2f}")


def query_status(session: zenoh.Session, prefix: str, fid: str = "*",
                 timeout: float = 3.0) -> list[StatusMsg]:
    """Every status the leaders answer for ``{prefix}/formation/{fid}/status``."""
    out: dict[str, StatusMsg] = {}
    selector = f"{keys.validate_prefix(prefix)}/formation/{fid}/status"
    # every leader's queryable answers (the default target would ask only the best match)
    for reply in session.get(selector, target=zenoh.QueryTarget.ALL,
                             consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout):
        if reply.ok is None:
            continue
        try:
            s = decode_status(reply.ok.payload.to_bytes())
        except DecodeError:
            continue
        if s.formation not in out or s.stamp > out[s.formation].stamp:
            out[s.formation] = s
    return [out[k] for k in sorted(out)]


def goal_command(ns: argparse.Namespace) -> int:
    try:
        via = tuple(parse_point(v) for v in ns.via)
        goal = GoalMsg(keys.validate_id(ns.fid, "formation"), ns.x, ns.y, ns.heading, via, time.time())
        if not (math.isfinite(ns.timeout) and ns.timeout > 0):
            raise ValueError("--timeout must be a positive number")
    except ValueError as exc:
        print(f"formation goal: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        session = open_session(ns)
    except Exception as exc:  # zenoh.ZError: no router there, bad auth file
        print(f"formation goal: cannot open a Zenoh session: {exc}", file=sys.stderr)
        return EXIT_FAIL
    try:
        return _send_and_wait(session, ns, goal)
    finally:
        session.close()


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
    last: StatusMsg | None = None
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
                if shows(s, goal):
                    print(status_line(s))
                    return EXIT_OK
    finally:
        sub.undeclare()
        pub.undeclare()
    what = status_line(last) if last is not None else "no status from its leader"
    print(f"formation goal: formation {goal.formation!r} did not take the goal within "
          f"{ns.timeout:g} s ({what})", file=sys.stderr)
    return EXIT_FAIL


def status_command(ns: argparse.Namespace) -> int:
    try:
        session = open_session(ns)
    except Exception as exc:
        print(f"formation status: cannot open a Zenoh session: {exc}", file=sys.stderr)
        return EXIT_FAIL
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
