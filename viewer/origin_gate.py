"""The Origin check in front of the Foxglove WebSocket.

A browser lets any page open a WebSocket to any address, loopback included, and says which page
asked only in the handshake's ``Origin`` header; the server must refuse a foreign one. The
foxglove-sdk server (0.30) offers no hook that sees the handshake, so :class:`OriginGate` listens
on the WebSocket's public port itself, reads the HTTP upgrade request, and

* answers ``403 Forbidden`` and closes when the request carries an ``Origin`` that is not
  allowed (:func:`origin_allowed`): the live page's own (``http://HOST:PAGE_PORT``, HOST the name
  the client used to reach this server), or one named in ``allowed`` (by default the Foxglove web
  app's, :data:`FOXGLOVE_APP`);
* otherwise connects to the Foxglove server, which listens on loopback only at a port of its own,
  hands it the request as read and then relays bytes both ways until either side closes.

A client without an ``Origin`` (the Foxglove desktop app, a script) is no browser page and is
let through, as the page's own HTTP server does. Refusals are logged on ``foxglove.origin``, which
the view shows in its log (:mod:`formation.commands.view`).
"""

from __future__ import annotations

import logging
import socket
import socketserver
import threading
from collections.abc import Iterable
from urllib.parse import urlsplit

logger = logging.getLogger("foxglove.origin")

FOXGLOVE_APP = "https://app.foxglove.dev"  # the Foxglove web app: allowed unless told otherwise
MAX_HEAD = 16 * 1024  # [bytes] a longer request head is refused
HEAD_TIMEOUT_S = 5.0  # [s] the whole request head must arrive within this
CHUNK = 64 * 1024  # [bytes] relayed per read
REFUSED = (b"HTTP/1.1 403 Forbidden\r\nContent-Type: text/plain\r\nContent-Length: 31\r\n"
           b"Connection: close\r\n\r\ncross-origin WebSocket refused\n")
BAD_REQUEST = (b"HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain\r\nContent-Length: 12\r\n"
               b"Connection: close\r\n\r\nbad request\n")


def read_head(sock: socket.socket) -> bytes | None:
    """The request head (through the blank line) and whatever followed it, or None when the
    client closed, stalled or sent more than :data:`MAX_HEAD` bytes first."""
    data = b""
    sock.settimeout(HEAD_TIMEOUT_S)
    try:
        while b"\r\n\r\n" not in data:
            if len(data) > MAX_HEAD:
                return None
            chunk = sock.recv(4096)
            if not chunk:
                return None
            data += chunk
    except OSError:
        return None
    finally:
        sock.settimeout(None)
    return data


def headers_of(head: bytes) -> dict[str, str]:
    """The header fields of a request head, names lower-cased (a repeated one: the last)."""
    lines = head.split(b"\r\n\r\n", 1)[0].decode("latin-1").split("\r\n")[1:]
    out: dict[str, str] = {}
    for line in lines:
        name, sep, value = line.partition(":")
        if sep:
            out[name.strip().lower()] = value.strip()
    return out


def origin_allowed(origin: str | None, host: str, page_port: int | None,
                   allowed: Iterable[str] = (FOXGLOVE_APP,)) -> bool:
    """Whether a handshake with ``Origin: origin`` and ``Host: host`` may go on: no Origin (no
    browser page), one in ``allowed``, or the live page's own: ``http://`` the Host's name and
    ``page_port``."""
    if origin is None:
        return True
    if origin in allowed:
        return True
    if page_port is None:
        return False
    name = urlsplit(f"//{host}").hostname
    return name is not None and origin == f"http://{_netloc(name, page_port)}"


def _netloc(name: str, port: int) -> str:
    return f"[{name}]:{port}" if ":" in name else f"{name}:{port}"


def _pump(src: socket.socket, dst: socket.socket) -> None:
    """Copy ``src`` to ``dst`` until ``src`` ends; then end ``dst``'s sending side."""
    try:
        while chunk := src.recv(CHUNK):
            dst.sendall(chunk)
    except OSError:
        pass
    finally:
        try:
            dst.shutdown(socket.SHUT_WR)
        except OSError:
            pass


class _Gate(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, address: tuple[str, int], backend: tuple[str, int],
                 allowed: tuple[str, ...]) -> None:
        self.backend = backend
        self.allowed = allowed
        self.page_port: int | None = None
        self.refused = 0  # handshakes refused for their Origin
        super().__init__(address, _Handler)


class _Handler(socketserver.BaseRequestHandler):
    server: _Gate

    def handle(self) -> None:
        client: socket.socket = self.request
        head = read_head(client)
        if head is None:
            client.sendall(BAD_REQUEST)
            return
        fields = headers_of(head)
        gate = self.server
        origin = fields.get("origin")
        if not origin_allowed(origin, fields.get("host", ""), gate.page_port, gate.allowed):
            gate.refused += 1
            logger.warning("refused a WebSocket client from origin %s", (origin or "")[:100])
            client.sendall(REFUSED)
            return
        with socket.create_connection(gate.backend, timeout=HEAD_TIMEOUT_S) as upstream:
            upstream.settimeout(None)
            upstream.sendall(head)
            back = threading.Thread(target=_pump, args=(upstream, client), daemon=True)
            back.start()
            _pump(client, upstream)
            back.join()


class OriginGate:
    """Listen on ``(host, port)`` (0: a free port) for the Foxglove server at
    ``127.0.0.1:backend_port``; see the module docstring. ``page_port`` (settable later, once
    the page serves) names the live page's own origin; ``allowed`` further origins."""

    def __init__(self, host: str, port: int, backend_port: int, page_port: int | None = None,
                 allowed: Iterable[str] = (FOXGLOVE_APP,)) -> None:
        self._server = _Gate((host, port), ("127.0.0.1", backend_port), tuple(allowed))
        self._server.page_port = page_port
        self.port = int(self._server.server_address[1])
        self._thread = threading.Thread(target=self._server.serve_forever, name="origin-gate",
                                        daemon=True)
        self._thread.start()

    @property
    def backend(self) -> tuple[str, int]:
        """The Foxglove server's address this gate forwards an admitted page to."""
        return self._server.backend

    @property
    def page_port(self) -> int | None:
        return self._server.page_port

    @page_port.setter
    def page_port(self, port: int | None) -> None:
        self._server.page_port = port

    @property
    def refused(self) -> int:
        return self._server.refused

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=2.0)
