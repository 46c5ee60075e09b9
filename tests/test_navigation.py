"""Warehouse navigation: walls and shelves in scenario files, routes around them, waypoints."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from geometry.route import ADVANCE_RADIUS, ROUTE_MARGIN, advance, member_target, plan_route
from geometry.shapes import box, path_clearance, segment, shape_distance
from leader.navigation import Follower
from scenario import ScenarioError, load_scenario, parse_scenario
from scenario.routes import initial_route, route_radius
from simulator.inprocess import SimOptions, simulate
from tests.scenario_runs import summary_of
from wire.navigation import PlanMsg

ROOT = Path(__file__).resolve().parent.parent
NAV = sorted((ROOT / "tests" / "scenarios").glob("nav-*.yaml")) + [ROOT / "scenarios" / "warehouse.yaml"]

BASE = """
name: t
duration: 60
robot: {model: single_integrator, max_speed: 0.22, radius: 0.105}
controller: {epsilon: 0.04%s}
formations:
  - name: A
    leader: a1
    robots:
      a1: {start: [0.5, 0.0], goal: [%s, 0.0]}
      a2: {start: [0.0, 0.0], goal: [%s, 0.0]}
    edges: [[a1, a2]]
%s
obstacles:
%s
"""


def scenario_text(obstacles: str, goal_x: float = 4.5, controller: str = "", extra: str = "") -> str:
    return BASE % (controller, goal_x, goal_x - 0.5, extra, obstacles)


def test_walls_and_shelves_load_beside_circles():
    s = parse_scenario(scenario_text(
        "  - {name: c, center: [2.0, 3.0], safe_distance: 0.3}\n"
        "  - {name: w, segment: [[0.0, 1.0], [4.0, 1.0]], safe_distance: 0.15}\n"
        "  - {name: s, box: {center: [2.0, -1.5], size: [2.0, 0.6], yaw: 0.3}, safe_distance: 0.2}\n"))
    assert [o.name for o in s.obstacles] == ["c"]
    assert [(sh.name, sh.kind) for sh in s.shapes] == [("w", "segment"), ("s", "box")]
    w, b = s.shapes
    assert (w.cx, w.cy, w.hx, w.hy, w.yaw, w.ds) == pytest.approx((2.0, 1.0, 2.0, 0.0, 0.0, 0.15))
    assert (b.cx, b.cy, b.hx, b.hy, b.yaw, b.ds) == pytest.approx((2.0, -1.5, 1.0, 0.3, 0.3, 0.2))


@pytest.mark.parametrize("obstacle, message", [
    ("{name: shelf, box: {center: [0.0, 0.0], size: [0.6, 0.6]}, safe_distance: 0.1}",
     "robot 'a2' starts inside box 'shelf'"),
    ("{name: shelf, box: {center: [4.5, 0.0], size: [0.4, 0.4]}, safe_distance: 0.1}",
     "robot 'a1' has its goal inside box 'shelf'"),
    ("{name: wall, segment: [[-1.0, 0.1], [3.0, 0.1]], safe_distance: 0.15}",
     "robot 'a1' starts 0.100 m from segment 'wall', inside its safe distance 0.150 m"),
    ("{name: wall, segment: [[4.0, 0.2], [6.0, 0.2]], safe_distance: 0.25}",
     "has its goal 0.200 m from segment 'wall'"),
    ("{name: w, segment: [[1.0, 1.0], [1.0, 1.0]], safe_distance: 0.1}", "both ends are the same point"),
    ("{name: w, segment: [[1.0, 1.0], [2.0, 1.0]], velocity: [0.1, 0.0], safe_distance: 0.1}",
     "obstacles[0].velocity: not allowed on a segment"),
    ("{name: b, box: {center: [1.0, 3.0], size: [1.0, 0.0]}, safe_distance: 0.1}",
     "obstacles[0].box.size[1]: must be positive"),
    ("{name: b, box: {center: [1.0, 3.0], size: [1.0, 1.0], tilt: 1}, safe_distance: 0.1}",
     "obstacles[0].box: unknown key 'tilt'"),
    ("{name: b, box: {center: [1.0, 3.0], size: [1.0, 1.0]}}", "obstacles[0].safe_distance: missing"),
])
def test_a_start_or_goal_inside_a_shape_and_malformed_shapes_are_named(obstacle, message):
    with pytest.raises(ScenarioError, match=message.replace("(", r"\(").replace("[", r"\[")):
        parse_scenario(scenario_text(f"  - {obstacle}\n"))


def test_waypoints_inside_a_shape_and_an_unknown_planner_are_errors():
    shelf = "  - {name: shelf, box: {center: [2.0, 0.0], size: [0.5, 2.0]}, safe_distance: 0.1}\n"
    with pytest.raises(ScenarioError, match=r"formations\[0\].waypoints\[1\]: inside the safe distance"
                                            " of box 'shelf'"):
        parse_scenario(scenario_text(shelf, extra="    waypoints: [[2.0, 2.0], [2.0, 0.5]]"))
    with pytest.raises(ScenarioError, match="controller.planner: 'astar' is not one of"):
        parse_scenario(scenario_text(shelf, controller=", planner: astar"))


def test_files_without_walls_or_boxes_keep_the_one_waypoint_route():
    for path in sorted((ROOT / "scenarios").glob("thesis-*.yaml")):
        s = load_scenario(path)
        assert not s.shapes
        for f in s.formations:
            assert initial_route(s, f) == (f.goal_centroid,)


def test_planned_legs_keep_the_inflated_clearance_of_every_shape():
    shapes = [box("s1", (2.0, 0.0), (0.6, 3.0), 0.0, 0.15), box("s2", (4.0, 1.0), (0.6, 3.0), 0.4, 0.15),
              segment("w", (0.0, -2.5), (6.0, -2.5), 0.15)]
    radius = 0.3
    route = plan_route((0.0, 0.0), (6.0, 0.5), shapes, radius)
    assert route[-1] == (6.0, 0.5) and len(route) >= 2
    pts = [(0.0, 0.0), *route]
    for a, b in zip(pts, pts[1:], strict=False):
        for sh in shapes:
            assert path_clearance(a, b, sh) >= sh.ds + radius + ROUTE_MARGIN - 1e-9
    # the straight line is blocked, so the route is longer than it but not absurdly so
    length = sum(math.dist(a, b) for a, b in zip(pts, pts[1:], strict=False))
    assert math.dist((0.0, 0.0), (6.0, 0.5)) < length < 2.0 * math.dist((0.0, 0.0), (6.0, 0.5))


def test_a_start_closer_to_a_wall_than_the_inflation_may_leave_but_not_approach():
    wall = segment("w", (-5.0, 0.5), (5.0, 0.5), 0.15)
    route = plan_route((0.0, 0.0), (3.0, 0.0), [wall], 0.4)  # start 0.5 from the wall, need 0.7
    assert route == ((3.0, 0.0),)  # the leg along the wall keeps its start clearance


def test_advance_walks_the_route_and_member_targets_end_at_the_goals():
    route = ((1.0, 0.0), (1.0, 1.0), (2.0, 1.0))
    assert advance(route, 0, 0.0, 0.0) == 0
    assert advance(route, 0, 1.0, 0.0 + ADVANCE_RADIUS * 0.9) == 1
    assert advance(route, 0, 1.0, 1.0) == 0  # only the waypoint it is at counts
    assert advance(route, 1, 1.0, 1.0) == 2
    assert advance(route, 2, 2.0, 1.0) == 2  # never past the goal
    assert member_target(route, 1, (2.3, 1.0), (0.3, 0.0)) == (1.3, 1.0)
    assert member_target(route, 2, (2.3, 1.0), (0.3, 0.0)) == (2.3, 1.0)  # the goal itself
    # a waypoint with a heading: the slot at the formation's pose there (turned a quarter)
    assert member_target(route, 1, (2.3, 1.0), (0.3, 0.0), math.pi / 2) == pytest.approx((1.0, 1.3))
    assert member_target(route, 2, (2.3, 1.0), (0.3, 0.0), math.pi / 2) == (2.3, 1.0)


def test_a_follower_s_target_at_a_waypoint_with_a_heading_is_its_slot_turned_there():
    """A pentagon stood 0.25 rad short of a waypoint's heading, each
    member within 2 cm of its target, the waypoint plus its goal offset unturned, so each
    blended into parking there (agent.body.member_nominal) and the turn never came. The target
    is the member's slot at the waypoint's pose: the goal offset turned by the waypoint's
    heading less the goal's (a plan's heading; the scenario's goals: 0)."""
    f = Follower("m", (5.3, 0.0), (5.0, 0.0), ((2.0, 0.0), (5.0, 0.0)), (math.pi / 2, None))
    target, waypoint = f.step(2.0, 0.0, 0.0)  # at the waypoint, a quarter turn short
    assert waypoint == (2.0, 0.0) and target == pytest.approx((2.0, 0.3))
    target, waypoint = f.step(2.0, 0.0, math.pi / 2)  # turned: on to the goal, its own
    assert waypoint == (5.0, 0.0) and target == (5.3, 0.0)
    # a plan whose goal shape is turned already a quarter: its offsets are; no turn more
    turned = PlanMsg("f", 1.0, 5.0, 0.0, math.pi / 2, ((2.0, 0.0), (5.0, 0.0)), (("m", 5.0, 0.3),),
                     1.0, (math.pi / 2, math.pi / 2))
    g = Follower("m", (5.3, 0.0), (5.0, 0.0))
    assert g.adopt(turned)
    target, _ = g.step(0.0, 0.0, 0.0)
    assert target == pytest.approx((2.0, 0.3))


