"""The live viewer during a real multi-process run: the page in headless Chromium, the Foxglove
WebSocket, ``formation record`` attached to the fleet's router, then ``formation replay``."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from browser import Browser, chromium_path, hex_rgb
from system import require
from test_viewer_recording import check_recording, read_mcap

from runtime.testing import free_tcp_port, tcp_endpoint, wait_for_tcp_port
from viewer.record import FLEET_TOPIC, SCENE_TOPIC

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

ROOT = Path(__file__).resolve().parent.parent
# two-small with every goal 1 m further: about 14 s of real time
SCENARIO = (ROOT / "tests" / "scenarios" / "two-small.yaml").read_text(encoding="utf-8").replace(
    "goal: [2.0, 0.0]", "goal: [3.0, 0.0]").replace("goal: [2.0, 0.5]", "goal: [3.0, 0.5]").replace(
    "goal: [1.6, 0.25]", "goal: [2.6, 0.25]").replace("goal: [0.0, -0.3]", "goal: [-1.0, -0.3]").replace(
    "goal: [0.4, -0.3]", "goal: [-0.6, -0.3]")


def _ctrl_c_stops() -> None:
    """In the child: Ctrl-C's default action, which these tests stop it with, even where the
    tests themselves run with SIGINT ignored (a shell runs ``cmd &`` without job control so, and
    an ignored signal is inherited: formation replay then never stopped)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def formation(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "formation", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, preexec_fn=_ctrl_c_stops, **kw)


def get_state(port: int) -> dict:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/state", timeout=5) as r:
        return json.load(r)


def wait_state(port: int, ready, timeout: float = 30.0, proc: subprocess.Popen | None = None) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        try:
            st = get_state(port)
            if ready(st):
                return st
        except OSError:
            pass
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"process ended: {proc.stdout.read()}")
        if time.monotonic() > deadline:
            raise TimeoutError(f"page on {port} not ready in {timeout} s")
        time.sleep(0.1)


def foxglove_messages(port: int, topics: set[str], count: int, timeout: float = 15.0) -> dict:
    """Subscribe to ``topics`` on the Foxglove WebSocket (subprotocol ``foxglove.sdk.v1``) and
    collect ``count`` messages of each: topic -> [(log time ns, payload)]."""
    from websockets.sync.client import connect

    out: dict[str, list] = {t: [] for t in topics}
    with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"],
                 open_timeout=10, max_size=None) as ws:
        assert ws.subprotocol == "foxglove.sdk.v1"
        channels: dict[int, str] = {}
        subs: dict[int, str] = {}
        deadline = time.monotonic() + timeout
        while any(len(v) < count for v in out.values()):
            assert time.monotonic() < deadline, f"got only {[(t, len(v)) for t, v in out.items()]}"
            msg = ws.recv(timeout=timeout)
            if isinstance(msg, str):
                m = json.loads(msg)
                if m["op"] == "advertise":
                    new = [c for c in m["channels"] if c["topic"] in topics]
                    for c in new:
                        channels[c["id"]] = c["topic"]
                        assert c["schemaName"] in ("foxglove.SceneUpdate", "formation.Fleet")
                    req = [{"id": 100 + c["id"], "channelId": c["id"]} for c in new]
                    subs.update({100 + c["id"]: c["topic"] for c in new})
                    if req:
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": req}))
            elif msg[0] == 1:  # message data: op, u32 subscription, u64 log time, payload
                sub, stamp = struct.unpack_from("<IQ", msg, 1)
                out[subs[sub]].append((stamp, bytes(msg[13:])))
    return out


