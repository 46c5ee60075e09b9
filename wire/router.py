"""A Zenoh router as a Python session in ``router`` mode (no ``zenohd`` needed).

A zenoh-python session opened with ``mode: router`` relays samples between the clients (and
peers) connected to it. Run it as a process::

    python -m wire.router --listen tcp/127.0.0.1:7447

until SIGINT or SIGTERM (exit status 0), or in-process with :func:`run_router` and a
``threading.Event`` that stops it. Multicast scouting is off unless ``--multicast-scouting``.
``--config FILE`` starts from a zenoh JSON5 file, such as the one :mod:`wire.acl` writes with
user/password authentication and an access control list; the flags still set mode, endpoints
and scouting.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Sequence

import zenoh

from wire.zconf import ZenohSettings, use_zenoh_threads

logger = logging.getLogger(__name__)

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
POLL_INTERVAL_S = 0.1  # how often the stop event is checked, so signals are handled [s]


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
) -> None:
    """Run a router session until ``stop_event`` is set, then close it.

    ``ready_event``, if given, is set once the session is open and listening. Opening errors
    (an endpoint in use, say) propagate as zenoh raises them.
    """
    conf = router_settings(listen, connect, multicast_scouting, config_file).to_config()
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
    """Entry point of ``python -m wire.router``."""
    parser = argparse.ArgumentParser(
        prog="python -m wire.router", description="Run a Zenoh router (a Python router session)."
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
    use_zenoh_threads("relay")
    try:
        run_router(listen, stop, connect=ns.connect, multicast_scouting=ns.multicast_scouting,
                   config_file=ns.config)
    except ValueError as exc:
        print(f"wire.router: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # zenoh.ZError: cannot listen, etc.
        print(f"wire.router: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
