"""The load is a body (issue 25): declared or the members' hull, placed by the rigid fit of the
members' start positions, counted in collisions and refused at the start where it overlaps."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from formation.cli import main
from geometry.ellipse import ellipse_value
from geometry.polygon import area, convex_hull, points_distance, polygon_distance
from geometry.rigid import RigidMotion, rigid_fit
from scenario import ScenarioError
from scenario.cargo import load_clearances, load_polygon, loads_now, placed_load
from scenario.load import formation_axes, scenario_from_dict, scenario_warnings, start_ellipse
from simulator.inprocess import simulate
from simulator.metrics import SafetyMonitor

coord = st.floats(-20.0, 20.0, allow_nan=False)
points = st.lists(st.tuples(coord, coord), min_size=2, max_size=8)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


def _spread(pts) -> float:
    cx = sum(p[0] for p in pts) / len(pts)
    cy = sum(p[1] for p in pts) / len(pts)
    return max(math.hypot(p[0] - cx, p[1] - cy) for p in pts)


# ------------------------------------------------------------------------- rigid fit


@settings(max_examples=200, deadline=None)
@given(points, angle, coord, coord)
def test_the_fit_recovers_a_rigid_motion_exactly(pts, theta, tx, ty):
    assume(_spread(pts) > 0.1)
    moved = RigidMotion(theta, tx, ty).apply_all(pts)
    fit = rigid_fit(pts, moved)
    assert math.isclose(math.cos(fit.theta - theta), 1.0, abs_tol=1e-9)
    for p, q in zip(fit.apply_all(pts), moved, strict=True):
        assert math.dist(p, q) < 1e-7


@settings(max_examples=200, deadline=None)
@given(points, points)
def test_the_fit_moves_the_centroid_onto_the_centroid(a, b):
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    placed = rigid_fit(a, b).apply_all(a)
    for k in (0, 1):
        assert math.isclose(sum(p[k] for p in placed) / n, sum(q[k] for q in b) / n,
                            abs_tol=1e-7)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(coord, coord), min_size=3, max_size=8))
def test_the_fit_is_a_proper_rotation_never_a_mirror(pts):
    """A mirrored point set is fitted by a rotation: distances and orientation are kept."""
    assume(_spread(pts) > 0.1)
    mirrored = [(-x, y) for x, y in pts]
    placed = rigid_fit(pts, mirrored).apply_all(pts)
    for i in range(len(pts)):
        for j in range(len(pts)):
            assert math.isclose(math.dist(placed[i], placed[j]), math.dist(pts[i], pts[j]),
                                abs_tol=1e-7)
    hull = convex_hull(pts)
    assume(len(hull) >= 3 and area(hull) > 0.01)
    # the placed hull keeps its signed area (a mirror would flip its sign)
    placed_hull = [placed[pts.index(v)] for v in hull]
    assert math.isclose(area(placed_hull), area(hull), rel_tol=1e-6)


# ------------------------------------------------------------------------- polygons


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(coord, coord), min_size=1, max_size=12))
def test_the_hull_contains_every_point(pts):
    hull = convex_hull(pts)
    assert np.all(points_distance(np.array(pts), hull) <= 1e-9 * (1 + _spread(pts)))


@given(st.floats(0.01, 5.0), st.floats(-3.0, 3.0))
def test_two_squares_apart_are_their_gap_and_overlapping_their_depth(gap, slide):
    a = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))
    b = tuple((x + 1.0 + gap, y + slide) for x, y in a)
    expect = math.hypot(gap, max(0.0, abs(slide) - 1.0))
    assert math.isclose(polygon_distance(a, b), expect, abs_tol=1e-9)
    assert math.isclose(polygon_distance(b, a), expect, abs_tol=1e-9)
    depth = min(gap, 0.9)
    c = tuple((x + 1.0 - depth, y + 0.05) for x, y in a)
    assert math.isclose(polygon_distance(a, c), -depth, abs_tol=1e-9)


def test_a_segment_through_a_box_overlaps_it_and_a_point_inside_is_negative():
    box = ((0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (0.0, 1.0))
    assert polygon_distance(((1.0, -1.0), (1.0, 2.0)), box) < 0.0
    assert polygon_distance(((3.0, -1.0), (3.0, 2.0)), box) == pytest.approx(1.0)
    assert points_distance(np.array([(1.0, 0.5)]), box)[0] == pytest.approx(-0.5)


# ------------------------------------------------------------------------- the scenario key

BASE = {
    "name": "t", "dt": 0.05, "duration": 30.0,
    "robot": {"max_speed": 0.22, "radius": 0.105},
    "controller": {"kp": 2.0, "gamma": 1.0, "epsilon": 0.05},
    "formations": [{
        "name": "A", "leader": "a1",
        "robots": {"a1": {"start": [0.0, 0.0], "goal": [4.0, 0.0]},
                   "a2": {"start": [0.0, 1.0], "goal": [4.0, 1.0]},
                   "a3": {"start": [1.0, 0.5], "goal": [5.0, 0.5]}},
        "edges": [["a1", "a2"], ["a1", "a3"], ["a2", "a3"]],
    }],
}


def scenario(load=None, **top):
    d = copy.deepcopy(BASE)
    if load is not None:
        d["formations"][0]["load"] = load
    d.update(top)
    return scenario_from_dict(d)


def test_a_rectangle_load_is_placed_in_the_start_frame():
    s = scenario({"size": [0.4, 0.2], "center": [0.1, 0.0], "yaw": math.pi / 2})
    f = s.formations[0]
    ox, oy = 1.0 / 3.0, 0.5  # the members' start centroid
    corners = sorted((round(x - ox, 9), round(y - oy, 9)) for x, y in load_polygon(f))
    assert corners == sorted([(0.0, -0.2), (0.2, -0.2), (0.2, 0.2), (0.0, 0.2)])


def test_a_polygon_load_is_kept_counter_clockwise():
    s = scenario({"polygon": [[0.1, 0.1], [0.1, -0.1], [-0.1, -0.1]]})
    poly = s.formations[0].load
    assert 0.5 * sum(poly[k][0] * poly[(k + 1) % 3][1] - poly[(k + 1) % 3][0] * poly[k][1]
                     for k in range(3)) > 0.0


@pytest.mark.parametrize("load, message", [
    ({"polygon": [[0, 0], [1, 1], [1, 0], [0, 1]]}, "formations[0].load.polygon: the polygon must be convex"),
    ({"polygon": [[0, 0], [1, 0]]}, "formations[0].load.polygon: must be a list of 3 to 32"),
    ({"polygon": [[0, 0], [1, 0], [0, 0.5]], "size": [1, 1]}, "formations[0].load.size: not allowed"),
    ({"center": [0, 0]}, "formations[0].load: needs size"),
    ({"size": [0.4, -1]}, "formations[0].load.size[1]: must be positive"),
    ({"size": [0.4, 0.2], "yaw": "left"}, "formations[0].load.yaw: must be a number"),
    ({"size": [0.4, 0.2], "mass": 3}, "formations[0].load: unknown key 'mass'"),
    ({"polygon": [[0, 0], [1, "x"], [0, 1]]}, "formations[0].load.polygon[1][1]: must be a number"),
])
def test_a_bad_load_is_one_line_naming_it(load, message):
    with pytest.raises(ScenarioError) as err:
        scenario(load)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_derived_ellipse_contains_the_load_declared_or_not():
    for load in (None, {"size": [2.0, 1.5]}):
        s = scenario(load)
        f = s.formations[0]
        e = start_ellipse(s, f, formation_axes(s, f))
        assert all(ellipse_value(e, *v) < 0.0 for v in load_polygon(f))


def test_a_declared_ellipse_that_does_not_contain_the_load_is_refused():
    d = copy.deepcopy(BASE)
    d["formations"][0]["ellipse"] = {"a": 1.5, "b": 1.2}
    d["formations"][0]["load"] = {"size": [4.0, 0.5]}
    with pytest.raises(ScenarioError, match=r"formations\[0\]\.ellipse: .* does not contain the load"):
        scenario_from_dict(d)


def test_a_declared_load_on_a_wall_is_refused_and_a_hull_on_one_is_a_warning(tmp_path, capsys):
    wall = [{"name": "w", "segment": [[0.5, 0.3], [0.5, 0.7]], "safe_distance": 0.15}]
    with pytest.raises(ScenarioError, match=r"formations\[0\]\.load: overlaps 'w' at the start"):
        scenario({"size": [1.0, 1.0]}, obstacles=wall)
    s = scenario(None, obstacles=wall)
    assert any("its load (the hull of its members) overlaps 'w'" in w for w in scenario_warnings(s))
    d = copy.deepcopy(BASE)
    d["obstacles"] = wall
    d["formations"][0]["load"] = {"size": [1.0, 1.0]}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(d))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "overlaps 'w'" in err[0]


def test_a_declared_load_over_a_circle_is_refused_by_its_physical_radius():
    # a circle of Ds 0.3 has a physical radius 0.3 - 0.105 = 0.195 m
    near = [{"name": "c", "center": [0.4, 0.5 + 0.25 + 0.19], "safe_distance": 0.3}]
    with pytest.raises(ScenarioError, match="overlaps 'c'"):
        scenario({"size": [0.4, 0.5]}, obstacles=near)
    clear = [{"name": "c", "center": [0.4, 0.5 + 0.25 + 0.2], "safe_distance": 0.3}]
    assert scenario({"size": [0.4, 0.5]}, obstacles=clear).formations[0].load


# ------------------------------------------------------------------------- counted as a body


PAIR = {
    "name": "pair-over-wall", "dt": 0.05, "duration": 30.0,
    "robot": {"max_speed": 0.22, "radius": 0.105},
    # no route planner: the formation goes straight, as a hand-given route would; the plain
    # thesis method, which knows nothing of the load (the default keeps it off the rail: below)
    "controller": {"kp": 2.0, "gamma": 1.0, "epsilon": 0.05, "planner": "none", "method": "thesis"},
    "formations": [{
        "name": "P", "leader": "p1",
        "robots": {"p1": {"start": [0.0, -0.6], "goal": [4.0, -0.6]},
                   "p2": {"start": [0.0, 0.6], "goal": [4.0, 0.6]}},
        "edges": [["p1", "p2"]],
    }],
    # a thin wall along the pair's path, between its two robots: no robot comes near it
    "obstacles": [{"name": "rail", "segment": [[1.5, 0.0], [2.5, 0.0]], "safe_distance": 0.2}],
}


def test_under_the_default_rigid_motion_the_pair_keeps_its_load_off_the_rail():
    d = copy.deepcopy(PAIR)
    del d["controller"]["method"]
    summary = simulate(scenario_from_dict(d)).summary
    assert summary["collisions"] == 0 and summary["min_clearance_m"]["load"] >= 0.0


def test_a_wall_between_a_pair_is_a_load_collision_the_robots_alone_miss():
    s = scenario_from_dict(copy.deepcopy(PAIR))
    summary = simulate(s).summary
    loads = [e for e in summary["collision_log"] if e.get("kind") == "load"]
    assert [(e["a"], e["b"]) for e in loads] == [("P", "rail")]
    assert summary["collisions"] == 1
    assert summary["min_clearance_m"]["load"] < 0.0
    assert summary["min_clearance_m"]["obstacle"] > 0.0  # the robots themselves stay clear
    assert 1.5 <= loads[0]["x"] <= 2.5 + 0.1


def _with_pair_b_mapping() -> dict:
    """BASE's triangle A and a pair B (b1, b2) beside it, as a mapping."""
    two = copy.deepcopy(BASE)
    two["formations"].append({"name": "B", "leader": "b1",
                              "robots": {"b1": {"start": [3.0, 3.0], "goal": [5.0, 3.0]},
                                         "b2": {"start": [3.0, 3.5], "goal": [5.0, 3.5]}},
                              "edges": [["b1", "b2"]]})
    return two


