"""The lab world (simulator.lab, scenario.world): wheels with limits and lag, a late, noisy camera
that drops frames, seeded so that every simulator sees the same world."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st

from agent.unicycle import integrate, to_unicycle
from experiments.montecarlo import run_one
from formation.cli import main
from scenario import ScenarioError, load_scenario, parse_scenario
from scenario.load import scenario_from_dict
from scenario.model import ObstacleSpec, with_world
from scenario.world import IDEAL, PROFILES, TURTLEBOT3_LAB, WorldSpec, parse_world
from simulator.inprocess import SimOptions, simulate
from simulator.lab import REVERSE_ENTER, REVERSE_LEAVE, Camera, LabWorld, command_rates, drive, wheel_step
from tests.same_files import assert_same

ROOT = Path(__file__).resolve().parent.parent
TWO_SMALL = ROOT / "tests" / "scenarios" / "two-small.yaml"
LAB = PROFILES[TURTLEBOT3_LAB]


def _with_world(path: Path, tmp_path: Path, world: dict) -> Path:
    d = yaml.safe_load(path.read_text())
    d["world"] = world
    out = tmp_path / path.name
    out.write_text(yaml.safe_dump(d, sort_keys=False))
    return out


# --- the scenario's world: section --------------------------------------------------------------

def test_the_world_section_defaults_to_ideal_and_overrides_a_profiles_numbers():
    assert load_scenario(TWO_SMALL).world == WorldSpec() and WorldSpec().ideal
    spec = parse_world({"profile": TURTLEBOT3_LAB, "drop_rate": 0.1, "seed": 9})
    assert spec.profile == TURTLEBOT3_LAB and spec.drop_rate == 0.1 and spec.seed == 9
    assert spec.motor_lag == LAB.motor_lag and spec.camera_fps == LAB.camera_fps
    assert parse_world({"seed": 3}) == WorldSpec(seed=3)


@pytest.mark.parametrize("raw, culprit", [
    ({"profile": "mars"}, "world.profile: unknown world profile"),
    ({"profile": TURTLEBOT3_LAB, "drop_rate": 1.5}, "world.drop_rate: out of range"),
    # the scenario's own number check (scenario.limits), so the same words as the rest of the file
    ({"profile": TURTLEBOT3_LAB, "motor_lag": float("nan")}, "world.motor_lag: must be finite"),
    ({"profile": TURTLEBOT3_LAB, "max_wheel_speed": float("inf")},
     "world.max_wheel_speed: must be finite"),
    ({"profile": TURTLEBOT3_LAB, "track": -0.1},
     r"world.track: must be positive, got -0.1 \(allowed: greater than 0 and at most 5 m\)"),
    ({"profile": TURTLEBOT3_LAB, "motor_lag": 11}, r"world.motor_lag: out of range, got 11"),
    ({"profile": TURTLEBOT3_LAB, "pose_noise": "big"}, "world.pose_noise: must be a number"),
    ({"profile": TURTLEBOT3_LAB, "seed": -1}, "world.seed: must be an integer"),
    ({"profile": TURTLEBOT3_LAB, "gravity": 9.8}, "world: unknown key"),
    ({"pose_noise": 0.01}, "world: the ideal world has no pose_noise"),
    ([1, 2], "world: must be a mapping"),
])
def test_a_bad_world_section_is_one_error_naming_it(raw, culprit):
    text = TWO_SMALL.read_text() + "\n" + yaml.safe_dump({"world": raw})
    with pytest.raises(ScenarioError, match=culprit):
        parse_scenario(text)


def test_world_option_replaces_the_profile_and_keeps_the_seed():
    sc = parse_scenario(TWO_SMALL.read_text() + "\nworld: {seed: 4}\n")
    lab = with_world(sc, TURTLEBOT3_LAB)
    assert lab.world == dataclasses.replace(LAB, seed=4)
    assert with_world(lab, TURTLEBOT3_LAB) is lab or with_world(lab, TURTLEBOT3_LAB).world == lab.world
    assert with_world(lab, IDEAL).world == WorldSpec(seed=4)
    assert with_world(sc, None) is sc


def test_an_unknown_world_on_the_command_line_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:  # argparse's choices
        main(["sim", str(TWO_SMALL), "--out", str(tmp_path / "o"), "--world", "mars"])
    assert exc.value.code == 2
    assert "--world" in capsys.readouterr().err


# --- actuators ----------------------------------------------------------------------------------

speeds = st.floats(-1.0, 1.0)


@settings(max_examples=300, deadline=None)
@given(w=speeds, target=speeds, lag=st.floats(0.0, 0.5), accel=st.floats(0.1, 10.0),
       cap=st.floats(0.05, 0.5), h=st.floats(1e-4, 0.05))
def test_a_wheel_moves_towards_its_clipped_target_within_its_acceleration(w, target, lag, accel,
                                                                          cap, h):
    spec = dataclasses.replace(LAB, motor_lag=lag, max_wheel_accel=accel, max_wheel_speed=cap)
    w = max(-cap, min(cap, w))  # a wheel that was within its limit
    new = wheel_step(w, target, spec, h)
    goal = max(-cap, min(cap, target))
    assert abs(new - w) <= accel * h + 1e-12  # the acceleration limit
    assert abs(new) <= cap + 1e-12  # the speed limit
    assert min(w, goal) - 1e-12 <= new <= max(w, goal) + 1e-12  # towards the target, no overshoot


@settings(max_examples=200, deadline=None)
@given(v=st.floats(-0.3, 0.3), omega=st.floats(-3.0, 3.0), th=st.floats(-math.pi, math.pi),
       dt=st.floats(0.01, 0.1))
@example(v=0.25, omega=1.1e-8, th=1.0, dt=0.0625)  # the arc's two sines cancelled: 2e-8 m off
def test_wheels_without_limits_or_lag_are_the_unicycle(v, omega, th, dt):
    spec = WorldSpec(profile=TURTLEBOT3_LAB)  # every limit inf, no lag
    pose, wheels = drive((1.0, -2.0, th), (0.0, 0.0), (v, omega), spec, dt)
    want = integrate(1.0, -2.0, th, v, omega, dt)
    assert pose == pytest.approx(want, abs=1e-9)
    assert wheels == pytest.approx((v - 0.08 * omega, v + 0.08 * omega))


def test_a_step_command_reaches_63_percent_after_one_time_constant():
    spec = dataclasses.replace(LAB, max_wheel_accel=math.inf)
    wheels = (0.0, 0.0)
    for _ in range(round(spec.motor_lag / 0.01)):
        _pose, wheels = drive((0.0, 0.0, 0.0), wheels, (0.1, 0.0), spec, 0.01)
    assert wheels[0] == pytest.approx(0.1 * (1 - math.exp(-1.0)), rel=1e-6)
    # with the profile's numbers the lag binds first (max_wheel_speed / motor_lag is less than
    # max_wheel_accel); without the lag the acceleration limit bounds the ramp, and a step beyond
    # the speed limit saturates there
    assert LAB.max_wheel_speed / LAB.motor_lag < LAB.max_wheel_accel
    spec = dataclasses.replace(LAB, motor_lag=0.0)
    wheels = (0.0, 0.0)
    _pose, wheels = drive((0.0, 0.0, 0.0), wheels, (5.0, 0.0), spec, 0.01)
    assert wheels[0] == pytest.approx(LAB.max_wheel_accel * 0.01)
    for _ in range(500):
        _pose, wheels = drive((0.0, 0.0, 0.0), wheels, (5.0, 0.0), spec, 0.01)
    assert wheels == (LAB.max_wheel_speed, LAB.max_wheel_speed)


def test_a_single_integrator_drives_its_wheels_through_the_lookahead_map():
    # velocity along the heading: straight on; across it: a turn of |u| / l
    assert command_rates((0.2, 0.0, 0.0, 0.0), 0.0, False, 0.05) == pytest.approx((0.2, 0.0, False))
    assert command_rates((0.0, 0.1, 0.0, 0.0), 0.0, False, 0.05) == pytest.approx((0.0, 2.0, False))
    assert command_rates((9.0, 9.0, 0.1, 0.5), 0.0, True, 0.05) == (0.1, 0.5, False)
    assert command_rates(None, 0.0, True, 0.05) == (0.0, 0.0, False)


@given(st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi), st.floats(0.01, 0.3),
       st.booleans())
def test_a_single_integrators_control_point_moves_at_its_command_ahead_or_behind(
        theta, angle, speed, backwards):
    # eq. 6.2 exactly, for the point l ahead of the body or, driving backwards, l behind it
    ux, uy = speed * math.cos(angle), speed * math.sin(angle)
    v, omega, back = command_rates((ux, uy, 0.0, 0.0), theta, False, 0.05, backwards)
    off = (theta - angle + math.pi) % (2 * math.pi) - math.pi
    if abs(off) > REVERSE_ENTER + 1e-9:
        assert back
    elif abs(off) < REVERSE_LEAVE - 1e-9:
        assert not back
    else:
        assert back == backwards  # between the two: it keeps its way (the hysteresis)
    point = 0.05 * (-1.0 if back else 1.0)
    moved = (v * math.cos(theta) - point * omega * math.sin(theta),
             v * math.sin(theta) + point * omega * math.cos(theta))
    assert moved == pytest.approx((ux, uy), abs=1e-9)


def test_a_single_integrator_sent_backwards_backs_up_its_body_without_turning_round():
    # facing +x, asked to move -x with a little sideways: under eq. 6.2's point ahead alone the
    # robot turns round in place, its body swinging 2 l; the firmware backs up instead
    spec = dataclasses.replace(LAB, motor_lag=0.0)
    pose, wheels, back = (0.0, 0.0, 0.0), (0.0, 0.0), False
    for _ in range(100):  # 5 s at 0.05 s
        v, omega, back = command_rates((-0.1, 0.005, 0.0, 0.0), pose[2], False, 0.05, back)
        pose, wheels = drive(pose, wheels, (v, omega), spec, 0.05)
    assert back
    assert abs(pose[2]) < 0.2  # still facing +x
    assert pose[0] == pytest.approx(-0.5, abs=0.03)  # the body came 0.5 m back
    pose, wheels = (0.0, 0.0, 0.0), (0.0, 0.0)
    for _ in range(100):
        v, omega = to_unicycle(-0.1, 0.005, pose[2], 0.05)
        pose, wheels = drive(pose, wheels, (v, omega), spec, 0.05)
    assert abs(math.cos(pose[2]) + 1.0) < 0.05  # the point ahead alone: turned round


# --- sensing ------------------------------------------------------------------------------------

def _camera(spec: WorldSpec, starts, obstacles=()) -> Camera:
    return Camera(spec, 0.05, starts, obstacles)


def test_pose_noise_has_the_profiles_mean_and_spread_and_frames_drop_at_its_rate():
    starts = [(1.0, 2.0, 0.5), (-3.0, 0.0, -1.0)]
    cam = _camera(LAB, starts)
    frames = range(5000)
    lost = sum(cam.frame(f).lost for f in frames)
    assert lost / 5000 == pytest.approx(LAB.drop_rate, abs=0.01)
    noise = np.array([cam.frame(f).robots for f in frames])  # (frames, robots, 3)
    err = noise.reshape(-1, 3)
    n = len(err)
    for axis, sd in ((0, LAB.pose_noise), (1, LAB.pose_noise), (2, LAB.heading_noise)):
        assert abs(err[:, axis].mean()) < 4 * sd / math.sqrt(n)
        assert err[:, axis].std() == pytest.approx(sd, rel=0.05)
    # what the robots are handed is the truth plus that noise (standing robots)
    seen = np.array([cam.poses(k * 0.05) for k in range(2000)]) - np.array(starts)
    assert seen[:, :, :2].std() == pytest.approx(LAB.pose_noise, rel=0.1)
    assert np.abs(seen[:, :, :2]).max() < 8 * LAB.pose_noise


def test_the_draws_depend_on_the_seed_and_the_frame_only():
    starts = [(0.0, 0.0, 0.0)] * 3
    a, b = _camera(LAB, starts), _camera(LAB, starts)
    forward = [a.poses(k * 0.05) for k in range(200)]
    backward = [b.poses(k * 0.05) for k in reversed(range(200))][::-1]
    assert forward == backward
    other = _camera(dataclasses.replace(LAB, seed=1), starts)
    assert [other.poses(k * 0.05) for k in range(200)] != forward


def test_a_moving_robot_and_obstacle_are_seen_where_they_were_a_latency_ago():
    spec = dataclasses.replace(LAB, pose_noise=0.0, heading_noise=0.0, drop_rate=0.0,
                               camera_fps=30.0, camera_latency=0.05)
    forklift = ObstacleSpec("forklift", (0.0, 5.0), 0.4, (0.2, 0.0))
    shelf = ObstacleSpec("shelf", (3.0, 3.0), 0.3)
    cam = _camera(spec, [(0.0, 0.0, 0.0)], [forklift, shelf])
    for k in range(100):
        t = k * 0.05
        cam.record(k, [(0.1 * t, 0.0, 0.0)])  # 0.1 m/s along x
        frame_t = max(0.0, math.floor((t - 0.05) * 30.0 + 1e-9) / 30.0)
        assert cam.poses(t)[0][0] == pytest.approx(0.1 * frame_t, abs=1e-12)
        xy = cam.obstacle_positions(t)
        assert xy[0] == pytest.approx((0.2 * math.floor((t - 0.05) * 30.0 + 1e-9) / 30.0, 5.0))
        assert xy[1] == (3.0, 3.0)  # a static obstacle is the map's


def test_a_lost_frame_hands_the_robots_the_last_frame_that_came():
    spec = dataclasses.replace(LAB, drop_rate=0.5, camera_fps=20.0, camera_latency=0.0)
    cam = _camera(spec, [(0.0, 0.0, 0.0)])
    for k in range(200):
        cam.record(k, [(0.01 * k, 0.0, 0.0)])
        f = cam.latest_frame(k * 0.05)
        assert f <= k and not cam.frame(f).lost
        assert all(cam.frame(g).lost for g in range(f + 1, k + 1))


# --- whole runs ---------------------------------------------------------------------------------

def test_single_integrators_on_differential_drives_are_warned_of_once(tmp_path, capsys):
    # a lab world's robots are differential drives: a single integrator's body centre moves only
    # along its heading there (eq. 6.2), which its rows do not know (docs/physics.md)
    lab = _with_world(TWO_SMALL, tmp_path, {"profile": TURTLEBOT3_LAB})
    assert main(["check", str(lab)]) == 0
    err = capsys.readouterr().err
    assert err.count("warning: robot.model: single_integrator on the differential drives of "
                     "world profile 'turtlebot3-lab'") == 1, err
    d = yaml.safe_load(lab.read_text())
    d["robot"]["model"] = "unicycle"
    unicycles = tmp_path / "uni.yaml"
    unicycles.write_text(yaml.safe_dump(d, sort_keys=False))
    assert load_scenario(unicycles).robot.is_unicycle
    assert main(["check", str(unicycles)]) == 0 and "warning" not in capsys.readouterr().err
    assert main(["check", str(TWO_SMALL)]) == 0 and "warning" not in capsys.readouterr().err
    # the command line's world: said before the run
    assert main(["sim", str(TWO_SMALL), "--out", str(tmp_path / "o"), "--quiet", "--no-plots",
                 "--world", TURTLEBOT3_LAB]) == 0
    assert "single_integrator on the differential drives" in capsys.readouterr().err


def test_an_ideal_world_section_changes_nothing(tmp_path):
    ideal = _with_world(TWO_SMALL, tmp_path, {"profile": "ideal", "seed": 5})
    assert main(["sim", str(TWO_SMALL), "--out", str(tmp_path / "a"), "--quiet", "--no-plots"]) == 0
    assert main(["sim", str(ideal), "--out", str(tmp_path / "b"), "--quiet", "--no-plots"]) == 0
    assert_same(tmp_path / "a" / "robots.csv", tmp_path / "b" / "robots.csv")


def test_the_lab_world_changes_the_run_and_the_summary_says_which_world_it_was(tmp_path):
    assert main(["sim", str(TWO_SMALL), "--out", str(tmp_path / "a"), "--quiet", "--no-plots",
                 "--world", TURTLEBOT3_LAB]) == 0
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["world_profile"]["profile"] == TURTLEBOT3_LAB
    assert summary["world_profile"]["camera_fps"] == LAB.camera_fps
    assert summary["all_reached"] and summary["collisions"] == 0
    ideal = simulate(load_scenario(TWO_SMALL), SimOptions(record=False)).summary
    assert summary["time_to_goal_s"] != ideal["time_to_goal_s"]
    assert ideal["world_profile"]["profile"] == IDEAL
    assert ideal["world_profile"]["max_wheel_speed"] is None


def test_a_lockstep_run_equals_the_simulation_in_the_lab_world(tmp_path):
    lab = _with_world(TWO_SMALL, tmp_path, {"profile": TURTLEBOT3_LAB, "seed": 7})
    assert main(["sim", str(lab), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(lab), "--out", str(tmp_path / "run"), "--quiet", "--no-plots",
                 "--insecure"]) == 0
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["world_profile"]["profile"] == TURTLEBOT3_LAB and run["world_profile"]["seed"] == 7
    assert_same(tmp_path / "sim" / "robots.csv", tmp_path / "run" / "robots.csv")


def test_a_montecarlo_run_in_the_lab_world_replays_from_its_scenario_file():
    r = run_one(3, TURTLEBOT3_LAB)
    assert r["scenario"]["world"] == {"profile": TURTLEBOT3_LAB, "seed": 3}
    again = simulate(scenario_from_dict(r["scenario"]), SimOptions(record=False)).summary
    assert again["formation_error_max_m"] == r["formation_error_max_m"]
    assert again["time_to_goal_s"] == r["time_to_goal_s"]
    assert again["collisions"] == r["collisions"]


def test_a_lab_world_has_no_pose_slots():
    from simulator.world import WorldOptions, lab_world

    sc = with_world(load_scenario(TWO_SMALL), TURTLEBOT3_LAB)
    with pytest.raises(ValueError, match="pose_slots"):
        lab_world(sc, WorldOptions(realtime=True, pose_slots=4))
    assert isinstance(lab_world(sc, WorldOptions()), LabWorld)
    assert lab_world(load_scenario(TWO_SMALL), WorldOptions()) is None


def test_the_docs_list_every_world_setting_and_its_range():
    from scenario.world import describe

    assert describe() in (ROOT / "docs" / "scenarios.md").read_text(encoding="utf-8")


def test_run_takes_world_too_and_refuses_pose_slots_in_a_lab_world(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", str(TWO_SMALL), "--out", str(out), "--realtime", "--pose-slots", "2",
                 "--world", TURTLEBOT3_LAB]) == 2
    assert "--pose-slots" in capsys.readouterr().err
    assert not (out / "processes.json").exists()