def test_a_live_run_serves_the_page_and_foxglove_while_a_recorder_attaches(tmp_path):
    require(chromium_path() is not None, "chromium", "chromium")
    scenario = tmp_path / "two.yaml"
    scenario.write_text(SCENARIO, encoding="utf-8")
    page, router = free_tcp_port(), free_tcp_port()
    run = formation("run", str(scenario), "--out", str(tmp_path / "run"), "--realtime", "--quiet",
                    "--no-plots", "--port", str(router), "--live", str(page), "--ws-port", "0")
    recorder = None
    try:
        wait_for_tcp_port(page, timeout_s=30)
        st = wait_state(page, lambda s: s["frame"] is not None and len(s["frame"]["robots"]) == 5
                        and all(r["status"] for r in s["frame"]["robots"]), proc=run)
        assert st["mode"] == "live" and st["ws_port"]
        # each formation's row as its leader reports it on its status key (about once a second)
        told = wait_state(page, lambda s: all(fm["leader"] for fm in s["frame"]["formations"]),
                          proc=run)
        assert {fm["name"]: fm["leader"] for fm in told["frame"]["formations"]} == {"A": "a1", "B": "b1"}
        assert all(fm["status"] in ("moving", "reached", "stalled", "stopped")
                   for fm in told["frame"]["formations"])
        recorder = formation("record", "--connect", tcp_endpoint(router), "--out",
                             str(tmp_path / "rec"), "--duration", "4",
                             "--auth", str(tmp_path / "run" / "secure" / "viewer.json5"))

        # the Foxglove WebSocket: scene updates arrive, and move on
        got = foxglove_messages(st["ws_port"], {SCENE_TOPIC, FLEET_TOPIC}, 3)
        stamps = [s for s, _ in got[SCENE_TOPIC]]
        assert stamps == sorted(stamps) and stamps[-1] > stamps[0]
        assert all(b"robot/a1" in p and b"ellipse/A" in p and b"load/A" in p
                   for _, p in got[SCENE_TOPIC])
        fleet = json.loads(got[FLEET_TOPIC][-1][1])
        assert {r["id"] for r in fleet["robots"]} == {"a1", "a2", "a3", "b1", "b2"}
        # each formation's load, placed with the run's scenario (its members' start hull)
        assert {ld["formation"]: len(ld["outline"]) for ld in fleet["loads"]} == {"A": 3, "B": 2}

        # the page in Chromium: robots drawn where the page projects them, the time moving on
        browser = Browser(f"http://127.0.0.1:{page}/")
        try:
            browser.wait_for("window.viewer.seq > 2 && window.viewer.robots.length == 5")
            for attempt in range(3):  # a loaded machine may paint late: look again, at most twice
                browser.evaluate("window.viewerFreeze = true")
                time.sleep(0.3)  # a poll already under way lands
                browser.painted()
                shown = browser.evaluate("window.viewer")
                png, rgb = browser.screenshot()
                (tmp_path / f"page{attempt}.png").write_bytes(png)
                problem = robots_not_drawn(shown, rgb)
                if problem is None and browser.evaluate("window.viewer.seq") == shown["seq"]:
                    break
                browser.evaluate("window.viewerFreeze = false")
                time.sleep(0.5)
            assert problem is None, problem
            t1 = shown["t"]
            assert f"t={t1:.2f}" in browser.evaluate("document.title")
            clock = browser.evaluate("document.getElementById('time').textContent")
            assert "UTC" in clock, clock
            # beside the clock: the run's time from the server's first frame, not the page's age
            st = get_state(page)
            assert st["frame"]["t0"] <= st["frame"]["t"] and "run time" in clock, clock
            run_time = float(clock.split("run time ")[1].split(" s")[0])
            assert run_time > 1.0, clock  # the page opened seconds after the run started
            browser.evaluate("window.viewerFreeze = false")
            time.sleep(1.5)
            t2 = browser.wait_for(f"window.viewer.t > {t1} && window.viewer.t")
            assert t2 > t1
            assert f"t={t2:.2f}" in browser.evaluate("document.title") or \
                browser.evaluate("window.viewer.t") > t2
            formations = browser.evaluate("document.getElementById('formations').textContent")
            assert "moving" in formations or "reached" in formations
            assert "a1" in formations and "b1" in formations  # the leaders, from their status
            # reloaded, the page's barrier charts reach back to the run's start (the server's
            # history), long before the page was first opened
            browser.evaluate("window.oldPage = true")  # gone once the page has reloaded
            browser.call("Page.reload")
            shown = browser.wait_for("window.oldPage === undefined && window.viewer.seq > 0 "
                                     "&& window.viewer")
            assert shown["history"]["start"] == pytest.approx(st["frame"]["t0"]), shown["history"]
            assert shown["history"]["start"] < t1 - 1.0
        finally:
            browser.close()

        assert recorder.wait(timeout=30) == 0, recorder.stdout.read()
        assert run.wait(timeout=60) == 0, run.stdout.read()
    finally:
        for p in (run, recorder):
            if p is not None:
                if p.poll() is None:
                    os.killpg(p.pid, signal.SIGINT)
                    p.wait(timeout=30)
                p.stdout.close()
    # the run's own recording: one scene per tick at the tick's time
    check_recording(tmp_path / "run")
    # the recorder's: wall-clock stamped frames of the fleet it watched
    rec = read_mcap(tmp_path / "rec" / "run.mcap")
    assert len(rec[SCENE_TOPIC]) >= 5
    frames = [json.loads(m[4]) for m in rec[FLEET_TOPIC]]
    assert all(abs(f["t"] - m[0] / 1e9) < 1e-6 for f, m in zip(frames, rec[FLEET_TOPIC], strict=True))
    assert abs(frames[-1]["t"] - time.time()) < 120  # wall time, not simulated time
    assert {r["formation"] for r in frames[-1]["robots"]} == {"A", "B"}  # from the diag key
    # no scenario: the loads are the hulls of the members as heard
    assert {ld["formation"] for ld in frames[-1]["loads"]} == {"A", "B"}
    assert all(r["h_obstacle"] is not None for r in frames[-1]["robots"])


