"""Robot base adapters: byte-exact CDR of Twist / TwistStamped, clamping, make_base."""

from __future__ import annotations

import math
import struct
from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from agent import base as b

HEADER = bytes([0x00, 0x01, 0x00, 0x00])


def f64(x: float) -> bytes:
    return struct.pack("<d", x)


def test_twist_is_header_plus_six_little_endian_doubles() -> None:
    payload = b.encode_twist(b.Twist(linear=(0.1, 0.0, 0.0), angular=(0.0, 0.0, -0.5)))
    # 0.1 = 0x3FB999999999999A, -0.5 = 0xBFE0000000000000, stored little endian.
    expected = (
        HEADER
        + bytes.fromhex("9a9999999999b93f")
        + bytes(8) * 4
        + bytes.fromhex("000000000000e0bf")
    )
    assert len(payload) == 4 + 48
    assert payload == expected


def test_twist_stamped_with_base_link_pads_two_bytes_before_the_doubles() -> None:
    twist = b.Twist(linear=(0.1, 0.0, 0.0), angular=(0.0, 0.0, -0.5))
    payload = b.encode_twist_stamped(b.TwistStamped(7, 500, "base_link", twist))
    # body offsets: sec 0..4, nanosec 4..8, length 8..12 (= 10: 9 chars + NUL),
    # chars 12..21, NUL 21..22, padding 22..24 (to 8), doubles 24..72.
    expected = (
        HEADER
        + bytes([7, 0, 0, 0])
        + bytes([0xF4, 0x01, 0, 0])
        + bytes([10, 0, 0, 0])
        + b"base_link\x00"
        + b"\x00\x00"
        + f64(0.1) + f64(0.0) * 4 + f64(-0.5)
    )
    assert len(payload) == 4 + 72
    assert payload == expected


def test_twist_stamped_with_empty_frame_id_pads_three_bytes() -> None:
    payload = b.encode_twist_stamped(b.TwistStamped(0, 0, "", b.Twist()))
    # length 8..12 (= 1: only the NUL), NUL 12..13, padding 13..16, doubles 16..64.
    expected = HEADER + bytes(8) + bytes([1, 0, 0, 0]) + b"\x00" + bytes(3) + bytes(48)
    assert len(payload) == 4 + 64
    assert payload == expected


def test_twist_stamped_with_frame_id_ending_on_a_boundary_needs_no_padding() -> None:
    # 11 chars + NUL = 12 bytes from offset 12 -> 24, already a multiple of 8.
    payload = b.encode_twist_stamped(b.TwistStamped(1, 2, "abcdefghijk", b.Twist()))
    assert len(payload) == 4 + 24 + 48
    assert payload[4 + 12 : 4 + 24] == b"abcdefghijk\x00"


def test_humble_cmd_vel_is_a_twist_with_only_linear_x_and_angular_z() -> None:
    payload = b.encode_cmd_vel(b.HUMBLE, 0.1, -0.5, 12.25)
    assert payload == b.encode_twist(b.Twist((0.1, 0.0, 0.0), (0.0, 0.0, -0.5)))


def test_jazzy_cmd_vel_carries_the_stamp_and_base_link() -> None:
    msg = b.decode_twist_stamped(b.encode_cmd_vel(b.JAZZY, 0.1, -0.5, 12.25))
    assert (msg.sec, msg.nanosec, msg.frame_id) == (12, 250_000_000, "base_link")
    assert msg.twist == b.Twist((0.1, 0.0, 0.0), (0.0, 0.0, -0.5))


def test_commands_are_clamped_to_burger_limits() -> None:
    t = b.decode_twist(b.encode_cmd_vel(b.HUMBLE, 1.0, -10.0, 0.0))
    assert t.linear[0] == pytest.approx(0.22) and t.angular[2] == pytest.approx(-2.84)
    t = b.decode_twist(b.encode_cmd_vel(b.HUMBLE, -1.0, 10.0, 0.0))
    assert t.linear[0] == pytest.approx(-0.22) and t.angular[2] == pytest.approx(2.84)


def test_non_finite_commands_become_a_stop() -> None:
    assert b.clamp_command(math.nan, 1.0) == (0.0, 0.0)
    assert b.clamp_command(0.1, math.inf) == (0.0, 0.0)


def test_invalid_stamp_becomes_zero_time() -> None:
    assert b.stamp_to_time(math.nan) == (0, 0)
    assert b.stamp_to_time(1e12) == (0, 0)
    assert b.stamp_to_time(3.9999999999995) == (3, 999_999_999)  # never nanosec = 1e9
    assert b.stamp_to_time(-1.25) == (-2, 750_000_000)


