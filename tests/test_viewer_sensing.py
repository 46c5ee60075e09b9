"""A fused run's estimates and blind floor in the viewer and the figures: each robot's own
estimate with its 95 % confidence ring beside the truth, and the boxes the camera cannot see, in
the frames, ``run.mcap`` (read back), the page (a headless browser) and the safety figures; a
camera run's frames and scene stay without them."""

from __future__ import annotations

import dataclasses
import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from browser import Browser, chromium_path
from system import require
from test_viewer_recording import assert_renderable, read_mcap

from scenario import load_scenario
from scenario.model import ControllerSpec
from simulator.plots import (
    BLIND_GID,
    ESTIMATE_GID,
    LOCALISATION_TITLE,
    blind_spans,
    estimate_tracks,
    safety_figure,
    trajectory_figure,
)
from simulator.series import Series
from viewer.frame import ESTIMATE_FIELDS, ROBOT_FIELDS, frames_from_series
from viewer.record import FLEET_TOPIC, SCENE_TOPIC, scene_update, write_recording
from viewer.server import Hub, PageServer

AISLE = Path(__file__).parent / "scenarios" / "blind-aisle.yaml"  # fused, one blind box at 0, 0
ERROR = (0.03, -0.04)  # [m] each estimate off its robot's true position
SIGMA = 0.0617  # [m] (a number no other primitive of a scene has)


def fused():
    return load_scenario(AISLE)


def camera():
    s = fused()
    assert isinstance(s.controller, ControllerSpec)
    return dataclasses.replace(s, controller=dataclasses.replace(s.controller, localisation="camera"),
                               world=dataclasses.replace(s.world, camera_blind=()))


def series_of(s, ticks: int = 3, step: float = 1.5, with_estimate: bool = True) -> Series:
    """The formation driving along x, ``step`` metres a tick, each robot's estimate ERROR off."""
    out = Series()
    for k in range(ticks):
        t = round(0.05 * k, 6)
        for r in s.robots:
            x, y = r.start[0] + step * k, r.start[1]
            row = (t, r.id, r.formation, x, y, 0.0, x, y, 0.1, 0.0, 0.1, 0.0, "ok", 0.0, 0.02,
                   0.5, math.inf)
            if with_estimate:
                row += (x + ERROR[0], y + ERROR[1], SIGMA)
            out.robots.append(row)
    return out


def test_a_fused_runs_frames_carry_each_estimate_beside_the_truth_and_the_blind_boxes():
    s = fused()
    frames = list(frames_from_series(series_of(s), s))
    for f in frames:
        for r in f["robots"]:
            assert (r["est_x"] - r["x"], r["est_y"] - r["y"]) == pytest.approx(ERROR)
            assert r["sigma_m"] == SIGMA
        (box,) = f["blind"]
        xs, ys = [c[0] for c in box["corners"]], [c[1] for c in box["corners"]]
        assert (min(xs), max(xs), min(ys), max(ys)) == pytest.approx((-1.75, 1.75, -1.0, 1.0))


def test_a_camera_runs_frames_and_scene_have_no_estimates_and_no_blind_floor():
    s = camera()
    frame = next(iter(frames_from_series(series_of(s, with_estimate=False), s)))
    assert "blind" not in frame
    assert all(set(r) == {"id", "formation", *ROBOT_FIELDS, "gx", "gy"} for r in frame["robots"])
    scene = scene_update(frame).encode()
    assert b"robot/p1" in scene and b"estimate/" not in scene and b"blind/" not in scene


def test_the_scene_rings_each_estimate_with_its_radius_and_lays_the_blind_box_on_the_floor():
    s = fused()
    frame = next(iter(frames_from_series(series_of(s), s)))
    scene = scene_update(frame).encode()  # protobuf: doubles as 8 little-endian bytes
    for r in frame["robots"]:
        assert f"estimate/{r['id']}".encode() in scene
        assert struct.pack("<d", r["est_x"]) in scene and struct.pack("<d", r["est_y"]) in scene
    assert struct.pack("<d", SIGMA) in scene  # the ring's first point: (sigma, 0) off its centre
    assert b"blind/0" in scene and struct.pack("<d", -1.75) in scene
    assert struct.pack("<d", SIGMA) not in scene_update(
        next(iter(frames_from_series(series_of(camera(), with_estimate=False), camera())))).encode()


def test_the_recording_read_back_holds_the_estimates_and_the_blind_floor(tmp_path):
    s = fused()
    series = series_of(s)
    messages = read_mcap(write_recording({}, series, s, tmp_path))
    assert_renderable(messages)
    fleet = [json.loads(m[4]) for m in messages[FLEET_TOPIC]]
    assert len(fleet) == 3
    got = {r["id"]: tuple(r[k] for k in ESTIMATE_FIELDS) for r in fleet[-1]["robots"]}
    want = {row[1]: row[-3:] for row in series.robots if row[0] == fleet[-1]["t"]}
    assert got == want  # JSON keeps every double exactly
    assert all(b"estimate/p1" in m[4] and b"blind/0" in m[4] for m in messages[SCENE_TOPIC])


