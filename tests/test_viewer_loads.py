"""The loads in the viewer (issue 25): in every frame, in ``run.mcap`` and on the page."""

from __future__ import annotations

import copy
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from browser import Browser, chromium_path, hex_rgb
from system import require
from test_viewer_recording import read_mcap

from geometry.polygon import points_distance
from geometry.rigid import RigidMotion
from scenario.cargo import load_polygon, placed_load
from scenario.load import scenario_from_dict
from simulator.series import Series
from viewer.frame import frames_from_series
from viewer.live import FleetWatcher
from viewer.loads import LoadView, hull_entries
from viewer.record import FLEET_TOPIC, LOG_TOPIC, SCENE_TOPIC, write_recording
from viewer.server import Hub, PageServer

# A carries a declared 1.2 x 0.8 box; B, a pair, the default hull (a segment); a wall far off
SCENARIO = {
    "name": "loads", "dt": 0.05, "duration": 10.0,
    "robot": {"max_speed": 0.22, "radius": 0.105},
    "controller": {"kp": 2.0, "gamma": 1.0, "epsilon": 0.05},
    "formations": [
        {"name": "A", "leader": "a1", "load": {"size": [1.2, 0.8]},
         "robots": {"a1": {"start": [0.0, 0.0], "goal": [4.0, 0.0]},
                    "a2": {"start": [0.0, 1.0], "goal": [4.0, 1.0]},
                    "a3": {"start": [1.0, 0.5], "goal": [5.0, 0.5]}},
         "edges": [["a1", "a2"], ["a1", "a3"], ["a2", "a3"]]},
        {"name": "B", "leader": "b1",
         "robots": {"b1": {"start": [0.0, 4.0], "goal": [4.0, 4.0]},
                    "b2": {"start": [0.0, 5.0], "goal": [4.0, 5.0]}},
         "edges": [["b1", "b2"]]},
    ],
    "obstacles": [{"name": "rail", "segment": [[6.0, 3.0], [6.0, 6.0]], "safe_distance": 0.2}],
}
MOVE = RigidMotion(0.4, 0.5, -0.2)


def scenario():
    return scenario_from_dict(copy.deepcopy(SCENARIO))


def robots_at(s, where: dict[str, tuple[float, float]]) -> list[dict]:
    """Frame robot entries at ``where`` (id -> body position)."""
    return [{"id": r.id, "formation": r.formation, "x": where[r.id][0], "y": where[r.id][1]}
            for r in s.robots if r.id in where]


def moved(s, *, b_into_a: bool = False, b_over_rail: bool = False) -> dict[str, tuple[float, float]]:
    """A moved rigidly by MOVE; B at its start, or one member in A's load, or across the rail."""
    pos = {r.id: MOVE.apply(r.start[:2]) for r in s.formations[0].robots}
    pos.update({r.id: (r.start[0], r.start[1]) for r in s.formations[1].robots})
    if b_into_a:
        pos["b1"] = MOVE.apply((-0.05, 0.5))  # inside A's box, clear of A's robots and centre
    if b_over_rail:
        pos["b1"], pos["b2"] = (5.5, 4.5), (6.5, 4.5)
    return pos


def test_each_formations_load_is_placed_as_the_figures_place_it_declared_or_not():
    s = scenario()
    fa, fb = s.formations
    where = moved(s)
    out = LoadView(s).fields(robots_at(s, where), [])
    loads = {ld["formation"]: ld for ld in out["loads"]}
    assert loads["A"]["declared"] is True and loads["B"]["declared"] is False
    expect_a = placed_load(fa, load_polygon(fa), [where[r.id] for r in fa.robots])
    assert loads["A"]["outline"] == [list(p) for p in expect_a]
    assert len(expect_a) == 4 and all(math.dist(p, MOVE.apply(q)) < 1e-9
                                      for p, q in zip(expect_a, load_polygon(fa), strict=True))
    assert loads["B"]["outline"] == [[0.0, 4.0], [0.0, 5.0]]  # a pair's hull: a segment
    assert out["load_hits"] == []
    # a member not heard of: its formation's load is not drawn
    del where["b2"]
    assert [ld["formation"] for ld in LoadView(s).fields(robots_at(s, where), [])["loads"]] == ["A"]


def test_a_robot_in_a_load_and_a_load_over_a_wall_are_hits_with_a_line_to_what_was_hit():
    s = scenario()
    view = LoadView(s)
    where = moved(s, b_into_a=True)
    out = view.fields(robots_at(s, where), [])
    (hit,) = [h for h in out["load_hits"] if h["formation"] == "A"]
    assert hit["other"] == "b1" and hit["clearance"] < 0.0
    a_outline = [tuple(p) for p in out["loads"][0]["outline"]]
    assert hit["line"][1] == list(where["b1"])  # the robot's centre
    on_edge = points_distance(np.array([hit["line"][0]]), a_outline)[0]
    assert on_edge == pytest.approx(0.0, abs=1e-9)  # the load's outline nearest to it
    assert view.fields(robots_at(s, where), [], hits=False)["load_hits"] == []
    over = view.fields(robots_at(s, moved(s, b_over_rail=True)), [])["load_hits"]
    assert [(h["formation"], h["other"]) for h in over] == [("B", "rail")]
    assert over[0]["line"][1][0] == pytest.approx(6.0)  # on the wall


def test_without_a_scenario_the_loads_are_the_members_hulls():
    robots = [{"id": "x1", "formation": "X", "x": 0.0, "y": 0.0},
              {"id": "x2", "formation": "X", "x": 1.0, "y": 0.0},
              {"id": "x3", "formation": "X", "x": 0.5, "y": 1.0},
              {"id": "y1", "formation": "Y", "x": 5.0, "y": 5.0},
              {"id": "z1", "formation": "?", "x": 3.0, "y": 3.0}]
    assert hull_entries(robots) == [
        {"formation": "X", "outline": [[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]], "declared": False}]


