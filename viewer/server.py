"""The live page's server: one hub of frames, an HTTP server for the page, a Foxglove WebSocket.

* :class:`Hub` holds the newest frame (and a sequence number), the newest log lines and the
  barrier history (:class:`BarrierHistory`: the last :data:`HISTORY_S` seconds of every robot's
  barrier values), and hands every frame it gets to a :class:`viewer.record.Channels` (the
  Foxglove WebSocket, and ``run.mcap`` for ``formation record``).
* :class:`PageServer` serves, from a thread of its own, ``GET /`` (the page of
  :mod:`viewer.page`: inline JavaScript and a canvas, nothing to install, nothing fetched from
  elsewhere), ``GET /state`` (the newest frame as JSON, with the logs and the WebSocket's port),
  ``GET /history`` (the barrier history, which a page fetches once when it loads, so a reloaded
  page plots the run from its start) and ``POST /control`` (replay: play, pause, speed, seek).
* :class:`LivePump` polls a :class:`viewer.live.FleetWatcher` a few times a second and
  publishes what it sees; :class:`ReplayPlayer` plays the frames of a recording.

Nothing here runs on the control loop's thread: the pump and the player have their own.
"""

from __future__ import annotations

import bisect
import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from .frame import Frame, num
from .origin_gate import OriginGate
from .page import render_page
from .record import FLEET_TOPIC, LOG_TOPIC, ONSET_LEVEL, ONSET_TEXT, Channels

logger = logging.getLogger(__name__)

LOG_LINES = 50  # the page shows the newest log lines
LIVE_PERIOD_S = 0.1  # [s] how often a live pump looks at the fleet
# the barrier history a page gets when it (re)loads: back to the run's start, at most the last
# 10 minutes (a long --hold run), at most one sample per 0.1 s of the frames' time (the page
# polls ten times a second); so at most 6000 samples, about 40 bytes of JSON per robot each
HISTORY_S = 600.0  # [s]
HISTORY_STEP_S = 0.1  # [s]
HISTORY_SAMPLES = round(HISTORY_S / HISTORY_STEP_S)


class BarrierHistory:
    """A ring of the recent frames' barrier values: per sample the frame's time and each robot's
    id, formation and smallest ``h_formation``, ``h_obstacle``, ``h_formations`` (``None`` where
    unknown). Bounded by :data:`HISTORY_SAMPLES` samples and :data:`HISTORY_S` seconds of frame
    time; a frame older than the newest sample (a replay sought back) starts it afresh, as the
    page does. Not thread-safe: the hub holds its lock around it."""

    def __init__(self, span_s: float = HISTORY_S, step_s: float = HISTORY_STEP_S,
                 cap: int = HISTORY_SAMPLES) -> None:
        self.span_s = span_s
        self.step_s = step_s
        self._ring: deque[tuple[float, tuple[tuple, ...]]] = deque(maxlen=cap)

    def __len__(self) -> int:
        return len(self._ring)

    def add(self, frame: Frame) -> None:
        t = float(frame["t"])
        ring = self._ring
        if ring and t < ring[-1][0]:
            ring.clear()
        elif ring and t < ring[-1][0] + self.step_s:
            return
        ring.append((t, tuple((r["id"], r.get("formation"), num(r.get("h_formation")),
                               num(r.get("h_obstacle")), num(r.get("h_formations")))
                              for r in frame["robots"])))
        while ring[0][0] < t - self.span_s:
            ring.popleft()

    def samples(self) -> list[tuple[float, tuple[tuple, ...]]]:
        """The samples, oldest first (a copy)."""
        return list(self._ring)

    @staticmethod
    def by_robot(samples: Sequence[tuple[float, tuple[tuple, ...]]]) -> dict[str, dict]:
        """Per robot id its (newest) formation and points ``[t, h_formation, h_obstacle,
        h_formations]``, oldest first: the page's own history."""
        out: dict[str, dict] = {}
        for t, rows in samples:
            for rid, formation, *h in rows:
                entry = out.setdefault(rid, {"formation": formation, "pts": []})
                entry["formation"] = formation
                entry["pts"].append([t, *h])
        return out


