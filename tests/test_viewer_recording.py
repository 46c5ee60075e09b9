"""``run.mcap``: every simulation's recording, read back with the ``mcap`` reader."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader

from formation.cli import main
from viewer.frame import formation_status, frames_from_series
from viewer.record import FLEET_TOPIC, LOG_TOPIC, RENDERED_SCHEMAS, SCENE_TOPIC, status_logs

ROOT = Path(__file__).resolve().parent.parent


def read_mcap(path: Path) -> dict[str, list]:
    """topic -> [(log_time_ns, schema name, schema encoding, message encoding, data)]"""
    out: dict[str, list] = {}
    with path.open("rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append(
                (message.log_time, schema.name, schema.encoding, channel.message_encoding,
                 message.data))
    return out


def assert_renderable(messages: dict[str, list]) -> None:
    """Only schemas Foxglove and Lichtblick render: their own protobuf schemas, or JSON with a
    JSON schema."""
    for topic, rows in messages.items():
        for _t, name, schema_enc, msg_enc, _data in rows[:1]:
            assert (name in RENDERED_SCHEMAS and schema_enc == "protobuf" and msg_enc == "protobuf") \
                or (schema_enc == "jsonschema" and msg_enc == "json"), topic


def check_recording(out: Path) -> dict[str, list]:
    """The checks every run's recording passes; returns its messages."""
    summary = json.loads((out / "summary.json").read_text())
    messages = read_mcap(out / "run.mcap")
    assert {SCENE_TOPIC, FLEET_TOPIC} <= set(messages)
    assert_renderable(messages)
    with (out / "robots.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    ticks = sorted({float(r["t"]) for r in rows})
    # one scene (and one fleet frame) per tick, at the tick's simulated time
    assert len(messages[SCENE_TOPIC]) == summary["steps"] == len(ticks)
    assert [m[0] for m in messages[SCENE_TOPIC]] == [round(t * 1e9) for t in ticks]
    assert [m[0] for m in messages[FLEET_TOPIC]] == [m[0] for m in messages[SCENE_TOPIC]]
    # the fleet frames hold what robots.csv holds
    last = json.loads(messages[FLEET_TOPIC][-1][4])
    final = {r["robot"]: r for r in rows if float(r["t"]) == ticks[-1]}
    assert {r["id"] for r in last["robots"]} == set(final)
    for r in last["robots"]:
        assert r["x"] == pytest.approx(float(final[r["id"]]["x"]), abs=1e-5)
        assert r["ux"] == pytest.approx(float(final[r["id"]]["ux"]), abs=1e-5)
    end = round(summary["sim_time_s"] * 1e9)
    for t, *_ in messages.get(LOG_TOPIC, []):
        assert 0 <= t <= end
    return messages


@pytest.mark.integration
def test_a_simulation_records_every_tick_its_scene_fleet_and_the_relaxed_rows_as_logs(tmp_path):
    out = tmp_path / "sim"
    # thesis 5.1.1 under the plain thesis method relaxes its formation rows for a few ticks near
    # the obstacles (the default rigid motion keeps the band without)
    doc = yaml.safe_load((ROOT / "scenarios" / "thesis-5.1.1.yaml").read_text())
    doc["controller"]["method"] = "thesis"
    path = tmp_path / "thesis-5.1.1-plain.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert main(["sim", str(path), "--out", str(out), "--quiet", "--no-plots"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["qp"]["relaxed"] > 0
    messages = check_recording(out)
    assert any(b"formation rows relaxed" in m[4] for m in messages[LOG_TOPIC])
    relaxed_ticks = {m[0] for m in messages[LOG_TOPIC] if b"relaxed" in m[4]}
    fleet_relaxed = {m[0] for m in messages[FLEET_TOPIC]
                     if any(r["status"] == "relaxed" for r in json.loads(m[4])["robots"])}
    # every relaxation onset is logged at a tick where a robot was relaxed
    assert relaxed_ticks & fleet_relaxed
    # the scene draws every robot, ellipse and obstacle
    scene = messages[SCENE_TOPIC][0][4]
    for name in (b"robot/r1", b"ellipse/", b"obstacle/"):
        assert name in scene


def test_status_logs_mark_the_onset_and_the_end_of_each_relaxation():
    def frame(t, status):
        return {"t": t, "robots": [{"id": "a", "status": status, "slack": 0.01}]}

    logs = list(status_logs([frame(0.0, "ok"), frame(0.1, "relaxed"), frame(0.2, "relaxed"),
                             frame(0.3, "ok"), frame(0.4, "stale")]))
    assert [(t, level) for t, level, _n, _m in logs] == [
        (0.1, "warning"), (0.3, "info"), (0.4, "warning")]
    assert "2 ticks" in logs[1][3]


def test_a_formation_is_reached_stopped_or_moving_by_its_members():
    def robot(x, ux, status="ok"):
        return {"id": "r", "formation": "A", "x": x, "y": 0.0, "gx": 1.0, "gy": 0.0,
                "ux": ux, "uy": 0.0, "v": 0.0, "status": status}

    assert formation_status("A", [robot(1.0, 0.0)], 0.05)["status"] == "reached"
    assert formation_status("A", [robot(0.0, 0.0, "stale")], 0.05)["status"] == "stopped"
    moving = formation_status("A", [robot(0.0, 0.2), robot(0.5, 0.2, "relaxed")], 0.05)
    assert moving["status"] == "moving" and moving["qp"] == "relaxed"
    assert moving["distance"] == pytest.approx(0.75)


def test_frames_from_an_empty_series_are_none():
    from scenario import load_scenario
    from simulator.inprocess import Series

    s = load_scenario(ROOT / "tests" / "scenarios" / "two-small.yaml")
    assert list(frames_from_series(Series(), s)) == []


def _watcher():
    """A FleetWatcher on a session stub, and ``put(key, payload)`` feeding it as Zenoh would."""
    from types import SimpleNamespace

    from viewer.live import FleetWatcher

    class Session:
        def declare_subscriber(self, key, handler):
            return SimpleNamespace(undeclare=lambda: None)

    w = FleetWatcher(Session())

    def put(key: str, data: bytes) -> None:
        w.on_sample(SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: data)))

    return w, put