def robots_not_drawn(shown: dict, rgb) -> str | None:
    """What is wrong with the robots in the screenshot, or None: every robot's disc is in its
    formation's colour at its projected centre, and the page's projection is one similarity
    (uniform scale, y up) for all robots."""
    robots = shown["robots"]
    assert len(robots) == 5
    a, b = robots[0], robots[-1]
    scale = (b["cx"] - a["cx"]) / (b["x"] - a["x"])
    assert scale > 10  # pixels per metre
    for r in robots:
        assert r["cx"] == pytest.approx(a["cx"] + (r["x"] - a["x"]) * scale, abs=1.0)
        assert r["cy"] == pytest.approx(a["cy"] - (r["y"] - a["y"]) * scale, abs=1.0)
        x, y = round(r["cx"]), round(r["cy"])
        k = max(int(r["r"] * 0.4), 1)  # the disc's inner part (the heading tick starts further out)
        assert k <= y < rgb.shape[0] - k and k <= x < rgb.shape[1] - k
        patch = rgb[y - k:y + k + 1, x - k:x + k + 1].reshape(-1, 3).astype(int)
        near = np.abs(patch - np.array(hex_rgb(r["color"]))).max(axis=1) <= 24
        if near.mean() < 0.9:
            return f"{r['id']} at {x},{y}: mean colour {patch.mean(axis=0)}, want {r['color']}"
    colors = {r["color"] for r in robots}
    assert len(colors) == 2  # one per formation
    return None


def test_replay_serves_a_recording_with_play_pause_and_speed(tmp_path):
    from formation.cli import main

    assert main(["sim", str(ROOT / "tests" / "scenarios" / "two-small.yaml"), "--out",
                 str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    port = free_tcp_port()
    proc = formation("replay", str(tmp_path / "sim" / "run.mcap"), "--port", str(port),
                     "--ws-port", "0", "--speed", "4", "--duration", "20")
    try:
        wait_for_tcp_port(port, timeout_s=30)
        st = wait_state(port, lambda s: s["frame"] is not None and s["frame"]["t"] > 0.5, proc=proc)
        assert st["mode"] == "replay" and st["playback"]["speed"] == 4.0
        summary = json.loads((tmp_path / "sim" / "summary.json").read_text())
        last_tick = summary["sim_time_s"] - 0.05  # the recording's last frame (dt 0.05)
        assert st["playback"]["end"] == pytest.approx(last_tick)
        req = urllib.request.Request(f"http://127.0.0.1:{port}/control", method="POST",
                                     data=json.dumps({"playing": False}).encode())
        with urllib.request.urlopen(req, timeout=5) as r:
            assert json.load(r)["playing"] is False
        time.sleep(0.3)
        paused = get_state(port)["frame"]["t"]
        time.sleep(0.5)
        assert get_state(port)["frame"]["t"] == paused
        req = urllib.request.Request(f"http://127.0.0.1:{port}/control", method="POST",
                                     data=json.dumps({"seek": 2.0, "playing": True,
                                                      "speed": 1.0}).encode())
        urllib.request.urlopen(req, timeout=5).close()
        st = wait_state(port, lambda s: 2.0 <= s["frame"]["t"] < paused or paused < 2.0)
        assert st["playback"]["speed"] == 1.0
        bad = urllib.request.Request(f"http://127.0.0.1:{port}/control", method="POST",
                                     data=json.dumps({"speed": -1}).encode())
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(bad, timeout=5)
        assert err.value.code == 400
        err.value.close()
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=30)
        proc.stdout.close()
        assert code == 0


def test_bad_viewer_input_exits_2_before_anything_starts(tmp_path):
    from formation.cli import main

    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"not an mcap")
    assert main(["replay", str(bad), "--port", "0"]) == 2
    assert main(["replay", str(tmp_path / "missing.mcap"), "--port", "0"]) == 2
    assert main(["view", "--connect", "tcp/127.0.0.1:9", "--auth", str(tmp_path / "none"),
                 "--port", "0"]) == 2
    assert main(["record", "--connect", "tcp/127.0.0.1:9", "--prefix", "a/*", "--out",
                 str(tmp_path / "rec")]) == 2
    assert not (tmp_path / "rec").exists()
    assert main(["run", str(ROOT / "tests" / "scenarios" / "two-small.yaml"), "--out",
                 str(tmp_path / "run"), "--live", "70000"]) == 2
    assert not (tmp_path / "run").exists()


