"""A Zenoh router as a Python session in ``router`` mode (no ``zenohd`` needed).

A zenoh-python session opened with ``mode: router`` relays samples between the clients (and
peers) connected to it. Run it as a process::

    python -m runtime.router --listen tcp/127.0.0.1:7447

until SIGINT or SIGTERM (exit status 0), or in-process with :func:`run_router` and a
``threading.Event`` that stops it. Multicast scouting is off unless ``--multicast-scouting``.
``--config FILE`` starts from a zenoh JSON5 file, such as the one :mod:`wire.acl` writes with
user/password authentication and an access control list; the flags still set mode, endpoints
and scouting.

A run owns its router: ``--id HEX`` sets the router's Zenoh id (its identity, 32 hex digits) to
a token the launcher drew at random for this run (:func:`new_router_id`), and the launcher's
readiness check (:func:`wait_for_router`) accepts only a router that reports that id. Without
it, two runs given the same port mixed: the second's router could not listen, but its
readiness check (something accepts TCP on the port) accepted the first run's router and its
world published into the other run.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import secrets
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence

import zenoh

from runtime.lifeline import watch_parent
from wire.zconf import UsrPwdAuth, ZenohSettings, use_zenoh_threads

logger = logging.getLogger(__name__)

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
POLL_INTERVAL_S = 0.1  # how often the stop event is checked, so signals are handled [s]
_ROUTER_ID = re.compile(r"^[1-9a-f][0-9a-f]{31}$")
IN_USE = "Address already in use"  # in zenoh's error when a listen endpoint is taken


class RouterClash(RuntimeError):
    """The endpoint is served by some other process than this run's router."""


def new_router_id() -> str:
    """A fresh random router id for one run (32 lowercase hex digits, 124 random bits: zenoh
    refuses an id written with a leading 0)."""
    return secrets.choice("123456789abcdef") + secrets.token_hex(16)[1:]


def check_router_id(router_id: str) -> str:
    if not _ROUTER_ID.match(router_id):
        raise ValueError(f"router id {router_id!r} must be 32 lowercase hex digits, "
                         f"the first not 0")
    return router_id


def router_settings(
    listen: Sequence[str],
    connect: Sequence[str] = (),
    multicast_scouting: bool = False,
    config_file: str | None = None,
) -> ZenohSettings:
    """The settings of a router listening on ``listen`` (and linking to ``connect`` routers),
    starting from the zenoh JSON5 ``config_file`` if given."""
    if isinstance(listen, str):
        raise ValueError("listen must be a sequence of endpoints, not a single str")
    if not listen:
        raise ValueError("listen must name at least one endpoint")
    return ZenohSettings(
        mode="router",
        listen=tuple(listen),
        connect=tuple(connect),
        multicast_scouting=multicast_scouting,
        scouting_delay_s=0.0,  # a router has nothing to wait for before it serves
        config_file=config_file,
    )


def run_router(
    listen: Sequence[str],
    stop_event: threading.Event,
    *,
    connect: Sequence[str] = (),
    multicast_scouting: bool = False,
    ready_event: threading.Event | None = None,
    config_file: str | None = None,
    router_id: str | None = None,
) -> None:
    """Run a router session until ``stop_event`` is set, then close it.

    ``ready_event``, if given, is set once the session is open and listening; ``router_id``
    sets its Zenoh id (see the module docstring). Opening errors (an endpoint in use, say)
    propagate as zenoh raises them.
    """
    conf = router_settings(listen, connect, multicast_scouting, config_file).to_config()
    if router_id is not None:
        conf.insert_json5("id", json.dumps(check_router_id(router_id)))
    session = zenoh.open(conf)
    try:
        logger.info("router %s listening on %s", session.zid(), ", ".join(listen))
        if ready_event is not None:
            ready_event.set()
        while not stop_event.wait(POLL_INTERVAL_S):
            pass
    finally:
        session.close()
        logger.info("router closed")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m runtime.router``."""
    parser = argparse.ArgumentParser(
        prog="python -m runtime.router", description="Run a Zenoh router (a Python router session)."
    )
    parser.add_argument(
        "--listen", metavar="ENDPOINT", action="append", default=None,
        help=f"endpoint to listen on (repeatable; default {DEFAULT_LISTEN})",
    )
    parser.add_argument(
        "--connect", metavar="ENDPOINT", action="append", default=[],
        help="another router to link to (repeatable)",
    )
    parser.add_argument(
        "--multicast-scouting", action=argparse.BooleanOptionalAction, default=False,
        help="discover peers by UDP multicast (default: off)",
    )
    parser.add_argument(
        "--config", metavar="FILE", default=None,
        help="a zenoh JSON5 file to start from (authentication, access control)",
    )
    parser.add_argument(
        "--id", dest="router_id", metavar="HEX", default=None,
        help="the router's Zenoh id (32 hex digits): a per-run token the launcher checks",
    )
    parser.add_argument(
        "--log-level", default="INFO", type=str.upper,
        choices=["DEBUG", "INFO", "WARNING", "ERROR"], help="logging level (default INFO)",
    )
    ns = parser.parse_args(argv)
    logging.basicConfig(
        level=ns.log_level, format="%(asctime)s %(name)s %(levelname)s %(message)s"
    )
    listen = ns.listen or [DEFAULT_LISTEN]

    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        logger.info("received %s, stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    watch_parent()  # started by a launcher: stop when it dies (runtime.lifeline)
    use_zenoh_threads("relay")
    try:
        run_router(listen, stop, connect=ns.connect, multicast_scouting=ns.multicast_scouting,
                   config_file=ns.config, router_id=ns.router_id)
    except ValueError as exc:
        print(f"runtime.router: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - zenoh.ZError (cannot listen, etc.) is no narrower class
        print(f"runtime.router: {exc}", file=sys.stderr)
        return 1
    return 0


def wait_for_router(
    endpoint: str,
    router_id: str,
    *,
    timeout_s: float,
    alive: Callable[[], None] | None = None,
    auth: UsrPwdAuth | None = None,
) -> None:
    """Wait until this run's router (Zenoh id ``router_id``) serves ``endpoint``.

    A client session is opened on ``endpoint`` and asked which router it reached: the wanted id
    returns; another id raises :class:`RouterClash` naming the endpoint at once. ``alive`` is
    called between attempts (the launcher's check that the router process still runs: it raises
    when it exited, e.g. because the port was taken). ``TimeoutError`` after ``timeout_s``.
    """
    check_router_id(router_id)
    conf = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                         auth=auth).to_config()
    deadline = time.monotonic() + timeout_s
    last: Exception | None = None
    while True:
        if alive is not None:
            alive()
        try:
            with zenoh.open(conf) as session:
                seen = [str(z) for z in session.info.routers_zid()]
        except Exception as exc:  # noqa: BLE001 - zenoh.ZError: nothing there yet, or refused
            last, seen = exc, []
        if router_id in seen:
            return
        if seen:
            raise RouterClash(f"{endpoint} is served by another Zenoh router (id {seen[0]}), "
                              f"not this run's: is another run using port "
                              f"{endpoint.rsplit(':', 1)[-1]}?")
        if time.monotonic() > deadline:
            raise TimeoutError(f"no router answered on {endpoint} within {timeout_s} s"
                               + (f" ({last})" if last else ""))
        time.sleep(0.05)


if __name__ == "__main__":
    sys.exit(main())
