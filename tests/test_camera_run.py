"""`formation run --camera synthetic`: the world renders overhead frames, the camera service
detects the markers with OpenCV, and the agents drive on the detected poses."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pytest

from formation.cli import main

pytestmark = pytest.mark.integration  # starts processes, Zenoh routers, sshd or a browser

PAIR = textwrap.dedent("""
    name: camera-pair
    dt: 0.05
    duration: 30.0
    robot: {model: unicycle, max_speed: 0.22, lookahead: 0.05, radius: 0.105}
    controller: {kp: 2.0, gamma: 1.0, epsilon: 0.05}
    formations:
      - name: P
        leader: p1
        robots:
          p1: {start: [0.0, 0.25], goal: [1.2, 0.25]}
          p2: {start: [0.0, -0.25], goal: [1.2, -0.25]}
        edges: [[p1, p2]]
    obstacles:
      - {name: crate, center: [0.6, 1.0], safe_distance: 0.3}
""")


def test_agents_reach_their_goals_on_poses_detected_in_rendered_frames(tmp_path, capsys):
    scenario = tmp_path / "pair.yaml"
    scenario.write_text(PAIR)
    out_truth, out_cam = tmp_path / "truth", tmp_path / "cam"
    assert main(["run", str(scenario), "--out", str(out_truth), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(scenario), "--out", str(out_cam), "--quiet", "--no-plots",
                 "--camera", "synthetic"]) == 0
    truth = json.loads((out_truth / "summary.json").read_text())
    cam = json.loads((out_cam / "summary.json").read_text())
    assert cam["mode"] == "multiprocess" and cam["all_reached"] and cam["collisions"] == 0
    assert cam["formation_error_max_m"] <= 1.5 * 0.05
    # Sub-millimetre detection noise: the run takes about as long as on true poses.
    assert abs(cam["time_to_goal_s"] - truth["time_to_goal_s"]) <= 0.15 * truth["time_to_goal_s"]


def test_agents_reach_their_goals_on_poses_from_the_real_camera_process(tmp_path):
    """`formation run --camera process`: the world publishes rendered frames over Zenoh, the
    camera process (python -m camera_service) turns them into poses and obstacles (a moving cart
    tracked from its marker), and the agents drive on those."""
    scenario = Path(__file__).parent / "scenarios" / "two-pairs-camera.yaml"
    out_sim, out_cam = tmp_path / "sim", tmp_path / "cam"
    assert main(["sim", str(scenario), "--out", str(out_sim), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(scenario), "--out", str(out_cam), "--quiet", "--no-plots",
                 "--camera", "process"]) == 0
    sim = json.loads((out_sim / "summary.json").read_text())
    cam = json.loads((out_cam / "summary.json").read_text())
    assert cam["all_reached"] and cam["collisions"] == 0
    assert cam["formation_error_max_m"] <= 1.5 * 0.05
    stats = cam["camera_process"]
    assert stats["frames"] >= cam["steps"] - 1 and stats["wrong_size"] == 0
    assert all(n == stats["frames"] for n in stats["detections"].values())  # every robot, always
    assert stats["obstacle_frames"] == stats["frames"]  # the cart, tracked in every frame
    assert abs(cam["time_to_goal_s"] - sim["time_to_goal_s"]) <= 0.15 * sim["time_to_goal_s"]


def test_camera_dropouts_are_refused_with_the_camera_process_before_anything_starts(tmp_path,
                                                                                   capsys):
    scenario = Path(__file__).parent / "scenarios" / "two-pairs-camera.yaml"
    assert main(["run", str(scenario), "--out", str(tmp_path / "o"), "--camera", "process",
                 "--camera-dropout", "a1@1:1"]) == 2
    assert "--camera-dropout" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