def test_the_floor_has_metric_axes_and_a_scale_bar(tmp_path):
    """The page's floor is measured: labels every 1, 2 or 5 x 10^k metres and a scale bar of a
    round length drawn at the page's scale (dark where the page says it is). The screenshot is
    docs/viewer-axes.png (written when FORMATION_WRITE_DOCS=1)."""
    require(chromium_path() is not None, "chromium", "chromium")
    from formation.cli import main

    scenario = ROOT / "tests" / "scenarios" / "nav-behind-shelf.yaml"
    assert main(["sim", str(scenario), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    port = free_tcp_port()
    proc = formation("replay", str(tmp_path / "sim" / "run.mcap"), "--port", str(port),
                     "--ws-port", "0", "--duration", "60")
    try:
        wait_for_tcp_port(port, timeout_s=30)
        wait_state(port, lambda s: s["frame"] is not None and s["frame"]["t"] > 3.0, proc=proc)
        browser = Browser(f"http://127.0.0.1:{port}/")
        try:
            axes = browser.wait_for("window.viewer && window.viewer.seq > 2 && window.floorAxes")
            mantissa = axes["bar_m"] / 10 ** np.floor(np.log10(axes["bar_m"]))
            assert round(mantissa, 6) in (1.0, 2.0, 5.0), axes
            assert axes["bar_px"] == pytest.approx(axes["bar_m"] * axes["scale"])
            browser.evaluate("window.viewerFreeze = true")
            browser.painted()
            png, rgb = browser.screenshot()
            (tmp_path / "page.png").write_bytes(png)
            axes = browser.evaluate("window.floorAxes")
            mid = ((axes["bar_left"] + axes["bar_right"]) / 2, axes["bar_y"])
            dark = [rgb[round(mid[1]) + dy, round(mid[0]) + dx].max() for dx in (-2, 0, 2)
                    for dy in (-1, 0, 1)]
            assert min(dark) < 90, (mid, dark)
            if os.environ.get("FORMATION_WRITE_DOCS") == "1":
                (ROOT / "docs" / "viewer-axes.png").write_bytes(png)
        finally:
            browser.close()
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=30)
        proc.stdout.close()


def test_a_reloaded_page_plots_the_barriers_since_the_run_started(tmp_path):
    """The barrier charts of a page loaded (and reloaded) mid-run reach back to the run's first
    frame: the page fetches the server's history (GET /history) before it polls, and draws it
    (lines in the formations' colours left of where the page was loaded)."""
    require(chromium_path() is not None, "chromium", "chromium")
    from formation.cli import main

    assert main(["sim", str(ROOT / "tests" / "scenarios" / "two-small.yaml"), "--out",
                 str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    port = free_tcp_port()
    # at a quarter speed: the run (9.7 s of simulated time) outlasts the page's two loads on a
    # busy machine
    proc = formation("replay", str(tmp_path / "sim" / "run.mcap"), "--port", str(port),
                     "--ws-port", "0", "--duration", "90", "--speed", "0.25")
    try:
        wait_for_tcp_port(port, timeout_s=30)
        first = wait_state(port, lambda s: s["frame"] is not None, proc=proc)["playback"]["start"]
        wait_state(port, lambda s: s["frame"]["t"] > first + 2.0, proc=proc)
        browser = Browser(f"http://127.0.0.1:{port}/")
        try:
            for load in range(2):  # the first load mid-run, then a reload later on
                shown = browser.wait_for("window.oldPage === undefined && window.viewer.seq > 0 "
                                         "&& window.viewer.history.points > 0 && window.viewer")
                loaded_at = shown["t"]
                assert loaded_at > first + 2.0
                assert shown["history"]["start"] == pytest.approx(first), shown["history"]
                # about 10 samples a second since the start, for 5 robots, not only those polled
                assert shown["history"]["points"] >= 5 * 5 * (loaded_at - first), shown["history"]
                # drawn: each formation's lines across the time before the page (re)loaded
                drawn, columns = chart_columns_before(browser, loaded_at - 1.0,
                                                      tmp_path / f"load{load}.png")
                assert columns >= 10 and drawn >= 0.9 * columns, (load, drawn, columns)
                wait_state(port, lambda s, t=loaded_at: s["frame"]["t"] > t + 1.0, proc=proc)
                browser.evaluate("window.oldPage = true")  # gone once the page has reloaded
                browser.call("Page.reload")
        finally:
            browser.close()
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=30)
        proc.stdout.close()


def chart_columns_before(browser: Browser, t: float, png_path: Path) -> tuple[int, int]:
    """The barrier charts left of time ``t``: how many pixel columns from the run's first frame
    to ``t`` hold a line of each formation (blue A, red B: the fewer of the two), and how many
    columns that span is."""
    browser.evaluate("window.viewerFreeze = true")
    try:
        browser.painted()
        shown, axes = browser.evaluate("window.viewer"), browser.evaluate("window.chartAxes")
        png, rgb = browser.screenshot()
        png_path.write_bytes(png)
    finally:
        browser.evaluate("window.viewerFreeze = false")
    assert axes["t0"] < shown["history"]["start"] < t < axes["t1"], (axes, t)
    assert sorted(r["color"] for r in shown["robots"]) == ["#1f77b4"] * 3 + ["#d62728"] * 2

    def x(time: float) -> int:
        return round(axes["left"] + (time - axes["t0"]) / (axes["t1"] - axes["t0"]) * axes["width"])

    left, x0, x1 = round(axes["left"]) + 2, x(shown["history"]["start"]) + 1, x(t)
    y0, y1 = round(axes["top"]) + 2, round(axes["top"] + axes["height"]) - 2
    region = rgb[y0:y1, left:x1].astype(int)
    blue = region[:, :, 2] - region[:, :, 0] > 40
    red = region[:, :, 0] - region[:, :, 2] > 40
    red[red[:, :x0 - left].any(axis=1)] = False  # the dashed zero lines run the charts' width
    drawn = [int(m[:, x0 - left:].any(axis=0).sum()) for m in (blue, red)]
    return min(drawn), x1 - x0


def test_a_refused_old_protocol_client_goes_to_the_views_log_not_the_output(tmp_path):
    from websockets.sync.client import connect

    from formation.cli import main

    assert main(["sim", str(ROOT / "tests" / "scenarios" / "two-small.yaml"), "--out",
                 str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    port = free_tcp_port()
    proc = formation("replay", str(tmp_path / "sim" / "run.mcap"), "--port", str(port),
                     "--ws-port", "0", "--duration", "60")
    try:
        wait_for_tcp_port(port, timeout_s=30)
        ws_port = wait_state(port, lambda s: s["ws_port"], proc=proc)["ws_port"]
        with pytest.raises(Exception, match="400"):  # the old subprotocol: refused
            connect(f"ws://127.0.0.1:{ws_port}", subprotocols=["foxglove.websocket.v1"],
                    open_timeout=30).close()
        st = wait_state(port, lambda s: any(e["name"] == "foxglove" for e in s["logs"]), proc=proc)
        assert any("handshake" in e["message"] for e in st["logs"] if e["name"] == "foxglove")
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=30)
        out = proc.stdout.read()
        proc.stdout.close()
    assert out.splitlines()[0].startswith("page: ") and "foxglove" not in out.lower().replace(
        "foxglove websocket", ""), out
