"""Plausibility of inputs (agent.plausibility) and the count of unmet hard rows (agent.hard_rows)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from agent.barriers import obstacle_h
from agent.control import ControlParams
from agent.hard_rows import HARD_BARRIERS, HardRowCounter, unmet_hard_rows, unmet_of_result
from agent.plausibility import (
    JUMP_MARGIN_M,
    SPEED_FACTOR,
    ObstacleMemory,
    held_obstacle,
    jump_ok,
    listed_obstacles,
    points_ok,
    speed_bound,
    velocity_ok,
)
from formation.cli import main
from simulator.inprocess import Series
from simulator.plots import hard_row_ticks
from wire.payloads import EllipseMsg, ObstacleMsg, Obstacles, Others

ROOT = Path(__file__).resolve().parent.parent


def test_the_speed_bound_is_the_limit_with_the_look_ahead_sweep_for_unicycles():
    assert speed_bound(ControlParams(max_speed=0.22)) == pytest.approx(SPEED_FACTOR * 0.22)
    uni = ControlParams(max_speed=0.22, unicycle=True, lookahead=0.05, max_turn_rate=2.84)
    assert speed_bound(uni) == pytest.approx(SPEED_FACTOR * math.hypot(0.22, 0.05 * 2.84))


@given(speed=st.floats(0.0, 0.22), heading=st.floats(-math.pi, math.pi),
       elapsed=st.floats(0.0, 5.0))
def test_a_robot_driving_within_its_limit_always_passes_the_jump_check(speed, heading, elapsed):
    x, y = 1.0 + speed * elapsed * math.cos(heading), 2.0 + speed * elapsed * math.sin(heading)
    assert jump_ok(1.0, 2.0, 10.0, x, y, 10.0 + elapsed, speed_bound(ControlParams()))


def test_jumps_beyond_speed_times_elapsed_plus_margin_are_refused():
    bound = speed_bound(ControlParams())
    assert not jump_ok(0.0, 0.0, 10.0, 1e9, 1e9, 10.05, bound)
    assert not jump_ok(0.0, 0.0, 10.0, 0.5, 0.0, 10.05, bound)  # 10 m/s
    assert jump_ok(0.0, 0.0, 10.0, JUMP_MARGIN_M * 0.9, 0.0, 10.0, bound)  # noise, same stamp
    assert not jump_ok(0.0, 0.0, 10.0, 0.2, 0.0, 10.0, bound)  # the same stamp, elsewhere
    assert jump_ok(0.0, 0.0, 10.0, 1.0, 0.0, 15.0, bound)  # after a 5 s dropout: 1 m is possible
    assert not velocity_ok(1e6, 0.0, bound)
    assert velocity_ok(0.22, 0.0, bound)


def test_a_held_obstacle_covers_everywhere_it_can_have_gone_and_its_row_sees_it_grow():
    o = ObstacleMsg("forklift", 2.0, 0.0, -0.3, 0.0, 0.5)
    h = held_obstacle(o, 1.5, 0.0, 0.0)
    assert h.ds == pytest.approx(0.5 + 0.3 * 1.5)
    assert (h.x, h.y) == (2.0, 0.0)
    assert (h.vx, h.vy) == pytest.approx((-0.3, 0.0))  # towards the robot at its speed
    # any point the forklift can have reached is inside the grown disc
    for ang in [k * math.pi / 8 for k in range(16)]:
        px, py = 2.0 + 0.45 * math.cos(ang), 0.45 * math.sin(ang)
        assert obstacle_h(px, py, h) <= 0.0  # the robot may not be there
        assert math.hypot(px - h.x, py - h.y) <= h.ds
    assert held_obstacle(ObstacleMsg("crate", 1.0, 1.0, 0.0, 0.0, 0.3), 1.0, 0.0, 0.0).ds == 0.3


def test_an_obstacle_missing_from_a_new_list_is_held_for_a_bounded_time_then_dropped():
    fork = ObstacleMsg("forklift", 2.0, 0.0, -0.3, 0.0, 0.5)
    crate = ObstacleMsg("crate", 0.0, 3.0, 0.0, 0.0, 0.3)
    mem = ObstacleMemory(hold_s=2.0)
    mem.update(Obstacles(10.0, (fork, crate)))
    assert mem.held(10.0) == []
    mem.update(Obstacles(10.05, (crate,)))  # the forklift is gone from the list
    assert mem.missing == 1
    assert mem.held(11.0) == [(fork, pytest.approx(1.0))]
    mem.update(Obstacles(10.05, (crate,)))  # the same list again counts nothing new
    mem.update(Obstacles(10.1, (crate,)))
    assert mem.missing == 1
    assert mem.held(12.0) == [(fork, pytest.approx(2.0))]
    assert mem.held(12.1) == [] and mem.dropped == 1  # it left the scene for good
    mem.update(Obstacles(9.0, ()))  # an older list changes nothing
    assert mem.missing == 1
    mem.update(Obstacles(12.2, (fork,)))  # back in view: current again
    assert mem.held(12.2) == [] and mem.missing == 2  # the crate went missing now
    with pytest.raises(ValueError, match="hold_s"):
        ObstacleMemory(hold_s=math.nan)


def test_the_same_list_taken_again_counts_nothing_and_is_converted_to_rows_once():
    fork = ObstacleMsg("forklift", 2.0, 0.0, -0.3, 0.0, 0.5)
    crate = ObstacleMsg("crate", 0.0, 3.0, 0.0, 0.0, 0.3)
    first, second = Obstacles(10.0, (fork, crate)), Obstacles(10.05, (crate,))
    mem = ObstacleMemory(hold_s=2.0)
    for msg in (first, second, second, second):  # one list object, held by the inbox per tick
        mem.update(msg)
    assert mem.missing == 1 and mem.held(10.5) == [(fork, pytest.approx(0.5))]
    rows = listed_obstacles(first)
    assert [(o.x, o.y, o.vx, o.vy, o.ds) for o in rows] == [(2.0, 0.0, -0.3, 0.0, 0.5),
                                                            (0.0, 3.0, 0.0, 0.0, 0.3)]
    assert listed_obstacles(first) is rows  # once per list
    assert [o.x for o in listed_obstacles(second)] == [0.0]
    assert listed_obstacles(Obstacles(10.05, (crate,))) == listed_obstacles(second)


def test_hard_rows_count_fallbacks_failures_and_barriers_below_zero_but_not_relaxed_formations():
    assert unmet_hard_rows("ok", {"h_obstacle": 0.1, "h_formations": 2.0}) == ()
    assert unmet_hard_rows("relaxed", {"h_obstacle": 0.1, "h_formations": 2.0}) == ()
    assert unmet_hard_rows("fallback", {"h_obstacle": 0.1}) == ("fallback",)
    assert unmet_hard_rows("failed", {}) == ("failed",)
    assert unmet_hard_rows("ok", {"h_formations": -0.005}) == ("formations",)
    assert unmet_hard_rows("ok", {"h_obstacle": -1e-3, "h_separation": -0.01}) == (
        "obstacle", "separation")
    assert unmet_hard_rows("ok", {"h_obstacle": math.nan, "h_formations": None}) == ()
    c = HardRowCounter()

    class R:
        status, h_obstacle, h_formations = "ok", 0.2, -0.005

    c.add(R())
    R.status = "fallback"
    c.add(R())
    assert c.ticks == 2 and c.by_reason == {"formations": 2, "fallback": 1}


@pytest.mark.parametrize("status", ["ok", "relaxed", "fallback", "failed"])
@pytest.mark.parametrize("values", [
    (0.1, 2.0, 0.3), (-1e-3, 2.0, None), (math.nan, -0.005, 0.0), (None, None, -0.01),
    (-1e-10, 0.0, math.nan), (0.0, 0.0, 0.0),
])
def test_a_results_unmet_hard_rows_are_its_barrier_values_ones(status, values):
    class R:
        pass

    r = R()
    r.status = status
    for name, v in zip(HARD_BARRIERS, values, strict=True):
        if v is not None:  # a result without the field: none of that kind
            setattr(r, name, v)
    assert unmet_of_result(r) == unmet_hard_rows(status, dict(zip(HARD_BARRIERS, values, strict=True)))


def test_the_figures_mark_the_ticks_with_a_hard_row_not_met():
    s = Series()
    nan = math.nan
    s.robots.append((0.0, "r1", "F", 0, 0, 0, 0, 0, 0, 0, 0, 0, "ok", 0.0, 0.1, 0.3, 1.0))
    s.robots.append((0.05, "r1", "F", 0, 0, 0, 0, 0, 0, 0, 0, 0, "ok", 0.0, 0.1, 0.3, -0.005))
    s.robots.append((0.1, "r2", "F", 0, 0, 0, 0, 0, 0, 0, 0, 0, "fallback", 0.1, 0.1, 0.2, 1.0))
    s.robots.append((0.1, "r1", "F", 0, 0, 0, 0, 0, 0, 0, 0, 0, "stale", 0.0, nan, nan, nan))
    marks = hard_row_ticks(s)
    assert [(m[0], m[2], m[3]) for m in marks] == [(0.05, ("formations",), "r1"),
                                                 (0.1, ("fallback",), "r2")]


@pytest.mark.integration
def test_summary_json_counts_hard_row_ticks_apart_from_minimal_formation_relaxations(tmp_path,
                                                                                     capsys):
    out = tmp_path / "sim"
    assert main(["sim", str(ROOT / "tests" / "scenarios" / "two-small.yaml"), "--out", str(out),
                 "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["hard_row_unmet_ticks"] == s["qp"]["hard_row_unmet_ticks"] == 0
    assert s["qp"]["hard_row_unmet"] == {}
    line = capsys.readouterr().out
    assert "relaxed (by design, minimal)" in line and "hard rows unmet: 0" in line
    assert (out / "safety.png").exists()


def test_a_run_that_enters_an_obstacle_counts_and_says_its_hard_row_ticks(tmp_path, capsys):
    # safety off: the pair drives through the forklift's safe distance; every tick with the
    # obstacle barrier below zero is counted, in the summary and in the summary line
    out = tmp_path / "unsafe"
    assert main(["sim", str(ROOT / "tests" / "scenarios" / "crossing-forklift.yaml"), "--out",
                 str(out), "--quiet", "--no-plots", "--no-safety"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["collisions"] > 0 and s["min_h"]["obstacle"] < 0
    assert s["hard_row_unmet_ticks"] == s["qp"]["hard_row_unmet"]["obstacle"] > 0
    assert f"hard rows unmet: {s['hard_row_unmet_ticks']:,}" in capsys.readouterr().out


def _feed(tracker, poses, still=True):
    """Offer (x, y, stamp) poses refused as jumps; the indices that re-acquired the marker."""
    return [k for k, (x, y, t) in enumerate(poses) if tracker.offer(x, y, t, still)]


def test_a_marker_that_jumped_for_good_is_reacquired_after_three_agreeing_poses_while_still():
    from agent.plausibility import REACQUIRE_POSES, Reacquire

    camera = [(5.0 + 0.001 * k, 0.0, 0.1 * k) for k in range(10)]  # 10 fps
    assert _feed(Reacquire(0.3), camera) == [REACQUIRE_POSES, 2 * REACQUIRE_POSES + 1]  # 0.3 s
    assert _feed(Reacquire(0.3), camera, still=False) == []  # it may have driven off: no


@given(st.integers(0, 10_000))
def test_a_forger_at_three_times_the_camera_rate_never_reacquires_between_genuine_poses(seed):
    # genuine poses at 20 Hz near (0, 0) are plausible after the kept pose (reset); forged
    # ones 5 m off arrive three per camera frame: never three agreeing in a row
    import random

    from agent.plausibility import Reacquire

    rng = random.Random(seed)
    tracker = Reacquire(0.3)
    for k in range(60):
        tracker.reset()  # the genuine pose of frame k was accepted
        for j in range(3):
            t = 0.05 * k + 0.0125 * (j + 1)
            assert not tracker.offer(5.0 + rng.uniform(-0.01, 0.01), 0.0, t, True)
    tracker.reset()
    assert _feed(tracker, [(5.0, 0.0, 10.0), (0.0, 0.0, 10.01), (5.0, 0.0, 10.02)]) == []


def test_an_ellipse_whose_member_point_lies_far_outside_it_is_implausible():
    """A genuine leader's members sit inside its ellipse (a broken band leaves them well within
    twice its semi-major axis plus 1 m); a point beyond would make the other formations keep
    their ellipses off a place no member is: the message is dropped, as an ``ellipse``, a
    ``beacon`` or inside an ``others``."""
    from agent.inbox import plausible
    from wire import keys

    near = EllipseMsg("f", 1.0, 1.0, 0.0, 0.6, 0.3, 0.0, 0.0, 0.0, 5.0,
                      ((1.5, 1.0), (0.5, 1.0), (1.0, 1.0 + 2 * 0.6 + 0.99)))
    far = EllipseMsg("f", 1.0, 1.0, 0.0, 0.6, 0.3, 0.0, 0.0, 0.0, 5.0, ((1.0, 1.0 + 2 * 0.6 + 1.01),))
    assert points_ok(near) and not points_ok(far)
    assert points_ok(EllipseMsg("f", 1.0, 1.0, 0.0, 0.6, 0.3, 0.0, 0.0, 0.0, 5.0))  # none sent
    speed = 0.3
    assert plausible(keys.ELLIPSE, near, None, speed) and not plausible(keys.ELLIPSE, far, None, speed)
    assert not plausible(keys.BEACON, far, None, speed)
    assert not plausible(keys.OTHERS, Others("g", 5.0, (far,), None), None, speed)
    own_far = EllipseMsg("g", *[getattr(far, k) for k in ("cx", "cy", "alpha", "a", "b", "vx", "vy",
                                                          "alpha_rate", "stamp")], far.points)
    assert not plausible(keys.OTHERS, Others("g", 5.0, (near,), own_far), None, speed)
    assert plausible(keys.OTHERS, Others("g", 5.0, (near,), None), None, speed)
