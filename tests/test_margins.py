"""The margins for the controller's declared bounds (agent.margins, controller.bounds, --bounds)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from agent import margins
from agent.barriers import Obstacle
from agent.config import build_agent_configs, config_from_dict, config_to_dict
from agent.control import Controller, ControlParams, StepInput
from agent.inputs import carry_pose
from formation.cli import main
from scenario import Bounds, ScenarioError, load_scenario
from scenario.bounds import matching, parse, with_bounds
from scenario.load import scenario_from_dict
from scenario.world import PROFILES, TURTLEBOT3_LAB
from tests.same_files import assert_same

ROOT = Path(__file__).resolve().parents[1]
TWO_SMALL = ROOT / "tests" / "scenarios" / "two-small.yaml"
LAB = PROFILES[TURTLEBOT3_LAB]
LAB_BOUNDS = Bounds(pose_noise=0.002, heading_noise=0.01, latency=0.1, motor_lag=0.1)

bound = st.floats(0.0, 0.5)
bounds = st.builds(Bounds, pose_noise=bound, heading_noise=bound, latency=bound, motor_lag=bound)


def test_without_bounds_every_margin_is_exactly_zero():
    b = Bounds()
    assert not b.declared
    assert margins.robot_margin(b, 0.22, 0.05) == 0.0
    assert margins.pair_margin(b, 0.44, 0.05) == 0.0
    assert margins.moving_obstacle_margin(b, 0.15) == 0.0
    assert margins.grown_axes(1.0, 0.5, 0.0) == (1.0, 0.5)
    assert margins.carried_age(0.3, b.latency) == 0.0
    p = ControlParams(unicycle=True)
    assert p.margin == 0.0 and p.pair_margin((0.2, 0.0), (-0.2, 0.0)) == 0.0


def test_the_margins_add_up_the_documented_terms():
    vmax, look = 0.22, 0.05
    noise = 3.0 * math.sqrt(2.0) * 0.002
    assert margins.position_noise(LAB_BOUNDS) == pytest.approx(noise)
    assert margins.heading_shift(LAB_BOUNDS, look) == pytest.approx(look * 3.0 * 0.01)
    assert margins.travel(LAB_BOUNDS, vmax) == pytest.approx(vmax * 0.2)
    assert margins.robot_margin(LAB_BOUNDS, vmax, look) == pytest.approx(noise + 0.0015 + 0.044)
    # a pair moving together keeps only both ends' noise; closing at 2 vmax, their travel too
    assert margins.pair_margin(LAB_BOUNDS, 0.0, look) == pytest.approx(2.0 * (noise + 0.0015))
    assert margins.pair_margin(LAB_BOUNDS, 2 * vmax, look) == pytest.approx(
        2.0 * (noise + 0.0015) + 2 * vmax * 0.2)
    assert margins.moving_obstacle_margin(LAB_BOUNDS, 0.15) == pytest.approx(noise + 0.15 * 0.1)


@settings(max_examples=200, deadline=None)
@given(bounds, st.floats(0.05, 2.0), st.floats(0.0, 0.5), st.floats(0.0, 4.0))
def test_every_margin_is_non_negative_and_grows_with_each_bound(b, vmax, look, rel):
    m = margins.robot_margin(b, vmax, look)
    assert m >= 0.0 and margins.pair_margin(b, rel, look) >= 0.0
    for name in ("pose_noise", "heading_noise", "latency", "motor_lag"):
        more = dataclasses.replace(b, **{name: getattr(b, name) + 0.1})
        assert margins.robot_margin(more, vmax, look) >= m
        assert margins.pair_margin(more, rel, look) >= margins.pair_margin(b, rel, look)


def test_the_noise_radius_holds_the_camera_noise_it_is_meant_to():
    rng = np.random.default_rng(5)
    err = rng.standard_normal((200_000, 2)) * LAB.pose_noise
    outside = np.mean(np.hypot(err[:, 0], err[:, 1]) > margins.position_noise(LAB_BOUNDS))
    assert outside < 5 * math.exp(-9.0)  # Rayleigh: exp(-9) = 1.2e-4 beyond 3 sqrt(2) sigma


@settings(max_examples=300, deadline=None)
@given(st.floats(0.05, 3.0), st.floats(0.05, 3.0), st.floats(0.0, 1.0), st.floats(0.0, 2 * math.pi))
def test_the_grown_ellipse_holds_every_point_within_the_margin_of_the_ellipse(a, b, m, t):
    ga, gb = margins.grown_axes(a, b, m)
    # a point of the ellipse and its outward normal: the margin's set's boundary lies at p + m n
    px, py = a * math.cos(t), b * math.sin(t)
    nx, ny = math.cos(t) / a, math.sin(t) / b
    k = math.hypot(nx, ny)
    qx, qy = px + m * nx / k, py + m * ny / k
    assert (qx / ga) ** 2 + (qy / gb) ** 2 <= 1.0 + 1e-9


def test_adding_the_margin_to_both_axes_would_fall_short_off_the_axes():
    a, b, m, t = 2.0, 0.5, 0.3, math.pi / 4  # why grown_axes scales instead
    px, py = a * math.cos(t), b * math.sin(t)
    nx, ny = math.cos(t) / a, math.sin(t) / b
    k = math.hypot(nx, ny)
    qx, qy = px + m * nx / k, py + m * ny / k
    assert (qx / (a + m)) ** 2 + (qy / (b + m)) ** 2 > 1.0


@settings(max_examples=200, deadline=None)
@given(st.floats(-1.0, 1.0), st.floats(0.0, 1.0))
def test_a_pose_is_carried_by_its_measured_age_never_beyond_the_latency(age, latency):
    carried = margins.carried_age(age, latency)
    assert 0.0 <= carried <= latency
    if 0.0 <= age <= latency:
        assert carried == age


def test_carry_pose_moves_the_body_under_the_last_command():
    assert carry_pose(1.0, 2.0, 0.3, 0.2, -0.1, 0.1, 0.0) == pytest.approx((1.02, 1.99, 0.3))
    # a unicycle driving straight ahead: the body moves along its heading, heading unchanged
    x, y, th = carry_pose(0.0, 0.0, math.pi / 2, 0.0, 0.2, 0.1, 0.05)
    assert (x, y, th) == pytest.approx((0.0, 0.02, math.pi / 2), abs=1e-9)
    assert carry_pose(1.0, 2.0, 0.3, 0.2, 0.2, 0.0, 0.05) == (1.0, 2.0, 0.3)


def _stop_distance(params: ControlParams) -> float:
    """A single integrator driving at a circle (Ds 0.5) on its goal's line: the closest it gets."""
    x, y, closest = 0.0, 0.0, math.inf
    obstacle = Obstacle(2.0, 0.0, 0.0, 0.0, 0.5)
    for _ in range(400):
        res = Controller(params).step(StepInput((x, y, 0.0), (4.0, 0.0), obstacles=[obstacle]))
        x, y = x + res.ux * params.period, y + res.uy * params.period
        closest = min(closest, math.hypot(x - 2.0, y))
    return closest


