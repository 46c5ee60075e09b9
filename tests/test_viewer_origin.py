"""The live page's HTTP server refuses requests another site's page makes (viewer.server)."""

from __future__ import annotations

import json
import urllib.error
import urllib.request

import pytest

from viewer.server import Hub, PageServer


@pytest.fixture
def page():
    server = PageServer(Hub(), "127.0.0.1", 0)
    yield server
    server.close()


def _get(url: str, origin: str | None) -> int:
    req = urllib.request.Request(url, headers={} if origin is None else {"Origin": origin})
    try:
        with urllib.request.urlopen(req, timeout=10) as resp:
            json.loads(resp.read()) if url.endswith(("/state", "/history")) else resp.read()
            return resp.status
    except urllib.error.HTTPError as exc:
        exc.close()
        return exc.code


def test_state_is_served_to_the_page_itself_and_refused_to_another_origin(page):
    state = page.url + "state"
    assert _get(state, None) == 200
    assert _get(state, f"http://127.0.0.1:{page.port}") == 200  # the page's own origin
    assert _get(state, "http://evil.example") == 403
    assert _get(page.url + "history", None) == 200
    assert _get(page.url + "history", "http://evil.example") == 403  # the barrier history too
    assert _get(page.url, f"http://127.0.0.1:{page.port + 1}") == 403
    req = urllib.request.Request(page.url + "control", data=b"{}", method="POST",
                                 headers={"Origin": "http://evil.example"})
    with pytest.raises(urllib.error.HTTPError) as err:
        urllib.request.urlopen(req, timeout=10)
    err.value.close()
    assert err.value.code == 403


# --- the Foxglove WebSocket (viewer.origin_gate in front of the foxglove-sdk server) ------------

@pytest.fixture
def view():
    from viewer.server import View

    v = View("127.0.0.1", 0, 0)
    yield v
    v.close()


def _handshake(port: int, origin: str | None):
    """A real WebSocket client's handshake (subprotocol foxglove.sdk.v1) with this Origin."""
    from websockets.sync.client import connect

    return connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], origin=origin,
                   open_timeout=10)


def test_the_foxglove_websocket_refuses_another_sites_page_and_serves_its_own(view):
    from websockets.exceptions import InvalidStatus

    ws_port, page_port = view.hub.ws_port, view.page.port
    for foreign in ("http://evil.example", f"http://127.0.0.1:{ws_port}", "null",
                    f"https://127.0.0.1:{page_port}"):
        with pytest.raises(InvalidStatus) as refused:
            _handshake(ws_port, foreign)
        assert refused.value.response.status_code == 403, foreign
    assert view.gate is not None and view.gate.refused == 4
    # the page's own origin, the Foxglove web app and a client that is no browser page: served
    for origin in (f"http://127.0.0.1:{page_port}", "https://app.foxglove.dev", None):
        with _handshake(ws_port, origin) as ws:
            assert ws.subprotocol == "foxglove.sdk.v1"
            hello = json.loads(ws.recv(timeout=10))  # the Foxglove server's own first message
            assert hello["op"] == "serverInfo", hello
    assert view.gate.refused == 4


def test_a_raw_foreign_handshake_gets_403_and_the_foxglove_server_has_a_loopback_port(view):
    import socket

    backend = view.gate.backend
    assert backend[0] == "127.0.0.1" and backend[1] != view.hub.ws_port
    with socket.create_connection(("127.0.0.1", view.hub.ws_port), timeout=10) as s:
        s.sendall(b"GET / HTTP/1.1\r\nHost: x\r\nOrigin: http://evil.example\r\n\r\n")
        assert s.recv(100).startswith(b"HTTP/1.1 403")