def test_the_fleet_watcher_drops_and_counts_malformed_messages_and_builds_frames_from_the_rest():
    import math

    from wire.diag import Diag, encode_diag
    from wire.payloads import Cmd, Pose, State, encode

    w, put = _watcher()
    assert w.frame() is None
    put("warehouse/robot/a1/pose", encode(Pose(1.0, 2.0, 0.5, 10.0)))
    put("warehouse/robot/a1/state", encode(State(1.0, 2.0, 0.1, 0.0, 10.0)))
    put("warehouse/robot/a1/cmd", encode(Cmd(0.1, 0.0, 0.1, 0.0, 10.0)))
    put("warehouse/robot/a1/diag", encode_diag(Diag("A", "relaxed", 10.0, 0.02, 0.01, math.inf,
                                                    2.0, 3.0, 2.0, 200, 0, 4, 0, 0)))
    put("warehouse/robot/a2/pose", b"\x01garbage")
    put("warehouse/robot/a1/diag-not", b"ignored")
    put("other/robot/a3/pose", encode(Pose(0.0, 0.0, 0.0, 99.0)))
    f = w.frame()
    assert f["t"] == 10.0
    (r,) = f["robots"]
    assert (r["id"], r["formation"], r["status"], r["x"], r["ux"]) == ("a1", "A", "relaxed", 1.0, 0.1)
    assert r["h_obstacle"] is None and r["h_formation"] == 0.01 and (r["gx"], r["gy"]) == (3.0, 2.0)
    assert f["formations"][0]["qp"] == "relaxed"
    assert w.rejected == {"pose": 1}
    put("warehouse/robot/a1/diag", b"\x01\x01")
    assert w.frame()["robots"][0]["formation"] == "A"  # the last good diagnostics stay
    assert w.rejected == {"pose": 1, "diag": 1}


