"""Scenario validation: every invalid file fails before anything moves, with one line naming the
culprit and exit status 2 from the command line."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from formation.cli import main
from scenario import ScenarioError, load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "scenarios").glob("*.yaml")) + sorted((ROOT / "tests/scenarios").glob("*.yaml"))

BASE = {
    "name": "t",
    "dt": 0.05,
    "duration": 60.0,
    "robot": {"max_speed": 0.22, "radius": 0.105},
    "controller": {"kp": 2.0, "gamma": 1.0, "epsilon": 0.05},
    "formations": [
        {
            "name": "A",
            "leader": "a1",
            "robots": {
                "a1": {"start": [0.0, 0.0], "goal": [4.0, 0.0]},
                "a2": {"start": [0.5, 0.0], "goal": [4.5, 0.0]},
            },
            "edges": [["a1", "a2", 0.5]],
        }
    ],
    "obstacles": [{"name": "o1", "center": [2.0, 0.6], "safe_distance": 0.3}],
}


def variant(**changes):
    d = yaml.safe_load(yaml.safe_dump(BASE))
    for path, value in changes.items():
        node = d
        keys = path.split("__")
        for k in keys[:-1]:
            node = node[int(k)] if k.isdigit() else node[k]
        last = keys[-1]
        if value is DELETE:
            del node[last]
        else:
            node[int(last) if last.isdigit() else last] = value
    return yaml.safe_dump(d)


DELETE = object()

RECT4 = {
    "r1": {"start": [0.0, 0.25], "goal": [3.0, 0.25]},
    "r2": {"start": [0.5, 0.25], "goal": [3.5, 0.25]},
    "r3": {"start": [0.5, 0.0], "goal": [3.5, 0.0]},
    "r4": {"start": [0.0, 0.0], "goal": [3.0, 0.0]},
}

INVALID = [
    ("unknown top-level key", variant(colour="red"), "unknown key 'colour'"),
    ("unknown nested key", variant(robot__wheels=2), "robot: unknown key 'wheels'"),
    ("edge names an unknown robot", variant(formations__0__edges=[["a1", "a9", 0.5]]),
     "formations[0].edges[0]: unknown robot 'a9'"),
    ("non-rigid graph", variant(formations__0__robots=RECT4, formations__0__leader="r2",
                                formations__0__edges=[["r1", "r2"], ["r2", "r3"], ["r3", "r4"],
                                                      ["r2", "r4"]]),
     "formations[0].edges: the graph of formation 'A' is not rigid"),
    ("leader not adjacent to every member",
     variant(formations__0__robots=RECT4, formations__0__leader="r1",
             formations__0__edges=[["r1", "r2"], ["r1", "r4"], ["r2", "r3"], ["r2", "r4"],
                                   ["r3", "r4"]]),
     "formations[0].leader: 'r1' is not adjacent to 'r3'"),
    ("start outside the formation band", variant(formations__0__edges=[["a1", "a2", 0.7]]),
     "formations[0].edges[0]: start distance 0.500 m"),
    ("start inside an obstacle", variant(obstacles__0__center=[0.1, 0.1]),
     "obstacles[0]: robot 'a1' starts"),
    ("non-finite number", variant(dt=math.inf), "dt: must be finite"),
    ("NaN in a start", variant(formations__0__robots__a1__start=[math.nan, 0.0]),
     "formations[0].robots.a1.start[0]: must be finite"),
    ("non-positive safe distance", variant(obstacles__0__safe_distance=0.0),
     "obstacles[0].safe_distance: must be positive"),
    ("negative speed", variant(robot__max_speed=-0.2), "robot.max_speed: must be positive"),
    ("string where a number belongs", variant(controller__kp="fast"), "controller.kp: must be a number"),
    ("unknown robot model", variant(robot__model="tank"), "robot.model: 'tank'"),
    ("band lets bodies overlap", variant(formations__0__edges=[["a1", "a2", 0.25]],
                                         formations__0__robots__a2__start=[0.25, 0.0]),
     "Df - epsilon = 0.200 m lets the bodies"),
    ("missing formations", variant(formations=DELETE), "formations: missing"),
    ("goal that breaks the formation", variant(formations__0__robots__a2__goal=[5.0, 0.0]),
     "goal distance 1.000 m between 'a1' and 'a2'"),
    ("goal inside a static obstacle", variant(obstacles__0__center=[4.0, 0.1]),
     "the goal of robot 'a1' is inside the safe distance of obstacle 'o1'"),
    ("ellipse minor axis larger than major", variant(formations__0__ellipse={"a": 0.3, "b": 0.6}),
     "formations[0].ellipse: a=0.3"),
]


@pytest.mark.parametrize("what,text,message", INVALID, ids=[c[0] for c in INVALID])
def test_invalid_scenarios_are_refused_with_a_message_naming_the_culprit(what, text, message):
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_yaml_syntax_error_names_the_line():
    with pytest.raises(ScenarioError, match="YAML syntax error at line 3"):
        parse_scenario("name: x\nformations: [\n")


def test_start_inside_another_formations_ellipse_is_refused():
    d = yaml.safe_load(yaml.safe_dump(BASE))
    d["formations"].append({
        "name": "B", "leader": "b1",
        "robots": {"b1": {"start": [0.25, 0.3], "goal": [0.0, 3.0]},
                   "b2": {"start": [0.75, 0.3], "goal": [0.5, 3.0]}},
        "edges": [["b1", "b2"]],
    })
    with pytest.raises(ScenarioError, match="starts inside the ellipse of formation"):
        parse_scenario(yaml.safe_dump(d))


def test_omitted_df_is_the_start_distance_and_headings_default_towards_the_goal():
    s = parse_scenario(variant(formations__0__edges=[["a1", "a2"]]))
    assert s.formations[0].edges[0].df == pytest.approx(0.5)
    assert s.robots[0].start[2] == pytest.approx(0.0)
    assert s.formations[0].goal_centroid == pytest.approx((4.25, 0.0))


def test_gamma_may_be_split_by_kind():
    s = parse_scenario(variant(controller__gamma={"formation": 1.0, "obstacle": 0.5, "formations": 0.1}))
    assert (s.controller.gamma.formation, s.controller.gamma.obstacle, s.controller.gamma.formations) == (
        1.0, 0.5, 0.1)


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_every_shipped_scenario_is_valid(path):
    s = load_scenario(path)
    assert s.robots or (s.lifelong is not None and s.lifelong.fleet.robots)  # formations or a fleet


def test_check_command_exits_2_with_one_line_and_no_traceback(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(variant(formations__0__edges=[["a1", "ghost", 0.5]]))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown robot 'ghost'" in err[0] and "Traceback" not in err[0]


def test_sim_refuses_an_invalid_file_before_writing_anything(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(variant(dt=-1))
    out = tmp_path / "out"
    assert main(["sim", str(bad), "--out", str(out)]) == 2
    assert not out.exists()
    assert "dt: must be positive" in capsys.readouterr().err


def test_check_command_accepts_a_valid_file(capsys):
    assert main(["check", str(ROOT / "scenarios/warehouse.yaml")]) == 0
    assert "ok" in capsys.readouterr().out


def test_missing_file_is_invalid_input(tmp_path, capsys):
    assert main(["check", str(tmp_path / "nope.yaml")]) == 2
    assert "nope.yaml: no such file" in capsys.readouterr().err
