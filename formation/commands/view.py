"""``formation view``, ``formation record``, ``formation replay`` and ``formation run --live``.

formation/cli.py only parses arguments (:func:`add_view_args` and friends) and calls the
``*_command`` functions here. Every command serves or writes until Ctrl-C, or for
``--duration`` seconds of wall time when given.
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from formation.exits import UsageError
from formation.outdir import begin_output
from wire import keys

# viewer.* and wire.zconf (zenoh) are imported inside the commands that use them: formation/cli.py
# imports this module to build its parser, and loading them would slow every `formation --help`
# (about 0.4 s for viewer.server alone).

logger = logging.getLogger(__name__)


def add_client_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--connect", required=True, metavar="EP",
                   help="Zenoh endpoint of the fleet's router, e.g. tcp/192.168.1.10:7447")
    p.add_argument("--prefix", default="warehouse", help="key prefix (default warehouse)")
    p.add_argument("--auth", metavar="FILE",
                   help="credentials: OUT/secure/viewer.json5 of formation run (or user:password)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C)")


def add_serve_args(p: argparse.ArgumentParser, port: bool = True) -> None:
    if port:
        p.add_argument("--port", type=int, default=8080, help="the page's HTTP port (default 8080)")
    p.add_argument("--ws-port", type=int, default=None,
                   help="the Foxglove WebSocket's port (default: the page's port + 1)")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDR",
                   help="address to serve on (default 127.0.0.1; 0.0.0.0 for a lab network)")


def _ports(port: int, ws_port: int | None) -> tuple[int, int]:
    for name, value in (("--port", port), ("--ws-port", ws_port)):
        if value is not None and not 0 <= value < 65536:
            raise UsageError(f"{name}: {value} is not a TCP port")
    if ws_port is None:
        ws_port = port + 1 if 0 < port < 65535 else 0
    return port, ws_port


def _open_view(ns: argparse.Namespace, port: int, mode: str, title: str, mcap: Path | None = None):
    from viewer.server import View

    asked = getattr(ns, "ws_port", None)
    port, ws_port = _ports(port, asked)
    try:
        view = View(host=ns.bind, port=port, ws_port=ws_port, mode=mode, title=title, mcap=mcap,
                    ws_fallback=asked is None)
    except (OSError, RuntimeError) as exc:
        raise RuntimeError(f"cannot serve on {ns.bind} port {port} (WebSocket {ws_port}): "
                           f"{exc}") from None
    _quiet_foxglove(view)
    return view


class _FoxgloveToLog(logging.Handler):
    """The Foxglove server's own messages (a client refused for an old subprotocol, say) go to
    the view's log (the page's log panel and the recording), not onto the run's progress output."""

    def __init__(self, hub: Any) -> None:
        super().__init__(logging.INFO)
        self.hub = hub

    def emit(self, record: logging.LogRecord) -> None:
        frame = self.hub.frame  # a refused client is no error of the run: a warning
        self.hub.log(frame["t"] if frame else 0.0, "warning", "foxglove", record.getMessage())


def _quiet_foxglove(view: Any) -> None:
    fox = logging.getLogger("foxglove")
    fox.propagate = False  # nothing on stderr, where the progress bar is
    for old in [h for h in fox.handlers if isinstance(h, _FoxgloveToLog)]:
        fox.removeHandler(old)
    fox.addHandler(_FoxgloveToLog(view.hub))
    view.on_close(lambda: _unquiet_foxglove(fox))


def _unquiet_foxglove(fox: logging.Logger) -> None:
    for old in [h for h in fox.handlers if isinstance(h, _FoxgloveToLog)]:
        fox.removeHandler(old)
    fox.propagate = True


def _announce(view: Any) -> None:
    print(f"page: {view.page.url}  Foxglove WebSocket: ws://{view.page.url.split('//')[1].split(':')[0]}"
          f":{view.hub.ws_port}", flush=True)