@pytest.mark.integration
@pytest.mark.parametrize("path", NAV, ids=[p.stem for p in NAV])
def test_navigation_scenarios_reach_every_goal_safely_in_process(path):
    s = load_scenario(path)
    assert s.shapes
    summary = summary_of(path)
    assert summary["all_reached"], summary["collision_log"]
    assert summary["collisions"] == 0
    assert summary["formation_error_max_m"] <= 1.5 * s.controller.epsilon
    shape_clearance = summary["min_clearance_shape_m"]
    assert set(shape_clearance) == {sh.name for sh in s.shapes}
    assert min(shape_clearance.values()) >= -0.005
    assert summary["min_clearance_m"]["robot"] >= 0.0


def test_without_a_route_the_formation_stalls_in_front_of_the_shelf():
    text = (ROOT / "tests" / "scenarios" / "nav-behind-shelf.yaml").read_text(encoding="utf-8")
    s = parse_scenario(text.replace("epsilon: 0.04}", "epsilon: 0.04, planner: none}"))
    s = dataclasses.replace(s, duration=40.0)
    summary = simulate(s, SimOptions(record=False)).summary
    assert not summary["all_reached"]
    assert summary["collisions"] == 0  # the barriers still hold


def test_waypoints_from_the_file_are_passed_in_order():
    text = scenario_text("  - {name: wall, segment: [[-1.0, 2.0], [6.0, 2.0]], safe_distance: 0.15}\n",
                         extra="    waypoints: [[2.0, 1.2], [3.0, -1.0]]")
    s = parse_scenario(text)
    f = s.formations[0]
    assert initial_route(s, f) == ((2.0, 1.2), (3.0, -1.0), f.goal_centroid)
    assert route_radius(f) == pytest.approx(0.25)
    res = simulate(s)
    assert res.summary["all_reached"]
    rows = res.series.robots
    times = sorted({r[0] for r in rows})
    near = []
    for w in ((2.0, 1.2), (3.0, -1.0)):
        hits = [t for t in times
                if math.dist(w, tuple(sum(r[k] for r in rows if r[0] == t) / 2 for k in (3, 4)))
                <= ADVANCE_RADIUS + 0.01]
        assert hits, w
        near.append(hits[0])
    assert near[0] < near[1]


