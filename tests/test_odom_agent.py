"""The agent's side of ``controller.localisation: fused`` (agent.odom_in) and the world's
odometry out (simulator.odom_out), without Zenoh: the state's confidence radius on the wire,
the filter fed by odometry and late camera poses, a robot that waits unseen, malformed and
out-of-order odometry dropped and counted, one controller per margin; a ROS 2 base's
nav_msgs/Odometry decoded from a hand-built CDR payload."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest

from agent import margins
from agent.control import Controller, ControlParams
from agent.odom_in import HELD_SIGMA, HELD_WAITING, MarginControllers, OdomIn
from agent.qp import make_solver
from experiments.localisation_bench import QUICK_TICKS, bench_localisation, format_localisation
from scenario import load_scenario
from simulator.odom_out import OdomOut, capture_stamp
from wire.odom import Odom, decode_odom, encode_odom
from wire.payloads import STATE_SIGMA_VERSION, STATE_VERSION, Pose, State, decode_state, encode
from wire.reader import DecodeError
from wire.rmw_zenoh import RmwSettings, decode_odometry, odom_data_key

BLIND = Path(__file__).parent / "scenarios" / "blind-aisle.yaml"
START = (-4.5, 0.2, 0.0)
DT = 0.05


def odom(dx: float, since: float, stamp: float) -> bytes:
    return encode_odom(Odom(dx, 0.0, 0.0, since, stamp))


def camera(x: float, y: float, stamp: float) -> bytes:
    return encode(Pose(x, y, 0.0, stamp))


def test_a_state_without_sigma_stays_version_2_byte_for_byte_and_one_with_it_is_version_3():
    old = encode(State(1.0, 2.0, 0.1, 0.0, 3.0, 0.5))
    assert old[0] == STATE_VERSION and len(old) == 49
    new = encode(State(1.0, 2.0, 0.1, 0.0, 3.0, 0.5, 0.02))
    assert new[0] == STATE_SIGMA_VERSION and new[:1] + new[1:49] != old
    assert decode_state(new).sigma == 0.02 and decode_state(old).sigma is None


@pytest.mark.parametrize("sigma", [-0.1, math.nan, math.inf])
def test_a_state_with_a_bad_sigma_is_refused(sigma):
    with pytest.raises(ValueError, match="sigma"):
        State(1.0, 2.0, 0.1, 0.0, 3.0, 0.5, sigma)


def test_a_robot_unseen_waits_at_its_start_and_is_held_until_its_first_camera_pose():
    loc = OdomIn("p1", "warehouse", START, DT, lockstep=True)
    pose = loc.on_odom(odom(0.0, 0.0, 0.0))
    assert pose == Pose(*START, 0.0) and loc.held == HELD_WAITING
    assert loc.counts["waiting_ticks"] == 1 and loc.trace[-1][1] != loc.trace[-1][1]  # NaN
    loc.on_camera(camera(-4.49, 0.21, 0.0))
    pose = loc.on_odom(odom(0.01, 0.0, DT))  # the first pose starts the filter where it is
    assert loc.held is None and loc.filter.fused == 1
    assert pose is not None and pose.stamp == DT and pose.x == -4.49
    pose = loc.on_odom(odom(0.01, DT, 2 * DT))  # then the odometry moves it
    assert pose is not None and pose.x > -4.49
    assert 0.0 < loc.radius < margins.RADIUS_LIMIT
    assert loc.state(0.0, 0.0, (0.0, 0.0), DT, 0.0).sigma == loc.radius


def test_an_agent_restarted_mid_run_hands_no_pose_until_the_camera_sees_it():
    loc = OdomIn("p1", "warehouse", START, DT, lockstep=True)
    assert loc.on_odom(odom(0.01, 4.0, 4.0 + DT)) is None and loc.held == HELD_WAITING
    loc.on_camera(camera(1.0, 2.0, 4.0 + DT))
    pose = loc.on_odom(odom(0.01, 4.0 + DT, 4.0 + 2 * DT))
    assert pose is not None and pose.x == 1.0 and loc.held is None


def test_a_camera_pose_waits_for_the_odometry_of_its_capture_and_is_fused_once():
    loc = OdomIn("p1", "warehouse", START, DT, lockstep=True)
    loc.on_camera(camera(*START[:2], 0.0))
    loc.on_odom(odom(0.0, 0.0, 0.0))
    loc.on_camera(camera(-4.49, 0.2, 2 * DT))  # captured after the next odometry
    loc.on_odom(odom(0.01, 0.0, DT))
    assert loc.filter.fused == 1 and len(loc.pending) == 1
    loc.on_camera(camera(-4.49, 0.2, 2 * DT))  # the same frame again
    loc.on_odom(odom(0.0, DT, 2 * DT))
    assert loc.filter.fused == 2 and not loc.pending


def test_malformed_and_older_odometry_is_dropped_and_counted():
    loc = OdomIn("p1", "warehouse", START, DT, lockstep=False)
    assert loc.on_odom(b"\x07garbage") is None
    loc.on_camera(b"")
    assert loc.dropped == {"odom": 1, "pose": 1}
    assert loc.on_odom(odom(0.0, 1.0, 1.0)) is not None  # the run's first: at its start
    assert loc.on_odom(odom(0.0, 0.5, 1.0)) is None and loc.older == 1


def test_past_the_radius_limit_the_robot_is_held_and_counted():
    loc = OdomIn("p1", "warehouse", START, DT, lockstep=True)
    loc.on_camera(camera(*START[:2], 0.0))
    loc.on_odom(odom(0.0, 0.0, 0.0))
    t = 0.0
    while loc.held is None:  # driving blind: the radius grows with the distance
        t += DT
        loc.on_odom(odom(0.2, t - DT, t))
        assert t < 1000.0
    assert loc.held == HELD_SIGMA and loc.radius > margins.RADIUS_LIMIT
    assert loc.counts["over_limit_ticks"] == 1 and loc.stats()["max_sigma_m"] == loc.radius


def test_one_controller_per_margin_with_the_bounds_the_estimates_need():
    params = ControlParams.from_scenario(load_scenario(BLIND))
    base = Controller(params, make_solver("exact"), lambda: 0)
    cache = MarginControllers()
    a = cache.get(base, 0.0101, 0.02)
    assert a is cache.get(base, 0.0102, 0.0199)  # the same steps: the same bounds
    assert a.params.bounds == margins.localisation_bounds(params.bounds, 0.0101, 0.02)
    # radii that round alike but need different margins get different controllers
    assert cache.get(base, 0.0074, 0.0) is not cache.get(base, 0.0026, 0.0)
    assert margins.margin_steps(0.0074, 0.0) == 2 and margins.margin_steps(0.0026, 0.0) == 1


class Sink:
    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.sent.append(payload)


def test_the_world_publishes_zero_first_then_each_robots_seeded_increment():
    sc = load_scenario(BLIND)
    sinks = [Sink() for _ in sc.robots]
    out = OdomOut(sc, sinks)
    before = [r.start for r in sc.robots]
    out.publish(0.0, before, None)
    after = [(s[0] + 0.01, s[1], s[2]) for s in before]
    out.publish(DT, after, None)
    first, second = decode_odom(sinks[0].sent[0]), decode_odom(sinks[0].sent[1])
    assert (first.dx, first.since, first.stamp) == (0.0, 0.0, 0.0)
    scale = out.odometer.errors[0][0]
    assert second.dx == pytest.approx(0.01 * (1.0 + scale)) and second.since == 0.0
    assert second.stamp == DT and capture_stamp(None, 1, DT, 7.0) == 7.0


def test_a_malformed_odometry_payload_is_a_decode_error():
    with pytest.raises(DecodeError, match="odom"):
        decode_odom(b"\x01" + b"\x00" * 7)


def _cdr_string(body: bytearray, text: str) -> None:
    body += bytes((-len(body)) % 4)
    raw = text.encode() + b"\x00"
    body += struct.pack("<I", len(raw)) + raw


def hand_built_odometry(x: float, y: float, yaw: float, frame: str = "odom",
                        child: str = "base_footprint") -> bytes:
    """A nav_msgs/msg/Odometry CDR payload built by hand from the .msg layout: header (stamp
    12 s + 0.5 s, frame_id), child_frame_id, pose (position, quaternion, 36 covariances),
    twist (linear, angular, 36 covariances); doubles aligned to 8 from after the header."""
    body = bytearray(struct.pack("<iI", 12, 500_000_000))
    _cdr_string(body, frame)
    _cdr_string(body, child)
    body += bytes((-len(body)) % 8)
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    body += struct.pack("<3d4d36d", x, y, 0.0, *q, *([0.0] * 36))
    body += struct.pack("<6d36d", 0.2, 0.0, 0.0, 0.0, 0.0, 0.5, *([0.0] * 36))
    return b"\x00\x01\x00\x00" + bytes(body)


@pytest.mark.parametrize("frame", ["odom", "o", "tb3_0/odom_frame"])  # each string's padding
def test_a_ros2_base_odometry_payload_decodes(frame):
    got = decode_odometry(hand_built_odometry(1.5, -0.25, 0.3, frame))
    assert (got.frame_id, got.child_frame_id) == (frame, "base_footprint")
    assert (got.x, got.y, got.vx, got.wz) == (1.5, -0.25, 0.2, 0.5)
    assert got.yaw == pytest.approx(0.3) and got.stamp == pytest.approx(12.5)


@pytest.mark.parametrize("cut", [b"\x01\x00\x00\x00", 14, -8])
def test_a_malformed_ros2_odometry_payload_is_refused(cut):
    good = hand_built_odometry(0.0, 0.0, 0.0)
    bad = cut + good[4:] if isinstance(cut, bytes) else good[:cut]
    with pytest.raises(ValueError, match="Odometry"):
        decode_odometry(bad)


def test_the_odometry_topic_keys_of_a_base():
    s = RmwSettings(namespace="tb3_1")
    assert "/tb3_1/odom/nav_msgs::msg::dds_::Odometry_/" in odom_data_key(s, "jazzy")
    assert odom_data_key(s, "humble").endswith("TypeHashNotSupported")


def test_the_filter_bench_times_a_seen_and_a_blind_tick():
    r = bench_localisation(quick=True)["localisation"]
    assert r["ticks"] == QUICK_TICKS and r["blind_us_per_tick"] > 0.0
    assert r["seen_us_per_tick"] > r["blind_us_per_tick"]  # the late update on top
    assert "us/tick" in format_localisation({"localisation": r})