def _session(ns: argparse.Namespace):
    from wire.zconf import ZenohSettings, open_session, read_auth_file

    try:  # --auth: OUT/secure/viewer.json5 of formation run, or a user:password file
        auth = read_auth_file(ns.auth).auth if ns.auth else None
        settings = ZenohSettings(mode="client", connect=(ns.connect,), multicast_scouting=False,
                                 connect_timeout_s=10.0, auth=auth)
        settings.to_config()
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    return open_session(settings, "")  # says so when the router refuses the credentials


def _check_prefix(prefix: str) -> None:
    try:
        keys.validate_prefix(prefix)
    except ValueError as exc:
        raise UsageError(f"--prefix: {exc}") from None


def _wait(duration: float | None) -> None:
    """Until Ctrl-C, SIGTERM or ``duration`` seconds."""
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        deadline = None if duration is None else time.monotonic() + duration
        while not stop.is_set():
            if deadline is not None and time.monotonic() >= deadline:
                break
            stop.wait(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)


def view_command(ns: argparse.Namespace) -> int:
    from viewer.live import FleetWatcher
    from viewer.server import LivePump

    _check_prefix(ns.prefix)
    view = _open_view(ns, ns.port, "live", f"formation view {ns.connect}")
    try:
        with _session(ns) as session:
            watcher = FleetWatcher(session, ns.prefix)
            pump = LivePump(watcher, view.hub)
            _announce(view)
            _wait(ns.duration)
            pump.close()
            watcher.close()
    finally:
        view.close()
    return 0


def record_command(ns: argparse.Namespace) -> int:
    from viewer.live import FleetWatcher
    from viewer.record import Channels
    from viewer.server import Hub, LivePump

    _check_prefix(ns.prefix)
    channels = Channels()
    with _session(ns) as session:
        # the credentials worked and the router answered: replace the previous recording
        out = begin_output(ns)  # (formation.outdir: the recording owns its --out)
        channels.open_mcap(out / "run.mcap")
        hub = Hub(channels, mode="record")
        try:
            watcher = FleetWatcher(session, ns.prefix)
            pump = LivePump(watcher, hub, period=0.05)
            print(f"recording {ns.connect} into {out / 'run.mcap'} (Ctrl-C to stop)", flush=True)
            _wait(ns.duration)
            pump.close()
            watcher.close()
            if watcher.rejected:
                hub.log(hub.frame["t"] if hub.frame else 0.0, "warning", "viewer",
                        f"rejected messages: {watcher.rejected}")
        finally:
            channels.close()
    print(f"wrote {out / 'run.mcap'} ({hub.seq} frames)")
    return 0


def replay_command(ns: argparse.Namespace) -> int:
    from viewer.server import ReplayPlayer, read_recording

    path = Path(ns.recording)
    try:
        frames, logs = read_recording(path)
    except OSError as exc:
        raise UsageError(f"{path}: {exc.strerror or exc}") from None
    except Exception as exc:  # noqa: BLE001 - an unreadable file is invalid input
        raise UsageError(f"{path}: not a readable recording ({exc})") from None
    view = _open_view(ns, ns.port, "replay", f"formation replay {path.name}")
    player = ReplayPlayer(frames, logs, view.hub, loop=ns.loop)
    if ns.speed is not None:
        player.control({"speed": ns.speed})
    view.on_close(player.close)
    try:
        _announce(view)
        _wait(ns.duration)
    finally:
        view.close()
    return 0


def live_observer(ns: argparse.Namespace, scenario: Any) -> tuple[Any, Callable | None]:
    """``formation run --live PORT``: the view, and the observer :func:`simulator.launch.launch`
    calls with the world's session (it returns the function that detaches it)."""
    port = getattr(ns, "live", None)
    if port is None:
        return None, None
    from viewer.live import FleetWatcher
    from viewer.server import LivePump

    view = _open_view(ns, port, "live", f"formation run {scenario.name}")
    _announce(view)

    def observe(session: Any) -> Callable[[], None]:
        watcher = FleetWatcher(session, radius=scenario.robot.radius,
                               tolerance=scenario.goal_tolerance, scenario=scenario)
        pump = LivePump(watcher, view.hub)

        def detach() -> None:
            pump.close()
            watcher.close()

        return detach

    return view, observe