def test_an_obstacle_row_keeps_the_declared_margin_beyond_the_safe_distance():
    plain = ControlParams(tiebreak=False)
    kept = dataclasses.replace(plain, bounds=LAB_BOUNDS)
    assert _stop_distance(plain) >= 0.5 - 1e-6
    assert _stop_distance(kept) >= 0.5 + kept.margin - 1e-6
    assert _stop_distance(kept) > _stop_distance(plain) + 0.9 * kept.margin


def _with_bounds(raw) -> dict:
    d = yaml.safe_load(TWO_SMALL.read_text())
    d["controller"]["bounds"] = raw
    return d


def test_scenario_bounds_are_read_checked_and_default_to_none():
    assert load_scenario(TWO_SMALL).controller.bounds == Bounds()
    sc = scenario_from_dict(_with_bounds({"latency": 0.1, "motor_lag": 0.1}))
    assert sc.controller.bounds == Bounds(latency=0.1, motor_lag=0.1)
    with pytest.raises(ScenarioError, match="controller.bounds.latency: must be positive"):
        scenario_from_dict(_with_bounds({"latency": -1}))
    with pytest.raises(ScenarioError, match="controller.bounds: unknown key 'lag'"):
        scenario_from_dict(_with_bounds({"lag": 0.1}))
    with pytest.raises(ScenarioError, match="controller.bounds: must be a mapping"):
        scenario_from_dict(_with_bounds([0.1]))


def test_bounds_travel_in_each_agents_config_and_are_left_out_without_them():
    plain = build_agent_configs(load_scenario(TWO_SMALL))
    d = config_to_dict(next(iter(plain.values())))
    assert "bounds" not in d["control"]  # files stay as they were
    sc = with_bounds(load_scenario(TWO_SMALL), TURTLEBOT3_LAB)
    cfg = next(iter(build_agent_configs(sc).values()))
    assert cfg.control.bounds == matching(LAB, sc.dt) and cfg.control.bounds.declared
    d = config_to_dict(cfg)
    assert config_from_dict(d) == cfg
    d["control"]["bounds"]["motor_lag"] = -0.1
    with pytest.raises(ValueError, match="control.bounds.motor_lag"):
        config_from_dict(d)


def test_bounds_that_match_a_profile_count_its_camera_frames():
    b = matching(LAB, 0.05)
    assert (b.pose_noise, b.heading_noise, b.motor_lag) == (0.002, 0.01, 0.1)
    assert b.latency == pytest.approx(0.05 + 2 / 30)
    assert matching(PROFILES["ideal"], 0.05) == Bounds()
    assert parse("ideal", 0.05) == Bounds()
    assert parse("latency=0.02, motor_lag=0.01", 0.05) == Bounds(latency=0.02, motor_lag=0.01)


