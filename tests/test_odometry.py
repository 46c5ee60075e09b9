"""The worlds' wheel odometry and blind floor (simulator.odometry, simulator.fused's camera):
seeded per-robot errors within their bounds, exact increments in the ideal case, and no pose on
blind floor or in a camera fault."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from agent import margins
from scenario import load_scenario
from scenario.model import Bounds
from scenario.world import CameraFault, Odometry, WorldSpec
from simulator.fused import FleetLocalisation
from simulator.odometry import Odometer, measured, odometry_errors
from wire.odom import body_increment

BLIND = Path(__file__).parent / "scenarios" / "blind-aisle.yaml"


def test_errors_are_seeded_per_robot_and_within_their_bounds():
    spec = WorldSpec(seed=5, odometry=Odometry(0.01, 0.005))
    a, b = odometry_errors(spec, 6), odometry_errors(spec, 6)
    assert a == b and len(set(a)) == 6
    assert all(abs(s) <= 0.01 and abs(d) <= 0.005 for s, d in a)
    assert odometry_errors(dataclasses.replace(spec, seed=6), 6) != a


def test_exact_odometry_reports_the_true_increment():
    before, after = (1.0, 2.0, 0.5), (1.1, 2.05, 0.6)
    inc = body_increment(before, after)
    assert math.isclose(math.hypot(inc[0], inc[1]), math.hypot(0.1, 0.05))
    assert math.isclose(inc[2], 0.1)
    assert Odometer(WorldSpec(), 1).increments([before], [after]) == [measured(inc, 0.0, 0.0)]


def test_a_scale_error_lengthens_and_a_drift_turns():
    inc = measured((0.1, 0.0, 0.0), 0.02, 0.01)
    assert math.isclose(inc[0], 0.102) and math.isclose(inc[2], 0.001)


def test_the_camera_reports_nothing_on_blind_floor_and_follows_faults():
    sc = load_scenario(BLIND)
    w = dataclasses.replace(sc.world, camera_faults=(
        CameraFault("misread", 0.0, 1.0, robot="p1", other="p3"),
        CameraFault("forged", 0.0, 1.0, robot="p2", offset=(0.5, 0.0))))
    loc = FleetLocalisation(dataclasses.replace(sc, world=w), None)
    truth = [(-4.5, 0.2, 0.0), (-4.0, 0.2, 0.0), (0.0, -0.2, 0.0), (-4.5, -0.2, 0.0)]
    poses = loc.camera_poses(0.5, truth, truth)
    assert poses[0] == truth[2]  # misread: p3's pose
    assert poses[1] == (-3.5, 0.2, 0.0)  # forged 0.5 m off
    assert poses[2] is None  # p3 stands in the blind box
    assert poses[3] == truth[3]
    assert loc.camera_poses(2.0, truth, truth)[0] == truth[0]  # the fault is over


def test_camera_only_holds_a_robot_without_a_pose_at_its_last_one():
    sc = load_scenario(BLIND)
    sc = dataclasses.replace(sc, controller=dataclasses.replace(sc.controller,
                                                                localisation="camera"))
    loc = FleetLocalisation.build(sc, None)
    assert loc is not None and not loc.fused
    seen = [(-1.8, 0.2, 0.0), (-4.0, 0.2, 0.0), (-4.0, -0.2, 0.0), (-4.5, -0.2, 0.0)]
    loc.sense(0, seen, seen)
    inside = [(-1.7, 0.2, 0.0)] + seen[1:]
    out = loc.sense(1, inside, inside)
    assert out[0] == seen[0] and loc.held == [True, False, False, False]
    assert loc.hold(0, out[0], 0.0).status == "stale" and loc.hold(1, out[1], 0.0) is None


def test_a_run_without_blind_floor_faults_or_fused_gets_no_localisation():
    sc = load_scenario(Path(__file__).parent / "scenarios" / "aisle-crate.yaml")
    assert FleetLocalisation.build(sc, None) is None


@pytest.mark.parametrize("own, other", [(0.0, 0.0), (0.02, 0.05), (0.05, 0.01), (0.2, 0.2)])
def test_localisation_bounds_cover_the_estimate_margins(own, other):
    """The grown bounds keep a pair at least both radii and an obstacle at least its own."""
    b = margins.localisation_bounds(Bounds(), own, other)
    assert 2.0 * margins.position_noise(b) >= margins.estimate_margin(own, other) - 1e-12
    assert margins.robot_margin(b, 0.22, 0.0) >= own - 1e-12
    assert margins.position_noise(b) <= 0.5 * (own + max(own, other)) + margins.RADIUS_STEP


def test_wheel_increments_straight_and_on_an_arc():
    from simulator.odometry import wheel_increment

    assert wheel_increment(0.1, 0.1, 0.16) == (0.1, 0.0, 0.0)
    # a quarter circle of radius 1 m (centre line), wheels 0.08 m either side of it
    r, q = 1.0, math.pi / 2
    dx, dy, dth = wheel_increment((r - 0.08) * q, (r + 0.08) * q, 0.16)
    assert math.isclose(dth, q) and math.isclose(dx, 1.0) and math.isclose(dy, 1.0)


def test_the_world_publishes_no_pose_of_a_robot_on_blind_floor():
    from simulator.odometry import seen_by_camera

    spec = load_scenario(BLIND).world
    assert seen_by_camera(spec, [(0.0, 0.0, 0.0), (-3.0, 0.0, 1.0), (1.74, 0.99, 0.0)]) == [
        False, True, False]


def test_a_robot_keeps_the_margins_of_the_radii_it_hears_and_not_of_far_ones():
    from agent.margins import heard_radius
    from simulator.fused import formation_radii

    membership = np.array([[1, 0]] * 4 + [[0, 1]] * 4, dtype=float)  # A: 0-3, B: 4-7
    radius = [0.01, 0.02, 0.01, 0.01] + [0.2] * 4
    per = formation_radii(radius, membership).tolist()
    assert per == [0.02, 0.2]  # what each leader puts on its ellipse
    assert heard_radius(0.01, (), [per[0]]) == 0.02  # B not in A's view: A's radii alone
    assert heard_radius(0.01, (), [per[0], per[1]]) == 0.2  # B in view: its radius counts
    assert heard_radius(0.2, (), [per[1], per[0]]) == 0.2  # and the other way round
    # an agent: its members' states and the ellipses; None from a sender on the camera's poses
    assert heard_radius(0.01, [None, 0.03], [None, 0.02]) == 0.03
    assert heard_radius(0.05, [None], [None]) == 0.05


def test_the_synthetic_camera_finds_no_marker_on_blind_floor():
    pytest.importorskip("cv2")
    from simulator.synthetic_camera import SyntheticCamera

    cam = SyntheticCamera(load_scenario(BLIND))
    state = [(-4.5, 0.2, 0.0), (0.0, 0.2, 0.0), (-4.0, -0.2, 0.0), (-4.5, -0.2, 0.0)]
    seen = cam.poses(state, [], 0.0)
    assert set(seen) == {"p1", "p3", "p4"}
    assert math.isclose(seen["p1"][0], -4.5, abs_tol=0.02)