@pytest.mark.parametrize("bad", [b"", b"\x00\x00\x00\x00" + bytes(48), HEADER + bytes(47)])
def test_decoders_reject_malformed_payloads(bad: bytes) -> None:
    with pytest.raises(ValueError):
        b.decode_twist(bad)
    with pytest.raises(ValueError):
        b.decode_twist_stamped(bad)


def test_unknown_base_is_rejected_naming_it() -> None:
    with pytest.raises(ValueError, match="base"):
        b.encode_cmd_vel("turtlebot4", 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="base"):
        b.make_base(SimpleNamespace(base="turtlebot4"))


finite = st.floats(min_value=-10, max_value=10, allow_nan=False)
frames = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"),
                 max_size=20)


@given(v=finite, w=finite, stamp=st.floats(min_value=0, max_value=2e9), frame=frames)
def test_twist_stamped_round_trips(v: float, w: float, stamp: float, frame: str) -> None:
    payload = b.encode_cmd_vel(b.JAZZY, v, w, stamp, frame_id=frame)
    msg = b.decode_twist_stamped(payload)
    assert msg.frame_id == frame
    assert (len(payload) - 4) % 8 == 0  # the body ends with 8-aligned doubles
    assert (msg.twist.linear[0], msg.twist.angular[2]) == b.clamp_command(v, w)


@given(v=finite, w=finite)
def test_twist_round_trips(v: float, w: float) -> None:
    t = b.decode_twist(b.encode_cmd_vel(b.HUMBLE, v, w, 0.0))
    assert (t.linear[0], t.angular[2]) == b.clamp_command(v, w)
    assert abs(t.linear[0]) <= b.BURGER_MAX_SPEED and abs(t.angular[2]) <= b.BURGER_MAX_TURN_RATE


def test_world_base_forwards_commands_and_stops_with_zero() -> None:
    sent: list[tuple[float, float, float]] = []
    base = b.make_base(SimpleNamespace(base="world"), publish=lambda *a: sent.append(a))
    base.send(0.1, 0.2, 3.0)
    base.stop()
    assert sent == [(0.1, 0.2, 3.0), (0.0, 0.0, 3.0)]


class FakePublisher:
    def __init__(self) -> None:
        self.payloads: list[bytes] = []
        self.undeclared = False

    def put(self, payload: bytes) -> None:
        self.payloads.append(payload)

    def undeclare(self) -> None:
        self.undeclared = True


class FakeSession:
    def __init__(self) -> None:
        self.keys: list[str] = []
        self.publisher = FakePublisher()

    def declare_publisher(self, key: str) -> FakePublisher:
        self.keys.append(key)
        return self.publisher


def test_turtlebot_base_puts_cdr_on_cmd_vel_and_stops_with_zero() -> None:
    session = FakeSession()
    control = SimpleNamespace(max_speed=0.1, max_turn_rate=5.0)
    base = b.make_base(SimpleNamespace(base=b.HUMBLE, control=control), session,
                       cmd_vel_key="robot1/cmd_vel")
    base.send(0.2, 3.0, 1.0)
    base.stop()
    assert session.keys == ["robot1/cmd_vel"]
    first, last = (b.decode_twist(p) for p in session.publisher.payloads)
    assert first.linear[0] == pytest.approx(0.1)  # the scenario's tighter limit
    assert first.angular[2] == pytest.approx(2.84)  # never beyond the burger's
    assert last == b.Twist()
    assert session.publisher.undeclared


def test_turtlebot_base_needs_a_session() -> None:
    with pytest.raises(ValueError, match="session"):
        b.make_base(SimpleNamespace(base=b.JAZZY))


@pytest.mark.integration
def test_turtlebot_base_over_real_zenoh_delivers_the_cdr_bytes() -> None:
    import threading

    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    got: list[bytes] = []
    done = threading.Event()
    with zenoh.open(conf) as session:
        sub = session.declare_subscriber(
            "r1/cmd_vel", lambda s: (got.append(s.payload.to_bytes()), done.set()))
        base = b.make_base(SimpleNamespace(base=b.JAZZY), session, cmd_vel_key="r1/cmd_vel")
        base.send(0.1, -0.5, 5.5)
        assert done.wait(5.0)
        base.stop()
        sub.undeclare()
    msg = b.decode_twist_stamped(got[0])
    assert (msg.sec, msg.nanosec, msg.twist.linear[0]) == (5, 500_000_000, 0.1)