def _with_pair_b():
    """BASE's triangle A and a pair B (b1, b2) beside it."""
    return scenario_from_dict(_with_pair_b_mapping())


def test_own_members_never_count_and_another_formations_robot_does():
    s = scenario()
    mon = SafetyMonitor(s)
    start = np.array([r.start[:2] for r in s.robots])
    mon.update(0.0, start, [])
    assert mon.collisions == 0  # its members are on the hull's corners
    s2 = _with_pair_b()
    mon = SafetyMonitor(s2)
    pos = np.array([r.start[:2] for r in s2.robots])
    pos[3] = (0.5, 0.5)  # b1 inside A's triangle
    pos[4] = (0.5, 0.9)
    mon.update(0.1, pos, [])
    kinds = sorted((e["a"], e["b"]) for e in mon.collision_log if e.get("kind") == "load")
    assert ("A", "b1") in kinds
    assert mon.update(0.2, pos, []) is None and mon.collisions == len(mon.collision_log)  # held


def _with_pair_b_and_circles():
    d = copy.deepcopy(BASE)
    d["formations"] += _with_pair_b_mapping()["formations"][1:]
    d["obstacles"] = [{"name": "o1", "center": [8.0, 8.0], "safe_distance": 0.4},
                      {"name": "o2", "center": [-8.0, 8.0], "safe_distance": 0.9}]
    return scenario_from_dict(d)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.floats(-4.0, 5.0), st.floats(-4.0, 5.0)), min_size=4, max_size=4),
       angle, st.floats(0.0, 2.0))