@pytest.mark.parametrize("spec, culprit", [
    ("nowhere", "'nowhere' is neither a world profile"),
    ("lag=0.1", "'lag=0.1' is neither"),
    ("latency=soon", "--bounds latency: must be a number"),
    ("latency=20", "--bounds latency: out of range"),
])
def test_a_bad_bounds_option_is_one_line_and_exit_2(tmp_path, capsys, spec, culprit):
    with pytest.raises(ScenarioError, match=culprit):
        parse(spec, 0.05)
    assert main(["sim", str(TWO_SMALL), "--out", str(tmp_path), "--quiet", "--bounds", spec]) == 2
    err = capsys.readouterr().err.strip()
    assert culprit in err and "\n" not in err and "Traceback" not in err


def test_the_band_narrows_by_the_pairs_margin_never_below_half_of_it():
    from agent.barriers import Neighbour
    from agent.control import ROW_TUNING, StepInput, build_rows

    plain = ControlParams(epsilon=0.04)
    kept = dataclasses.replace(plain, bounds=LAB_BOUNDS)
    edge = [Neighbour(0.5 + 0.9 * 0.04, 0.0, 0.0, 0.0, 0.5)]  # 0.9 epsilon out: inside the band
    assert build_rows(plain, (0.0, 0.0), 0.0, (0.0, 0.0), StepInput(neighbours=edge)).h_formation > 0.0
    # measured with both ends' noise (2 x 8.5 mm), the band the rows keep is that much narrower
    assert build_rows(kept, (0.0, 0.0), 0.0, (0.0, 0.0), StepInput(neighbours=edge)).h_formation < 0.0
    # closing fast, the narrowing stops at narrow_cap epsilon: the band is never empty
    fast = build_rows(kept, (0.0, 0.0), 0.0, (0.0, 0.0),
                      StepInput(neighbours=[Neighbour(0.5 + 0.4 * 0.04, 0.0, -0.22, 0.0, 0.5)],
                                last_u=(0.22, 0.0)))
    assert fast.h_formation > 0.0 and ROW_TUNING.narrow_cap < 1.0


def test_an_agent_carries_its_pose_by_its_measured_age_up_to_the_declared_latency():
    from agent.node import AgentNode, NodeOptions
    from wire.payloads import Pose

    sc = with_bounds(load_scenario(TWO_SMALL), TURTLEBOT3_LAB)
    cfg = build_agent_configs(sc)["a2"]
    node = AgentNode(cfg)  # real time
    node.ticker.last_u = (0.2, -0.1)
    pose = Pose(1.0, 2.0, 0.0, 100.0)
    carried, ahead = node.ticker.carried(pose, 100.05)
    assert ahead == pytest.approx(0.05)
    assert (carried.x, carried.y, carried.stamp) == pytest.approx((1.01, 1.995, 100.0))
    latency = cfg.control.bounds.latency
    assert node.ticker.carried(pose, 101.0)[1] == latency  # an older pose: no further than declared
    assert node.ticker.carried(pose, 99.0) == (pose, 0.0)  # a stamp ahead of the clock: as it came
    lockstep = AgentNode(cfg, NodeOptions(lockstep=True))
    lockstep.ticker.last_u = (0.2, -0.1)
    assert lockstep.ticker.carried(pose, 100.05) == (pose, 0.0)  # lock-step: every pose is its tick's
    plain = AgentNode(build_agent_configs(load_scenario(TWO_SMALL))["a2"])
    assert plain.ticker.carried(pose, 100.05) == (pose, 0.0)  # no bounds: as ever


def test_a_lockstep_run_with_bounds_equals_the_simulation_in_the_lab_world(tmp_path):
    common = ["--world", TURTLEBOT3_LAB, "--bounds", TURTLEBOT3_LAB, "--quiet", "--no-plots"]
    assert main(["sim", str(TWO_SMALL), "--out", str(tmp_path / "sim"), *common]) == 0
    assert main(["run", str(TWO_SMALL), "--out", str(tmp_path / "run"), "--insecure",
                 *common]) == 0
    sim = json.loads((tmp_path / "sim" / "summary.json").read_text())
    assert sim["all_reached"] and sim["collisions"] == 0
    assert_same(tmp_path / "sim" / "robots.csv", tmp_path / "run" / "robots.csv")
    # the bounds changed what the robots did: the same run without them differs
    assert main(["sim", str(TWO_SMALL), "--out", str(tmp_path / "plain"), *common[:2],
                 *common[4:]]) == 0
    assert (tmp_path / "plain" / "robots.csv").read_bytes() != \
        (tmp_path / "sim" / "robots.csv").read_bytes()