class Hub:
    """The newest frame, for the page and the Foxglove channels (thread-safe)."""

    def __init__(self, channels: Channels | None = None, mode: str = "live") -> None:
        self.channels = channels
        self.mode = mode
        self.ws_port: int | None = None
        self._lock = threading.Lock()
        self.frame: Frame | None = None
        self.seq = 0
        self.logs: deque[dict] = deque(maxlen=LOG_LINES)
        self.history = BarrierHistory()
        self._status: dict[str, str] = {}
        self.playback: dict[str, Any] = {}
        self.control: Callable[[dict], dict] | None = None

    def publish(self, frame: Frame) -> None:
        """A new frame: kept for the page, logged on the channels, its status changes logged."""
        for r in frame["robots"] if self.mode != "replay" else ():  # a replay has its logs
            s = r.get("status") or ""
            if self._status.get(r["id"]) != s:
                self._status[r["id"]] = s
                if s in ONSET_LEVEL:
                    slack = "n/a" if r.get("slack") is None else f"{r['slack']:.4f}"
                    self.log(frame["t"], ONSET_LEVEL[s], r["id"], ONSET_TEXT[s].format(slack=slack))
        with self._lock:
            self.frame = frame
            self.seq += 1
            self.history.add(frame)
        if self.channels is not None:
            self.channels.frame(frame)

    def log(self, t: float, level: str, name: str, message: str, record: bool = True) -> None:
        with self._lock:
            self.logs.append({"t": t, "level": level, "name": name, "message": message})
        if record and self.channels is not None:
            self.channels.log(t, level, name, message)

    def state(self) -> dict:
        with self._lock:
            return {"seq": self.seq, "mode": self.mode, "ws_port": self.ws_port,
                    "frame": self.frame, "logs": list(self.logs), "playback": dict(self.playback)}

    def history_state(self) -> dict:
        """``GET /history``: the barrier history up to frame ``seq`` and its span [s]."""
        with self._lock:
            seq, samples = self.seq, self.history.samples()
        return {"seq": seq, "span_s": self.history.span_s,
                "robots": BarrierHistory.by_robot(samples)}


class _Handler(BaseHTTPRequestHandler):
    hub: Hub
    page: bytes

    def log_message(self, fmt: str, *args: Any) -> None:  # quiet: debug log, not stderr
        logger.debug("http: " + fmt, *args)

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _foreign(self) -> bool:
        """A request another site's page made (its ``Origin`` is not this server's): refused
        with 403, so a page elsewhere in the operator's browser can neither read the fleet's
        state nor steer a replay. Requests without an ``Origin`` (same-origin GETs, curl) pass."""
        origin = self.headers.get("Origin")
        if origin is None or origin == f"http://{self.headers.get('Host', '')}":
            return False
        self._send(403, b"cross-origin request refused\n", "text/plain")
        return True

    def do_GET(self) -> None:  # http.server's name
        if self._foreign():
            return
        path = self.path.split("?", 1)[0]
        if path in ("/", "/index.html"):
            self._send(200, self.page, "text/html; charset=utf-8")
        elif path in ("/state", "/history"):
            st = self.hub.state() if path == "/state" else self.hub.history_state()
            self._send(200, json.dumps(st, allow_nan=False).encode("utf-8"), "application/json")
        else:
            self._send(404, b"not found\n", "text/plain")

    def do_POST(self) -> None:
        if self._foreign():
            return
        if self.path != "/control" or self.hub.control is None:
            self._send(404, b"not found\n", "text/plain")
            return
        try:
            n = int(self.headers.get("Content-Length", "0"))
            if not 0 <= n <= 4096:
                raise ValueError("body too long")
            req = json.loads(self.rfile.read(n) or b"{}")
            if not isinstance(req, dict):
                raise ValueError("expected a JSON object")
            reply = self.hub.control(req)
        except (ValueError, TypeError) as exc:
            self._send(400, json.dumps({"error": str(exc)}).encode(), "application/json")
            return
        self._send(200, json.dumps(reply).encode(), "application/json")


