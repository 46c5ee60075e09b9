"""The localisation's scenario keys: ``world.odometry``, ``world.camera_blind`` and
``controller.localisation`` parse, default to what every run had, and bad values are refused
naming the culprit."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from scenario import ScenarioError, load_scenario
from scenario.world import BlindBox, Odometry, blind_at, parse_world

BLIND = Path(__file__).parent / "scenarios" / "blind-aisle.yaml"


def test_defaults_are_the_camera_and_no_blind_floor():
    s = load_scenario(Path(__file__).parent / "scenarios" / "aisle-crate.yaml")
    assert s.controller.localisation == "camera"
    assert s.world.camera_blind == () and s.world.odometry.exact


def test_blind_aisle_parses():
    s = load_scenario(BLIND)
    assert s.controller.localisation == "fused"
    assert s.world.camera_blind == (BlindBox((0.0, 0.0), (3.5, 2.0), 0.0),)
    assert not s.world.odometry.exact  # the lab profile's odometry


def test_the_summary_leaves_the_localisation_keys_out():
    assert "odometry" not in parse_world({"profile": "turtlebot3-lab"}).summary()


def test_the_ideal_world_takes_odometry_and_blind_boxes():
    w = parse_world({"odometry": {"scale_error": 0.02},
                     "camera_blind": [{"box": {"center": [1, 2], "size": [2, 1]}}]})
    assert w.ideal and w.odometry == Odometry(0.02, 0.0)
    assert w.camera_blind[0].yaw == 0.0


def test_a_turned_box_contains_its_own_corner_region():
    box = BlindBox((0.0, 0.0), (4.0, 1.0), math.pi / 2)
    assert box.contains(0.0, 1.9) and not box.contains(1.9, 0.0)
    assert blind_at((box,), 0.4, -1.5) and not blind_at((box,), 0.6, 0.0)


@pytest.mark.parametrize("raw, culprit", [
    ({"odometry": {"scale_error": 0.5}}, "world.odometry.scale_error"),
    ({"odometry": {"drift": 0.1}}, "world.odometry: unknown key 'drift'"),
    ({"odometry": 3}, "world.odometry: must be a mapping"),
    ({"camera_blind": {"box": {}}}, "world.camera_blind: must be a list"),
    ({"camera_blind": [{"center": [0, 0]}]}, "world.camera_blind[0]: must be"),
    ({"camera_blind": [{"box": {"center": [0, 0], "size": [0, 1]}}]},
     "world.camera_blind[0].box.size[0]"),
    ({"camera_blind": [{"box": {"center": [0], "size": [1, 1]}}]},
     "world.camera_blind[0].box.center"),
    ({"camera_blind": [{"box": {"center": [0, 0], "size": [1, 1], "yaw": "x"}}]},
     "world.camera_blind[0].box.yaw"),
])
def test_bad_values_name_the_culprit(raw, culprit):
    with pytest.raises(ScenarioError, match=None) as err:
        parse_world(raw)
    assert culprit in str(err.value) and "\n" not in str(err.value)


def test_a_bad_localisation_is_refused(tmp_path: Path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(BLIND.read_text().replace("localisation: fused", "localisation: gps"))
    with pytest.raises(ScenarioError, match="controller.localisation"):
        load_scenario(bad)


def test_formation_run_refuses_fused_with_pose_slots_before_starting_anything(tmp_path, capsys):
    from formation.cli import main

    assert main(["run", str(BLIND), "--out", str(tmp_path / "o"), "--quiet", "--realtime",
                 "--pose-slots", "2", "--world", "ideal"]) == 2
    err = capsys.readouterr().err
    assert "--pose-slots" in err and "fused" in err and err.count("\n") == 1