def test_the_bounding_circle_sort_leaves_out_only_what_is_out_of_reach(pts, theta, reach):
    """load_clearances measures only the robots and circles whose disks come near a load's
    bounding circle: exactly what measuring every one against every load gives."""
    s = _with_pair_b_and_circles()
    bodies = np.array([r.start[:2] for r in s.robots])
    bodies[3], bodies[4] = pts[0], pts[1]  # B's two robots anywhere near A
    circles = [pts[2], pts[3]]
    fit = RigidMotion(theta, 0.3, -0.2)
    a_now = [fit.apply((float(bodies[m, 0]), float(bodies[m, 1]))) for m in range(3)]
    bodies[:3] = a_now
    loads = loads_now(s, [load_polygon(f) for f in s.formations], bodies)
    got = [c for c in load_clearances(s, loads, bodies, circles, reach)
           if s.formations[c.formation].name == "A" and c.other in ("b1", "b2", "o1", "o2")]
    want = []
    for m, rid in ((3, "b1"), (4, "b2")):
        d = float(points_distance(bodies[m:m + 1], loads[0])[0]) - s.robot.radius
        if d <= reach:
            want.append((rid, d))
    for (x, y), o in zip(circles, s.obstacles, strict=True):
        d = float(points_distance(np.array([(x, y)]), loads[0])[0]) - (o.safe_distance - s.robot.radius)
        if d <= reach:
            want.append((o.name, d))
    assert [(c.other, c.clearance) for c in got] == want