def series_of(s, ticks: list[dict[str, tuple[float, float]]]) -> Series:
    out = Series()
    for k, where in enumerate(ticks):
        t = round(0.05 * k, 6)
        for r in s.robots:
            x, y = where[r.id]
            out.robots.append((t, r.id, r.formation, x, y, 0.0, x, y, 0.0, 0.0, 0.0, 0.0,
                               "ok", 0.0, 0.1, 0.1, 0.1))
    return out


def test_the_recording_holds_the_loads_and_a_red_line_for_each_load_overlap(tmp_path):
    s = scenario()
    series = series_of(s, [moved(s), moved(s, b_into_a=True), moved(s)])
    frames = list(frames_from_series(series, s))
    assert [len(f["load_hits"]) for f in frames] == [0, 1, 0]
    summary = {"min_clearance_m": {"load": -0.2},
               "collision_log": [{"t": 0.05, "a": "A", "b": "b1", "clearance_m": -0.2,
                                  "kind": "load", "x": 0.0, "y": 0.0}]}
    messages = read_mcap(write_recording(summary, series, s, tmp_path))
    fleet = [json.loads(m[4]) for m in messages[FLEET_TOPIC]]
    assert fleet == json.loads(json.dumps(frames))  # the frames as built, loads and hits
    scenes = [m[4] for m in messages[SCENE_TOPIC]]
    assert all(b"load/A" in sc and b"load/B" in sc for sc in scenes)
    assert [b"load_hit/A/b1" in sc for sc in scenes] == [False, True, False]
    assert any(b"collision load A - b1" in m[4] for m in messages[LOG_TOPIC])
    # a run whose loads never overlapped anything is not searched for overlaps
    clean = read_mcap(write_recording({"min_clearance_m": {"load": 0.3}}, series, s,
                                      tmp_path / "clean"))
    assert not any(b"load_hit/" in m[4] for m in clean[SCENE_TOPIC])


def watcher(scenario=None):
    from wire.diag import Diag, encode_diag
    from wire.payloads import Pose, encode

    class Session:
        def declare_subscriber(self, key, handler):
            return SimpleNamespace(undeclare=lambda: None)

    w = FleetWatcher(Session(), scenario=scenario)

    def put(key: str, data: bytes) -> None:
        w.on_sample(SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: data)))

    def at(where, formation_of):
        for rid, (x, y) in where.items():
            put(f"warehouse/robot/{rid}/pose", encode(Pose(x, y, 0.0, 3.0)))
            put(f"warehouse/robot/{rid}/diag", encode_diag(Diag(
                formation_of[rid], "ok", 3.0, 0.0, 0.1, 0.1, 0.1, 0.0, 0.0, 1, 0, 0, 0, 0)))
        return w.frame()

    return at


def test_the_live_watcher_places_the_loads_with_the_scenario_and_hulls_without():
    s = scenario()
    formation_of = {r.id: r.formation for r in s.robots}
    where = moved(s, b_into_a=True)
    f = watcher(s)(where, formation_of)
    assert f == {**f, **LoadView(s).fields(f["robots"], f["obstacles"])}
    assert [(h["formation"], h["other"]) for h in f["load_hits"]] == [("A", "b1")]
    bare = watcher()(where, formation_of)
    assert {ld["formation"]: ld["declared"] for ld in bare["loads"]} == {"A": False, "B": False}
    assert bare["load_hits"] == []


@pytest.mark.integration
def test_the_page_draws_each_load_under_its_robots_and_a_red_line_for_an_overlap():
    require(chromium_path() is not None, "chromium", "chromium")
    s = scenario()
    frame = next(iter(frames_from_series(series_of(s, [moved(s, b_into_a=True)]), s)))
    hub = Hub(mode="live")
    hub.publish(frame)
    page = PageServer(hub)
    try:
        browser = Browser(page.url)
        try:
            browser.wait_for("window.viewer.seq >= 1 && window.viewer.hits.length == 1")
            browser.evaluate("window.viewerFreeze = true")
            browser.painted()
            shown = browser.evaluate("window.viewer")
            _png, rgb = browser.screenshot()
        finally:
            browser.close()
    finally:
        page.close()
    loads = {ld["formation"]: ld for ld in shown["loads"]}
    assert {k: v["declared"] for k, v in loads.items()} == {"A": True, "B": False}
    # A's box is tinted with A's colour where no robot stands (its centroid: a robot-free spot)
    a = loads["A"]
    patch = rgb[round(a["cy"]) - 3:round(a["cy"]) + 4, round(a["cx"]) - 3:round(a["cx"]) + 4]
    mean = patch.reshape(-1, 3).mean(axis=0)
    want = np.array(hex_rgb(a["color"]), dtype=float)
    white = np.array([255.0, 255.0, 255.0])
    assert np.linalg.norm(mean - want) < np.linalg.norm(white - want) - 40, (mean, a["color"])
    (hit,) = shown["hits"]
    assert (hit["formation"], hit["other"]) == ("A", "b1")
    # the line is red (#d00000, not the robot's #d62728) a quarter of the way from the load's
    # edge to the robot's centre, short of the robot's disc
    x = round(hit["ax"] + 0.25 * (hit["bx"] - hit["ax"]))
    y = round(hit["ay"] + 0.25 * (hit["by"] - hit["ay"]))
    r, g, b = (int(v) for v in rgb[y, x])
    assert r > 180 and g < 25 and b < 25, (hit, (r, g, b))
