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
