"""A ROS 2 base's wheel odometry into the agent's filter, without Zenoh: nav_msgs/Odometry
poses differenced into the increments the filter takes (composing them gives the pose back),
the first the reference, a reset or jump and a malformed payload dropped and counted, the
base's odom key over the bridge and over rmw_zenoh."""

from __future__ import annotations

import math
from itertools import pairwise
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.base import BURGER_MAX_SPEED, BURGER_MAX_TURN_RATE, base_limits, base_odom_key
from agent.localisation import motion
from agent.odom_in import OdomIn, RosOdom, ros_increment
from wire.odom import body_increment
from wire.payloads import Pose, encode
from wire.rmw_zenoh import RmwSettings, decode_odometry, encode_odometry, odom_data_key

SPEED, TURN = BURGER_MAX_SPEED, BURGER_MAX_TURN_RATE
DT = 0.05

coordinate = st.floats(-50.0, 50.0)
heading = st.floats(-math.pi, math.pi)
pose_st = st.tuples(coordinate, coordinate, heading)


def ros(stamp: float, x: float, y: float = 0.0, yaw: float = 0.0):
    return decode_odometry(encode_odometry(stamp, (x, y, yaw)))


@settings(max_examples=200, deadline=None)
@given(st.lists(pose_st, min_size=2, max_size=12))
def test_composing_the_increments_reproduces_every_pose(poses):
    """The filter's motion model over the differenced increments walks the base's own poses."""
    x = np.array(poses[0], dtype=float)
    for before, after in pairwise(poses):
        x, _f = motion(x, body_increment(before, after))
        assert x[0] == pytest.approx(after[0], abs=1e-9)
        assert x[1] == pytest.approx(after[1], abs=1e-9)
        assert math.remainder(x[2] - after[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=100, deadline=None)
@given(pose_st, st.floats(-0.2, 0.2), st.floats(-0.1, 0.1), st.floats(0.02, 0.2))
def test_a_step_the_base_can_make_is_its_increment_stamped_by_the_headers(start, v, w, dt):
    x, y, yaw = start
    end = (x + v * dt * math.cos(yaw), y + v * dt * math.sin(yaw), yaw + w * dt)
    ref = ros(100.0, *start)
    msg = ros(100.0 + dt, *end)
    inc = ros_increment(ref, msg, SPEED, TURN)
    assert inc is not None
    assert (inc.since, inc.stamp) == (ref.stamp, msg.stamp)
    assert (inc.dx, inc.dy, inc.dtheta) == pytest.approx(
        body_increment((ref.x, ref.y, ref.yaw), (msg.x, msg.y, msg.yaw)))
    assert inc.dx == pytest.approx(v * dt, abs=1e-6) and inc.dy == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("end", [(0.5, 0.0, 0.0),  # 0.5 m in 50 ms: a reset or a jump
                                 (0.0, 0.0, 1.0)])  # 1 rad in 50 ms
def test_a_move_faster_than_the_base_can_is_no_increment(end):
    assert ros_increment(ros(10.0, 0.0), ros(10.0 + DT, *end), SPEED, TURN) is None


def test_the_first_pose_is_the_reference_and_a_jump_re_references_counted():
    r = RosOdom(SPEED, TURN)
    first = r.step(ros(5.0, 3.0, 1.0, 0.5))
    assert first is not None and (first.dx, first.dy, first.dtheta) == (0.0, 0.0, 0.0)
    assert first.since == first.stamp == pytest.approx(5.0)
    assert r.step(ros(5.0 + DT, -7.0, 0.0)) is None and r.jumps == 1  # the odometry reset
    after = r.step(ros(5.0 + 2 * DT, -6.99, 0.0))  # measured from the new reference
    assert after is not None and after.dx == pytest.approx(0.01) and r.jumps == 1


def fused(start=(0.0, 0.0, 0.0)) -> OdomIn:
    loc = OdomIn("a1", "warehouse", start, DT, lockstep=False)
    loc.use_ros_base("a1/odom", SPEED, TURN)
    return loc


def test_a_ros_base_odometry_moves_the_estimate_and_grows_its_radius():
    loc = fused()
    assert loc.odom_key == "a1/odom"
    assert loc.on_odom(encode_odometry(20.0, (4.0, 4.0, 0.0))) == Pose(0.0, 0.0, 0.0, 20.0)
    loc.on_camera(encode(Pose(0.0, 0.0, 0.0, 20.0)))
    pose = loc.on_odom(encode_odometry(20.0 + DT, (4.0, 4.0, 0.0)))
    assert pose is not None and (pose.x, pose.y) == pytest.approx((0.0, 0.0), abs=1e-3)
    radius = loc.radius
    for k in range(2, 22):  # 0.2 m/s along the odometry frame's x: the robot's heading too
        pose = loc.on_odom(encode_odometry(20.0 + k * DT, (4.0 + 0.01 * (k - 1), 4.0, 0.0)))
    assert pose is not None and pose.stamp == pytest.approx(20.0 + 21 * DT)
    assert (pose.x, pose.y) == pytest.approx((0.2, 0.0), abs=1e-6)
    assert loc.radius > radius  # odometry alone: the uncertainty grows
    assert loc.stats()["odom_jumps"] == 0


def test_malformed_non_finite_older_and_jumping_odometry_is_dropped_and_counted():
    loc = fused()
    loc.on_odom(encode_odometry(1.0, (0.0, 0.0, 0.0)))
    good = encode_odometry(1.0 + DT, (0.01, 0.0, 0.0))
    y_at = len(good) - 8 * 84  # pose (3), orientation (4), 36 covariances, twist (6), 36
    non_finite = good[:y_at] + np.float64(math.nan).tobytes() + good[y_at + 8:]
    for bad in (b"\x00\x01\x00\x00", good[:-8], non_finite, encode(Pose(0.0, 0.0, 0.0, 1.0))):
        assert loc.on_odom(bad) is None
    assert loc.dropped["odom"] == 4
    assert loc.on_odom(encode_odometry(1.0, (0.0, 0.0, 0.0))) is None and loc.older == 1
    assert loc.on_odom(encode_odometry(1.0 + DT, (3.0, 0.0, 0.0))) is None
    stats = loc.stats()
    assert stats["odom_jumps"] == 1 and stats["dropped"]["odom"] == 4 and stats["older"] == 1


def test_world_odometry_stats_keep_their_shape():
    loc = OdomIn("a1", "warehouse", (0.0, 0.0, 0.0), DT, lockstep=True)
    assert "odom_jumps" not in loc.stats() and loc.odom_key == "warehouse/robot/a1/odom"


def test_encode_odometry_is_what_decode_odometry_reads():
    got = decode_odometry(encode_odometry(12.5, (1.5, -0.25, 0.3), (0.2, 0.5), "o", "base"))
    assert (got.frame_id, got.child_frame_id, got.x, got.y, got.vx, got.wz) == (
        "o", "base", 1.5, -0.25, 0.2, 0.5)
    assert got.yaw == pytest.approx(0.3) and got.stamp == pytest.approx(12.5)


def test_the_base_odom_key_over_the_bridge_and_over_rmw_zenoh():
    bridge = SimpleNamespace(base="turtlebot3-humble", cmd_vel_key="a1/cmd_vel", rmw=None)
    assert base_odom_key(bridge) == "a1/odom"
    assert base_odom_key(SimpleNamespace(base="turtlebot3-jazzy", cmd_vel_key="cmd_vel")) == "odom"
    s = RmwSettings(namespace="a1")
    over_rmw = SimpleNamespace(base="turtlebot3-jazzy", cmd_vel_key="cmd_vel", rmw=s)
    assert base_odom_key(over_rmw) == odom_data_key(s, "jazzy")
    with pytest.raises(ValueError, match="odom topic"):
        base_odom_key(SimpleNamespace(base="world"))


def test_the_base_limits_are_the_burgers_or_the_controllers_where_larger():
    assert base_limits(SimpleNamespace(control=None)) == (SPEED, TURN)
    faster = SimpleNamespace(control=SimpleNamespace(max_speed=0.26, max_turn_rate=1.0))
    assert base_limits(faster) == (0.26, TURN)