class PageServer:
    """The page and its ``/state`` on ``http://HOST:PORT/`` (a daemon thread)."""

    def __init__(self, hub: Hub, host: str = "127.0.0.1", port: int = 0, title: str = "") -> None:
        handler = type("Handler", (_Handler,), {"hub": hub, "page": render_page(title).encode()})
        self.httpd = ThreadingHTTPServer((host, port), handler)
        self.httpd.daemon_threads = True
        self.host = host
        self.port = int(self.httpd.server_address[1])
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="viewer-http",
                                        daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("", "0.0.0.0") else self.host
        return f"http://{host}:{self.port}/"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


class LivePump:
    """Every ``period`` seconds, publish the watcher's frame when its time moved on."""

    def __init__(self, watcher: Any, hub: Hub, period: float = LIVE_PERIOD_S) -> None:
        self.watcher = watcher
        self.hub = hub
        self.period = period
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="viewer-pump", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last_t = None
        while not self._stop.wait(self.period):
            try:
                frame = self.watcher.frame()
            except Exception:  # a viewer never takes anything down
                logger.exception("viewer: building a frame failed")
                continue
            if frame is not None and frame["t"] != last_t:
                last_t = frame["t"]
                self.hub.publish(frame)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


class View:
    """Page + Foxglove WebSocket (+ optionally ``run.mcap``) around one hub; ``close()`` ends all."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, ws_port: int = 0,
                 mcap: Path | None = None, mode: str = "live", title: str = "",
                 ws_fallback: bool = False) -> None:
        """``ws_fallback``: if ``ws_port`` is taken, serve the WebSocket on a free port instead
        (the page names it)."""
        self.channels = Channels()
        self.gate: OriginGate | None = None
        try:
            # the Foxglove server on loopback only; its public port is the Origin check's
            self.gate = _gate(host, ws_port, self.channels.serve("127.0.0.1", 0), ws_fallback)
            if mcap is not None:
                self.channels.open_mcap(mcap)
            self.hub = Hub(self.channels, mode=mode)
            self.hub.ws_port = self.gate.port
            self.page = PageServer(self.hub, host, port, title)
            self.gate.page_port = self.page.port  # the page's own origin may connect
        except BaseException:
            if self.gate is not None:
                self.gate.close()
            self.channels.close()
            raise
        self._closers: list[Callable[[], None]] = []

    def on_close(self, fn: Callable[[], None]) -> None:
        self._closers.append(fn)

    def close(self) -> None:
        for fn in reversed(self._closers):
            try:
                fn()
            except Exception:
                logger.debug("viewer close step failed", exc_info=True)
        self.page.close()
        if self.gate is not None:
            self.gate.close()
        self.channels.close()


def _gate(host: str, port: int, backend: int, fallback: bool) -> OriginGate:
    """The Origin check on ``(host, port)`` in front of the Foxglove server at ``backend``;
    with ``fallback`` a taken port gives a free one instead."""
    try:
        return OriginGate(host, port, backend)
    except OSError:
        if not fallback or port == 0:
            raise
        logger.info("port %d taken: the Foxglove WebSocket goes on a free port", port)
        return OriginGate(host, 0, backend)


# --- replay ---------------------------------------------------------------------------------------

def read_recording(path: Path) -> tuple[list[Frame], list[dict]]:
    """The ``/fleet`` frames and ``/log`` lines of a ``run.mcap`` (ValueError if it has none)."""
    # mcap is a test extra, not a dependency: only a replay of a recording needs its reader.
    from mcap.reader import make_reader

    frames: list[Frame] = []
    logs: list[dict] = []
    with Path(path).open("rb") as fh:
        reader = make_reader(fh)
        for _schema, channel, message in reader.iter_messages(topics=[FLEET_TOPIC, LOG_TOPIC],
                                                              log_time_order=True):
            if channel.topic == FLEET_TOPIC:
                frames.append(json.loads(message.data))
            else:
                logs.append({"t": message.log_time / 1e9, **_log_fields(message.data)})
    if not frames:
        raise ValueError(f"{path}: no {FLEET_TOPIC} frames (not a formation-cbf recording?)")
    return frames, logs


def _log_fields(data: bytes) -> dict:
    """level, name and message of an encoded ``foxglove.Log`` (protobuf: fields 2, 3, 4, 5)."""
    out = {"level": "info", "name": "", "message": ""}
    levels = {1: "debug", 2: "info", 3: "warning", 4: "error", 5: "error"}
    pos = 0
    try:
        while pos < len(data):
            tag, pos = _varint(data, pos)
            field, wire = tag >> 3, tag & 7
            if wire == 0:
                value, pos = _varint(data, pos)
                if field == 2:
                    out["level"] = levels.get(value, "info")
            elif wire == 2:
                n, pos = _varint(data, pos)
                chunk = data[pos:pos + n]
                pos += n
                if field in (3, 4):
                    out["message" if field == 3 else "name"] = chunk.decode("utf-8", "replace")
            elif wire == 5:
                pos += 4
            elif wire == 1:
                pos += 8
            else:
                break
    except IndexError:
        pass
    return out


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = data[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            return value, pos
        shift += 7


class ReplayPlayer:
    """Plays recorded frames into a hub on their own clock: play, pause, speed, seek."""

    SPEEDS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)

    def __init__(self, frames: Sequence[Frame], logs: Sequence[dict], hub: Hub,
                 loop: bool = False) -> None:
        self.frames = list(frames)
        self.times = [f["t"] for f in self.frames]
        self.logs = sorted(logs, key=lambda e: e["t"])
        self.hub = hub
        self.loop = loop
        self.playing = True
        self.speed = 1.0
        self._pos = self.times[0]  # recording time shown [s]
        self._index = -1
        self._log_index = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        hub.control = self.control
        self._update_playback()
        self._thread = threading.Thread(target=self._run, name="viewer-replay", daemon=True)
        self._thread.start()

    def _update_playback(self) -> None:
        self.hub.playback = {"playing": self.playing, "speed": self.speed,
                             "start": self.times[0], "end": self.times[-1], "time": self._pos}

    def control(self, req: dict) -> dict:
        with self._lock:
            if "playing" in req:
                self.playing = bool(req["playing"])
            if "speed" in req:
                speed = float(req["speed"])
                if not 0.01 <= speed <= 100.0:
                    raise ValueError(f"speed {speed} must be within 0.01 and 100")
                self.speed = speed
            if "seek" in req:
                t = float(req["seek"])
                self._pos = min(max(t, self.times[0]), self.times[-1])
                self._index = -1
                self._log_index = 0
            self._update_playback()
            return dict(self.hub.playback)

    def _run(self) -> None:
        last = time.monotonic()
        self._advance(0.0)  # the recording's first frame, before its clock moves on
        while not self._stop.wait(0.05):
            now = time.monotonic()
            self._advance(now - last)
            last = now

    def _advance(self, elapsed: float) -> None:
        """Move the shown time on by ``elapsed`` wall seconds (at the speed) and publish the
        frame and the log lines it reached."""
        with self._lock:
            if self.playing:
                self._pos += elapsed * self.speed
                if self._pos >= self.times[-1]:
                    if self.loop:
                        self._pos, self._index, self._log_index = self.times[0], -1, 0
                    else:
                        self._pos = self.times[-1]
                        self.playing = False
            k = max(bisect.bisect_right(self.times, self._pos + 1e-9) - 1, 0)
            new = k != self._index
            self._index = k
            logs = []
            while self._log_index < len(self.logs) and self.logs[self._log_index]["t"] <= self._pos:
                logs.append(self.logs[self._log_index])
                self._log_index += 1
            self._update_playback()
        for e in logs:
            self.hub.log(e["t"], e["level"], e["name"], e["message"], record=False)
        if new:
            self.hub.publish(self.frames[k])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