def test_shape_distance_agrees_with_the_planner_and_monitor_sign_convention():
    shelf = box("s", (0.0, 0.0), (1.0, 1.0), 0.0, 0.1)
    assert shape_distance(0.0, 0.0, shelf)[0] == pytest.approx(-0.5)
    assert path_clearance((0.0, 0.0), (3.0, 0.0), shelf) == 0.0


@pytest.mark.integration
def test_multi_process_lock_step_walks_the_same_routes_as_the_in_process_simulation(tmp_path):
    from formation.cli import main

    path = ROOT / "tests" / "scenarios" / "nav-swap-aisles.yaml"
    assert main(["sim", str(path), "--out", str(tmp_path / "sim"), "--quiet", "--no-plots"]) == 0
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet", "--no-plots"]) == 0
    run = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert run["mode"] == "multiprocess" and run["all_reached"] and run["collisions"] == 0
    assert min(run["min_clearance_shape_m"].values()) >= -0.005
    assert run["formation_error_max_m"] <= 1.5 * 0.04
    assert run["agents"]["stale"] == 0
    assert run["comm"]["classes"]["status"]["put"]["messages"] > 0  # the leaders report
    assert (tmp_path / "run" / "robots.csv").read_text() == (tmp_path / "sim" / "robots.csv").read_text()


def test_the_planners_quick_accept_never_passes_a_leg_closer_than_wanted():
    import random

    from geometry.route import hits_grown_box

    rng = random.Random(1)
    accepted = 0
    for _ in range(3000):
        if rng.random() < 0.7:
            sh = box("b", (rng.uniform(-2, 2), rng.uniform(-2, 2)),
                     (rng.uniform(0.1, 3), rng.uniform(0.1, 1)), rng.uniform(-3, 3), 0.15)
        else:
            sh = segment("w", (rng.uniform(-3, 3), rng.uniform(-3, 3)),
                         (rng.uniform(-3, 3), rng.uniform(-3, 3)), 0.15)
        p0, p1 = (rng.uniform(-4, 4), rng.uniform(-4, 4)), (rng.uniform(-4, 4), rng.uniform(-4, 4))
        want = rng.uniform(0.1, 1.0)
        if not hits_grown_box(p0, p1, sh, (math.cos(sh.yaw), math.sin(sh.yaw)), want):
            accepted += 1
            assert path_clearance(p0, p1, sh) >= want - 1e-9
    assert accepted > 300


def test_the_camera_service_publishes_a_scenarios_walls_and_shelves_as_static_obstacles():
    from camera_service.config import load_static_obstacles
    from wire.payloads import Obstacles, decode_obstacles, encode
    from wire.shapes import msg_to_shape, shape_to_msg

    circles, shapes = load_static_obstacles(ROOT / "tests" / "scenarios" / "nav-behind-shelf.yaml")
    assert circles == () and [s.name for s in shapes] == ["shelf", "wall-s"]
    back = decode_obstacles(encode(Obstacles(1.0, (), tuple(shape_to_msg(s) for s in shapes))))
    assert tuple(msg_to_shape(m) for m in back.shapes) == shapes