def test_the_fleet_watcher_shows_each_leaders_status_and_planned_route():
    from wire.diag import Diag, encode_diag
    from wire.navigation import PlanMsg, StatusMsg, encode_nav
    from wire.payloads import Pose, encode

    w, put = _watcher()
    for rid, form in (("a1", "A"), ("b1", "B")):
        put(f"warehouse/robot/{rid}/pose", encode(Pose(0.0, 0.0, 0.0, 5.0)))
        put(f"warehouse/robot/{rid}/diag", encode_diag(Diag(form, "ok", 5.0, 0.0, 0.01, 0.2, 0.3,
                                                            9.0, 9.0, 100, 0, 0, 0, 0)))
    put("warehouse/formation/A/status", encode_nav(StatusMsg(
        "A", "stalled", "a1", 1.0, 4.0, 2.0, None, 7.5, 1, 3, 2.0, 0.0, 5.0)))
    put("warehouse/formation/A/plan", encode_nav(PlanMsg(
        "A", 1.0, 0.0, 0.0, None, ((2.0, 0.0), (2.0, 2.0), (4.0, 2.0)), (("a1", 4.0, 2.0),), 5.0)))
    # a status about another formation under A's key is not A's report
    put("warehouse/formation/B/status", encode_nav(StatusMsg(
        "A", "reached", "b1", 1.0, 0.0, 0.0, None, 0.0, 0, 0, 0.0, 0.0, 5.0)))
    put("warehouse/formation/B/plan", b"\x01garbage")
    f = w.frame()
    rows = {fm["name"]: fm for fm in f["formations"]}
    assert (rows["A"]["status"], rows["A"]["distance"], rows["A"]["waypoint"], rows["A"]["leader"]) \
        == ("stalled", 7.5, "1/3", "a1")
    assert (rows["A"]["gx"], rows["A"]["gy"]) == (4.0, 2.0)
    assert rows["B"]["leader"] is None and rows["B"]["status"] == "stopped"  # from its members
    assert f["routes"] == [{"formation": "A", "points": [[2.0, 0.0], [2.0, 2.0], [4.0, 2.0]]}]
    assert w.rejected == {"plan": 1}


def test_the_fleet_watcher_shows_the_goals_a_leader_refused_and_why():
    from wire.diag import Diag, encode_diag
    from wire.navigation import StatusMsg, encode_nav
    from wire.payloads import Pose, encode

    w, put = _watcher()
    put("warehouse/robot/a1/pose", encode(Pose(0.0, 0.0, 0.0, 5.0)))
    put("warehouse/robot/a1/diag", encode_diag(Diag("A", "ok", 5.0, 0.0, 0.01, 0.2, 0.3,
                                                    9.0, 9.0, 100, 0, 0, 0, 0)))
    assert w.frame()["formations"][0]["refused"] is None  # no report yet
    why = "goal (5000, 5000) is outside the world (x -100..104 m, y -100..102 m)"
    put("warehouse/formation/A/status", encode_nav(StatusMsg(
        "A", "unreachable", "a1", 1.0, 4.0, 2.0, None, 7.5, 0, 1, 4.0, 2.0, 5.0,
        reason="no route: the goal lies inside a closed room", refused=2, refusal=why)))
    (row,) = w.frame()["formations"]
    assert (row["status"], row["reason"], row["refused"], row["refusal"]) == (
        "unreachable", "no route: the goal lies inside a closed room", 2, why)


@pytest.mark.integration
def test_walls_and_shelves_are_in_every_fleet_frame_and_drawn_in_the_scene(tmp_path):
    out = tmp_path / "sim"
    assert main(["sim", str(ROOT / "tests" / "scenarios" / "nav-behind-shelf.yaml"), "--out", str(out),
                 "--quiet", "--no-plots"]) == 0
    messages = check_recording(out)
    frame = json.loads(messages[FLEET_TOPIC][0][4])
    shapes = {s["name"]: s for s in frame["shapes"]}
    assert shapes["shelf"]["kind"] == "box" and len(shapes["shelf"]["corners"]) == 4
    assert sorted(map(tuple, shapes["shelf"]["corners"])) == [(1.85, -1.5), (1.85, 1.5), (2.65, -1.5),
                                                            (2.65, 1.5)]
    assert shapes["wall-s"]["corners"] == [[-1.0, -2.5], [6.0, -2.5]]
    scene = messages[SCENE_TOPIC][0][4]
    assert b"shape/shelf" in scene and b"shape/wall-s" in scene