def test_a_contact_logs_its_first_tick_and_keeps_its_deepest_until_released():
    s = _with_pair_b()
    mon = SafetyMonitor(s)
    pos = np.array([r.start[:2] for r in s.robots])

    def b1_at(t: float, x: float) -> list[dict]:
        pos[3] = (x, 0.2)
        pos[4] = (x, 0.6)
        mon.update(t, pos, [])
        return [e for e in mon.collision_log if e.get("kind") == "load" and e["b"] == "b1"]

    # b1's body (radius r) reaches over A's left edge x = 0 by -c: its clearance is c
    r = s.robot.radius
    for k, c in enumerate([-0.01, -0.05, -0.12, -0.03]):
        log = b1_at(0.1 * (k + 1), -c - r)
    assert len(log) == 1  # one contact, held
    assert log[0]["clearance_m"] == pytest.approx(-0.01, abs=1e-6)  # its first tick
    assert log[0]["deepest_m"] == pytest.approx(-0.12, abs=1e-6)  # its worst
    assert b1_at(1.0, -1.0)[0]["deepest_m"] == pytest.approx(-0.12, abs=1e-6)  # released
    log = b1_at(1.1, 0.02 - r)
    assert len(log) == 2 and log[1]["deepest_m"] == log[1]["clearance_m"] == pytest.approx(
        -0.02, abs=1e-6)  # a new contact, its own entry


def test_the_load_follows_its_members_rigidly():
    s = scenario({"size": [0.6, 0.3]})
    f = s.formations[0]
    start = [(r.start[0], r.start[1]) for r in f.robots]
    moved = RigidMotion(0.7, 3.0, -1.0).apply_all(start)
    placed = placed_load(f, load_polygon(f), moved)
    expect = RigidMotion(0.7, 3.0, -1.0).apply_all(load_polygon(f))
    assert all(math.dist(p, q) < 1e-9 for p, q in zip(placed, expect, strict=True))
