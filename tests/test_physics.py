"""MuJoCo as a second opinion (simulator.physics): TurtleBot3 bodies on wheels, contacts counted."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from formation.cli import main
from scenario import parse_scenario
from scenario.world import PROFILES, TURTLEBOT3_LAB

mujoco = pytest.importorskip("mujoco")  # the physics extra (make test installs it)

from simulator.physics import MOTOR_LAG, XL430_SPEED, MujocoWorld, world_for  # noqa: E402
from tests.same_files import assert_same  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TWO_SMALL = ROOT / "tests" / "scenarios" / "two-small.yaml"
R = PROFILES[TURTLEBOT3_LAB].wheel_radius


def _one(model: str = "unicycle", obstacles: str = "") -> MujocoWorld:
    return MujocoWorld(parse_scenario(f"""
name: one
dt: 0.05
robot: {{model: {model}}}
formations:
  - name: A
    leader: a1
    robots:
      a1: {{start: [0.0, 0.0, 0.0], goal: [2.0, 0.0]}}
{obstacles}"""))


def _forward_speed(world: MujocoWorld) -> float:
    return float(world.data.qvel[0])  # the free body's x velocity (heading 0)


def test_a_robot_follows_a_step_command_with_the_documented_lag():
    world = _one()
    world.substeps = 1  # read the speed every MuJoCo step
    speeds = []
    state = [(0.0, 0.0, 0.0)]
    for _ in range(round(6 * MOTOR_LAG / 0.002)):
        state = world.move(state, [(0.0, 0.0, 0.1, 0.0)])
        speeds.append(_forward_speed(world))
    at_lag = speeds[round(MOTOR_LAG / 0.002) - 1]
    assert at_lag == pytest.approx(0.1 * (1.0 - math.exp(-1.0)), abs=0.015)  # 63 % after one lag
    assert speeds[-1] == pytest.approx(0.1, rel=0.03)  # and there (a little slip) after six
    assert max(speeds) < 0.102  # no overshoot to speak of
    assert state[0][0] > 0.0 and abs(state[0][1]) < 1e-3 and abs(state[0][2]) < 1e-2


def test_a_step_beyond_the_motors_speed_saturates_at_the_xl430s():
    world = _one()
    state = [(0.0, 0.0, 0.0)]
    for _ in range(40):
        state = world.move(state, [(0.0, 0.0, 1.0, 0.0)])
    assert _forward_speed(world) == pytest.approx(XL430_SPEED * R, rel=0.05)
    assert _forward_speed(world) <= XL430_SPEED * R


def test_a_single_integrator_turns_its_body_through_the_lookahead_map():
    world = _one("single_integrator")
    state = [(0.0, 0.0, 0.0)]
    for _ in range(20):  # a velocity to the left: the robot turns that way and drives
        state = world.move(state, [(0.0, 0.1, 0.0, 0.0)])
    assert state[0][2] > 0.5 and state[0][1] > 0.0


def test_contacts_between_bodies_are_counted_once_per_onset():
    sc = parse_scenario("""
name: two
dt: 0.05
robot: {model: unicycle}
formations:
  - name: A
    leader: a1
    robots:
      a1: {start: [0.0, 0.0, 0.0], goal: [2.0, 0.0]}
  - name: B
    leader: b1
    robots:
      b1: {start: [0.6, 0.0, 3.14159], goal: [-2.0, 0.0]}
""")
    world = MujocoWorld(sc)
    state = [r.start for r in sc.robots]
    for _ in range(60):  # head-on at 0.1 m/s each: they meet after 2 s, and keep pushing
        state = world.move(state, [(0.0, 0.0, 0.1, 0.0)] * 2)
    assert world.collisions >= 1
    assert world.collision_log[0]["a"] == "a1" and world.collision_log[0]["b"] == "b1"
    assert world.collision_log[0]["t"] == pytest.approx((0.6 - 0.21) / 0.2, abs=0.4)
    assert world.summary_fields()["physics"]["collisions"] == world.collisions


def test_a_moving_obstacle_is_a_kinematic_body_that_follows_its_velocity():
    world = _one(obstacles="obstacles:\n  - {name: cart, center: [3.0, 3.0], safe_distance: 0.4, "
                           "velocity: [0.2, 0.0]}\n")
    state = [(0.0, 0.0, 0.0)]
    for _ in range(20):
        state = world.move(state, [None])
    cart = world.data.body("o_cart")
    assert cart.xpos[0] == pytest.approx(3.0 + 0.2 * 1.0, abs=1e-6)
    assert world.collisions == 0 and state[0] == pytest.approx((0.0, 0.0, 0.0), abs=1e-3)


def test_a_small_scenario_in_mujoco_reaches_every_goal_without_contact(tmp_path):
    assert main(["sim", str(TWO_SMALL), "--out", str(tmp_path), "--quiet", "--no-plots",
                 "--engine", "mujoco"]) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["all_reached"] and s["collisions"] == 0
    assert s["physics"]["engine"] == "mujoco" and s["physics"]["collisions"] == 0
    assert s["formation_error_max_m"] <= 1.5 * 0.05


def test_an_unknown_engine_is_refused():
    with pytest.raises(ValueError, match="engine"):
        world_for(parse_scenario(TWO_SMALL.read_text()), "bullet")


def test_the_multiprocess_world_builds_its_physics_from_its_options():
    from simulator.world import WorldOptions, lab_world

    sc = parse_scenario(TWO_SMALL.read_text())
    assert isinstance(lab_world(sc, WorldOptions(engine="mujoco")), MujocoWorld)
    assert lab_world(sc, WorldOptions()) is None


def test_a_lockstep_run_with_mujoco_equals_the_simulation(tmp_path):
    for mode, extra in (("sim", []), ("run", ["--insecure"])):
        assert main([mode, str(TWO_SMALL), "--out", str(tmp_path / mode), "--quiet", "--no-plots",
                     "--engine", "mujoco", *extra]) == 0
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["mode"] == "multiprocess" and run["physics"]["engine"] == "mujoco"
    assert run["physics"]["collisions"] == 0 and run["all_reached"]
    assert_same(tmp_path / "sim" / "robots.csv", tmp_path / "run" / "robots.csv")


def test_a_run_takes_the_engine_into_its_world():
    from simulator.launch import world_options
    from simulator.run_config import RunConfig

    sc = parse_scenario(TWO_SMALL.read_text())
    assert world_options(RunConfig(sc, Path("out"), engine="mujoco")).engine == "mujoco"
    assert world_options(RunConfig(sc, Path("out"))).engine == "kinematic"
    with pytest.raises(ValueError, match="--engine"):
        RunConfig(sc, Path("out"), engine="bullet")