def test_the_safety_figure_plots_each_robots_error_and_radius_and_shades_blind_floor():
    s = fused()
    series = series_of(s, ticks=4, step=2.0)  # starts at x -4.5 .. -4: on blind floor at tick 2
    tracks = estimate_tracks(series)
    assert set(tracks) == set(s.robot_ids)
    assert all(p[1] == pytest.approx(math.hypot(*ERROR)) and p[2] == SIGMA
               for pts in tracks.values() for p in pts)
    assert blind_spans(series, s) == [(0.1, 0.15)]  # x -0.5 .. 0 at t 0.1, 1.5 .. 2 at t 0.15
    fig = safety_figure(series, s)
    panel = fig.axes[-1]  # the last panel
    assert panel.get_title() == LOCALISATION_TITLE
    assert sum(1 for ln in panel.lines if ln.get_gid() == ESTIMATE_GID) == len(s.robot_ids)
    assert [p.get_gid() for p in panel.patches] == [BLIND_GID]
    traj = trajectory_figure(series, s).axes[0]
    assert sum(1 for p in traj.patches if p.get_gid() == BLIND_GID) == 1
    assert sum(1 for ln in traj.lines if ln.get_gid() == ESTIMATE_GID) == len(s.robot_ids)
    plain = safety_figure(series_of(camera(), with_estimate=False), camera())
    assert LOCALISATION_TITLE not in [a.get_title() for a in plain.axes]
    assert not any(p.get_gid() == BLIND_GID for p in trajectory_figure(
        series_of(camera(), with_estimate=False), camera()).axes[0].patches)


@pytest.mark.integration
def test_the_page_rings_each_estimate_over_its_robot_and_tints_the_blind_floor():
    require(chromium_path() is not None, "chromium", "chromium")
    s = fused()
    frames = list(frames_from_series(series_of(s, ticks=4, step=1.5), s))
    frame = frames[3]  # x 0 .. 0.5: inside the blind box
    hub = Hub(mode="live")
    hub.publish(frame)
    page = PageServer(hub)
    try:
        browser = Browser(page.url)
        try:
            browser.wait_for("window.viewer.seq >= 1 && window.viewer.estimates.length == 4")
            browser.evaluate("window.viewerFreeze = true")
            browser.painted()
            shown = browser.evaluate("window.viewer")
            radii = browser.evaluate("Array.from(document.querySelectorAll('#robots td.radius'))"
                                     ".map(c => c.textContent)")
            _png, rgb = browser.screenshot()
        finally:
            browser.close()
    finally:
        page.close()
    assert radii == [f"{100 * SIGMA:.1f}"] * 4  # the robots table lists each radius [cm]
    robots = {r["id"]: r for r in shown["robots"]}
    scale = robots["p1"]["r"] / s.robot.radius  # CSS pixels per metre
    for e in shown["estimates"]:
        r = robots[e["id"]]
        assert e["r"] == pytest.approx(SIGMA * scale, rel=1e-6)
        assert (e["cx"] - r["cx"], e["cy"] - r["cy"]) == pytest.approx(
            (ERROR[0] * scale, -ERROR[1] * scale), abs=0.5)
        # the ring is drawn dark over the robot's disc: on its circle, the darkest pixel is dark
        circle = [rgb[round(e["cy"] + e["r"] * math.sin(a)), round(e["cx"] + e["r"] * math.cos(a))]
                  for a in np.linspace(0.0, 2 * math.pi, 48, endpoint=False)]
        assert min(int(p.sum()) for p in circle) < 200, e
    # the blind box is tinted violet (red and blue above green) away from robots and labels
    (box,) = shown["blind"]
    y, x = round(box["cy"] + 0.8 * scale), round(box["cx"] - 1.5 * scale)
    r, g, b = (int(v) for v in rgb[y - 2:y + 3, x - 2:x + 3].reshape(-1, 3).mean(axis=0))
    assert b > g + 10 and r > g and (r, g, b) != (255, 255, 255), (r, g, b)


def test_the_live_watcher_draws_the_scenarios_blind_floor_and_a_states_estimate():
    from types import SimpleNamespace

    from viewer.live import FleetWatcher
    from wire.payloads import Pose, State, encode

    class Session:
        def declare_subscriber(self, key, handler):
            return SimpleNamespace(undeclare=lambda: None)

    def put(w, key: str, data: bytes) -> None:
        w.on_sample(SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: data)))

    w = FleetWatcher(Session(), scenario=fused())
    put(w, "warehouse/robot/p1/pose", encode(Pose(1.0, 0.5, 0.0, 7.0)))
    put(w, "warehouse/robot/p1/state", encode(State(1.0, 0.5, 0.1, 0.0, 7.0, 0.0)))
    f = w.frame()
    assert f["blind"] == next(iter(frames_from_series(series_of(fused()), fused())))["blind"]
    assert "sigma_m" not in f["robots"][0]  # a state without a radius: the camera's pose
    bare = FleetWatcher(Session())  # no scenario: no blind floor known
    put(bare, "warehouse/robot/p1/pose", encode(Pose(1.0, 0.5, 0.0, 7.0)))
    assert "blind" not in bare.frame()
    if "sigma" not in getattr(State, "__dataclass_fields__", {}):
        pytest.skip("this wire's state carries no confidence radius")
    state = State(1.2, 0.4, 0.1, 0.0, 7.0, 0.0, SIGMA)
    put(w, "warehouse/robot/p1/state", encode(state))
    (r,) = w.frame()["robots"]
    assert (r["est_x"], r["est_y"], r["sigma_m"]) == (1.2, 0.4, SIGMA)  # single integrators
    assert (r["x"], r["y"]) == (1.0, 0.5)  # the camera's pose stays beside it
