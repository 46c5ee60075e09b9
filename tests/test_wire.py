"""Tests of wire/: key space, payload round trips and defensive decoding, the pinned byte
layouts, zenoh configuration building, traffic counters and the asyncio mailbox (no network)."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import math
import os
import threading

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from zenoh.ext import UInt8, z_deserialize, z_serialize

from wire import decoders, keys, payloads, traffic, zconf
from wire.payloads import (
    Cmd,
    DecodeError,
    EllipseMsg,
    ObstacleMsg,
    Obstacles,
    Others,
    Pose,
    State,
    decode_cmd,
    decode_ellipse,
    decode_obstacles,
    decode_others,
    decode_pose,
    decode_state,
    encode,
)
from wire.reader import decode_payload

# --- strategies -------------------------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False)
positive = st.floats(min_value=0.0, exclude_min=True, allow_infinity=False)
non_negative = st.floats(min_value=0.0, allow_infinity=False)
ids = st.text(
    alphabet=st.characters(categories=("L", "N"), include_characters="_-."),
    min_size=1,
    max_size=keys.MAX_ID_LEN,
)

poses = st.builds(Pose, finite, finite, finite, finite)
states = st.builds(State, finite, finite, finite, finite, finite, finite)
cmds = st.builds(Cmd, finite, finite, finite, finite, finite)


point_lists = st.lists(st.tuples(finite, finite), max_size=6).map(tuple)


@st.composite
def points_and_headings(draw: st.DrawFn) -> tuple[tuple, tuple]:
    """An ellipse's points, and none or one heading per point."""
    pts = draw(point_lists)
    hs = draw(st.just(()) | st.lists(finite, min_size=len(pts), max_size=len(pts)).map(tuple))
    return pts, hs


def ellipses_of(formation: st.SearchStrategy[str]) -> st.SearchStrategy[EllipseMsg]:
    return st.builds(
        lambda e, ph: dataclasses.replace(e, points=ph[0], headings=ph[1]),
        st.builds(EllipseMsg, formation, finite, finite, finite, positive, positive, finite,
                  finite, finite, finite),
        st.just(((), ())) | points_and_headings(),
    )


ellipses = ellipses_of(ids)


@st.composite
def others_msgs(draw: st.DrawFn) -> Others:
    formation = draw(ids)
    members = draw(
        st.lists(ellipses, max_size=6, unique_by=lambda e: e.formation).filter(
            lambda es: all(e.formation != formation for e in es)
        )
    )
    own = draw(st.none() | ellipses_of(st.just(formation)))
    return Others(formation=formation, stamp=draw(finite), ellipses=tuple(members), own=own)


obstacle_items = st.builds(ObstacleMsg, ids, finite, finite, finite, finite, non_negative)
obstacles_msgs = st.builds(
    Obstacles, finite, st.lists(obstacle_items, max_size=6, unique_by=lambda o: o.id).map(tuple)
)

DECODERS = {
    Pose: decode_pose,
    State: decode_state,
    Cmd: decode_cmd,
    EllipseMsg: decode_ellipse,
    Others: decode_others,
    Obstacles: decode_obstacles,
}
ALL_DECODERS = list(DECODERS.values())
any_message = st.one_of(poses, states, cmds, ellipses, others_msgs(), obstacles_msgs)

E_A = EllipseMsg("A", 1.0, 2.0, 0.0, 0.5, 0.25, 1.0, 0.0, -1.0, 3.0)
E_B = EllipseMsg("B", 1.0, 2.0, 0.0, 0.5, 0.25, 1.0, 0.0, -1.0, 3.0)
E_A2 = dataclasses.replace(E_A, points=((1.0, 2.0), (0.5, -1.0)), headings=(0.25, 3.0))  # v2
EXAMPLES = [
    Pose(1.0, 2.0, 0.5, 3.0),
    State(1.0, 2.0, 0.5, -1.0, 3.0),
    Cmd(0.5, -1.0, 1.0, 0.0, 4.0),
    E_A,
    Others("B", 4.0, (E_A,), E_B),
    Obstacles(3.0, (ObstacleMsg("o1", 1.0, 2.0, 0.0, -1.0, 0.5),)),
    E_A2,
    Others("B", 4.0, (E_A2,), E_B),
]

# --- round trips ------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(msg=any_message)
def test_every_payload_survives_a_round_trip(msg: payloads.Message) -> None:
    data = encode(msg)
    assert DECODERS[type(msg)](data) == msg
    assert DECODERS[type(msg)](zenoh.ZBytes(data)) == msg
    assert DECODERS[type(msg)](bytearray(data)) == msg


@given(msg=states)
def test_round_trip_preserves_every_float_bit_for_bit(msg: State) -> None:
    back = decode_state(encode(msg))
    for name in ("x", "y", "ux", "uy", "stamp"):
        assert math.copysign(1.0, getattr(back, name)) == math.copysign(1.0, getattr(msg, name))
        assert getattr(back, name) == getattr(msg, name)


def test_encode_zbytes_is_the_same_bytes_as_encode() -> None:
    for msg in EXAMPLES:
        assert payloads.encode_zbytes(msg).to_bytes() == encode(msg)


def test_integer_fields_are_stored_as_floats() -> None:
    pose = Pose(1, 2, 0, 5)
    assert all(type(v) is float for v in (pose.x, pose.y, pose.theta, pose.stamp))
    assert encode(pose) == encode(Pose(1.0, 2.0, 0.0, 5.0))


def test_others_without_an_own_ellipse_round_trips() -> None:
    msg = Others("B", 1.0, (E_A,), None)
    assert decode_others(encode(msg)) == msg


# --- pinned byte layouts (zenoh serialization format) -------------------------------------------

# f64 little-endian IEEE 754, written out by hand:
F1, F2, F05, F3, F4, F025, FM1, F0 = (
    "000000000000f03f",  # 1.0
    "0000000000000040",  # 2.0
    "000000000000e03f",  # 0.5
    "0000000000000840",  # 3.0
    "0000000000001040",  # 4.0
    "000000000000d03f",  # 0.25
    "000000000000f0bf",  # -1.0
    "0000000000000000",  # 0.0
)
V1 = "01"  # u8 wire version
ELLIPSE_A = "01" + "41" + F1 + F2 + F0 + F05 + F025 + F1 + F0 + FM1 + F3  # str "A", 9 f64
ELLIPSE_B = "01" + "42" + F1 + F2 + F0 + F05 + F025 + F1 + F0 + FM1 + F3  # str "B", 9 f64

PINNED = [
    (EXAMPLES[0], V1 + F1 + F2 + F05 + F3, 33),
    (EXAMPLES[1], "02" + F1 + F2 + F05 + FM1 + F0 + F3, 49),  # state v2: theta before the stamp
    (EXAMPLES[2], V1 + F05 + FM1 + F1 + F0 + F4, 41),
    (EXAMPLES[3], V1 + ELLIPSE_A, 75),
    # version, formation "B", stamp 4.0, list of 1 ellipse, own as a list of 1 ellipse
    (EXAMPLES[4], V1 + "0142" + F4 + "01" + ELLIPSE_A + "01" + ELLIPSE_B, 1 + 2 + 8 + 1 + 74 * 2 + 1),
    # version, stamp 3.0, list of 1 obstacle: id "o1", x, y, vx, vy, ds
    (EXAMPLES[5], V1 + F3 + "01" + "026f31" + F1 + F2 + F0 + FM1 + F05, 1 + 8 + 1 + 3 + 40),
    # version 2: the ellipse, then its points as a list of (x, y), then their headings
    (EXAMPLES[6], "02" + ELLIPSE_A + "02" + F1 + F2 + F05 + FM1 + "02" + F025 + F3,
     75 + 1 + 32 + 1 + 16),
    # version 2 others: every ellipse with its points and headings lists (the own one's empty)
    (EXAMPLES[7], "02" + "0142" + F4 + "01" + ELLIPSE_A + "02" + F1 + F2 + F05 + FM1 + "02" + F025
     + F3 + "01" + ELLIPSE_B + "00" + "00", 1 + 2 + 8 + 1 + 74 + 33 + 17 + 1 + 74 + 2),
]


@pytest.mark.parametrize(("msg", "hex_layout", "size"), PINNED, ids=lambda v: type(v).__name__)
def test_each_payload_has_the_hand_written_byte_layout(
    msg: payloads.Message, hex_layout: str, size: int
) -> None:
    expected = bytes.fromhex(hex_layout)
    assert len(expected) == size
    assert encode(msg) == expected
    assert DECODERS[type(msg)](expected) == msg


def test_a_string_longer_than_127_bytes_has_a_two_byte_length_varint() -> None:
    msg = Obstacles(0.0, (ObstacleMsg("o" * 64, 0.0, 0.0, 0.0, 0.0, 0.0),))
    assert encode(msg)[9:12] == bytes([1, 64, ord("o")])  # count 1, len 64 (< 128: one byte)
    long_name = "é" * 64  # 128 UTF-8 bytes: LEB128 0x80 0x01
    msg = Obstacles(0.0, (ObstacleMsg(long_name, 0.0, 0.0, 0.0, 0.0, 0.0),))
    assert encode(msg)[10:12] == b"\x80\x01"
    assert decode_obstacles(encode(msg)) == msg


_E = tuple[str, float, float, float, float, float, float, float, float, float]
_E2 = tuple[str, float, float, float, float, float, float, float, float, float,
            list[tuple[float, float]], list[float]]
REFERENCE_TYPES = {
    Pose: tuple[UInt8, float, float, float, float],
    State: tuple[UInt8, float, float, float, float, float, float],
    Cmd: tuple[UInt8, float, float, float, float, float],
    EllipseMsg: tuple[UInt8, str, float, float, float, float, float, float, float, float, float],
    Others: tuple[UInt8, str, float, list[_E], list[_E]],
    Obstacles: tuple[UInt8, float, list[tuple[str, float, float, float, float, float]]],
}
REFERENCE_TYPES_V2 = {  # an ellipse with points, an others any of whose ellipses has them
    EllipseMsg: tuple[UInt8, str, float, float, float, float, float, float, float, float, float,
                      list[tuple[float, float]], list[float]],
    Others: tuple[UInt8, str, float, list[_E2], list[_E2]],
}


def _with_points(msg: object) -> bool:
    if isinstance(msg, EllipseMsg):
        return bool(msg.points)
    if isinstance(msg, Others):
        return any(e.points for e in msg.ellipses) or (msg.own is not None and bool(msg.own.points))
    return False


def _ellipse_fields(e: EllipseMsg, v2: bool) -> tuple[object, ...]:
    base = tuple(getattr(e, f) for f in EllipseMsg.__dataclass_fields__
                 if f not in ("points", "headings", "sigma", "parked"))
    return (*base, list(e.points), list(e.headings)) if v2 else base


def _fields(msg: object) -> tuple[object, ...]:
    if isinstance(msg, EllipseMsg):
        return _ellipse_fields(msg, _with_points(msg))
    if isinstance(msg, Others):
        v2 = _with_points(msg)
        own = [] if msg.own is None else [_ellipse_fields(msg.own, v2)]
        return (msg.formation, msg.stamp, [_ellipse_fields(e, v2) for e in msg.ellipses], own)
    if isinstance(msg, Obstacles):
        return (msg.stamp, [tuple(getattr(o, f) for f in ObstacleMsg.__dataclass_fields__)
                            for o in msg.obstacles])
    if isinstance(msg, State):  # wire order: the heading before the stamp
        return (msg.x, msg.y, msg.ux, msg.uy, msg.theta, msg.stamp)
    if isinstance(msg, Cmd):  # version 1: no acceleration (tests/test_double_integrator.py: 2)
        return (msg.v, msg.omega, msg.ux, msg.uy, msg.stamp)
    return tuple(getattr(msg, f) for f in type(msg).__dataclass_fields__)  # type: ignore[attr-defined]


@settings(max_examples=100, deadline=None)
@given(msg=any_message)
def test_zenohs_own_deserializer_reads_what_we_write(msg: payloads.Message) -> None:
    # the reference reader, on valid payloads only (it can abort the process on hostile ones)
    v2 = _with_points(msg)
    types = REFERENCE_TYPES_V2 if v2 else REFERENCE_TYPES
    got = z_deserialize(types[type(msg)], zenoh.ZBytes(encode(msg)))
    assert got == (2 if isinstance(msg, State) or v2 else 1, *_fields(msg))


# --- defensive decoding -----------------------------------------------------------------------


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_truncation_at_every_byte_position_raises_decode_error(msg: payloads.Message) -> None:
    data = encode(msg)
    decode = DECODERS[type(msg)]
    for cut in range(len(data)):
        with pytest.raises(DecodeError):
            decode(data[:cut])


@settings(max_examples=100, deadline=None)
@given(msg=any_message, data=st.data())
def test_truncated_payloads_of_any_message_raise_only_decode_error(
    msg: payloads.Message, data: st.DataObject
) -> None:
    encoded = encode(msg)
    cut = data.draw(st.integers(min_value=0, max_value=len(encoded) - 1))
    with pytest.raises(DecodeError):
        DECODERS[type(msg)](encoded[:cut])


@settings(max_examples=300, deadline=None)
@given(blob=st.binary(max_size=300) | st.binary(max_size=300).map(lambda b: b"\x01" + b))
def test_random_bytes_never_raise_anything_but_decode_error(blob: bytes) -> None:
    for decode in ALL_DECODERS:
        try:
            decode(blob)
        except DecodeError:
            pass


@settings(max_examples=200, deadline=None)
@given(msg=any_message, data=st.data())
def test_a_corrupted_byte_either_decodes_to_a_valid_message_or_raises_decode_error(
    msg: payloads.Message, data: st.DataObject
) -> None:
    encoded = bytearray(encode(msg))
    index = data.draw(st.integers(min_value=0, max_value=len(encoded) - 1))
    encoded[index] = data.draw(st.integers(min_value=0, max_value=255))
    try:
        back = DECODERS[type(msg)](bytes(encoded))
    except DecodeError:
        return
    assert encode(back) == bytes(encoded)


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_trailing_bytes_are_rejected(msg: payloads.Message) -> None:
    with pytest.raises(DecodeError, match="trailing"):
        DECODERS[type(msg)](encode(msg) + b"\x00")


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_an_unknown_version_is_rejected(msg: payloads.Message) -> None:
    data = bytearray(encode(msg))
    data[0] = 9  # (2 is an Obstacles with walls and shelves)
    with pytest.raises(DecodeError, match="version 9"):
        DECODERS[type(msg)](bytes(data))


@pytest.mark.parametrize("bad", [None, 7, "text", 1.5, [1, 2]])
def test_a_payload_of_the_wrong_python_type_raises_decode_error(bad: object) -> None:
    for decode in ALL_DECODERS:
        with pytest.raises(DecodeError):
            decode(bad)  # type: ignore[arg-type]


def test_a_payload_of_another_kind_is_rejected() -> None:
    for msg in EXAMPLES:
        for kind, decode in DECODERS.items():
            if kind is type(msg):
                continue
            with pytest.raises(DecodeError):
                decode(encode(msg))


def test_state_version_2_carries_the_heading_and_a_version_1_decoder_refuses_it_clearly() -> None:
    new = State(1.0, 2.0, 0.1, 0.0, 3.0, theta=1.25)
    data = encode(new)
    assert data[0] == payloads.STATE_VERSION == 2
    assert decode_state(data) == new
    # The decoder of the previous release: version byte 1 and five floats.
    def old_decoder(payload: bytes) -> State:
        return decode_payload(payload, lambda r: State(*r.floats(5, "state")), "state", 1)

    with pytest.raises(DecodeError, match="state: unsupported version 2 \\(expected 1\\)"):
        old_decoder(data)
    # ... and this decoder refuses an old five-float state instead of misreading it.
    v1 = z_serialize((UInt8(1), 1.0, 2.0, 0.1, 0.0, 3.0)).to_bytes()
    assert old_decoder(v1) == State(1.0, 2.0, 0.1, 0.0, 3.0)
    with pytest.raises(DecodeError, match="state: unsupported version 1 \\(expected 2 or 3\\)"):
        decode_state(v1)


FLOAT_FIELDS = {
    Pose: 4,
    State: 6,
    Cmd: 5,
}


@pytest.mark.parametrize("kind", [Pose, State, Cmd], ids=lambda k: k.__name__)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_non_finite_numbers_in_any_field_are_rejected_on_the_wire(kind: type, bad: float) -> None:
    count = FLOAT_FIELDS[kind]
    for index in range(count):
        values = [1.0] * count
        values[index] = bad
        version = payloads.STATE_VERSION if kind is State else 1
        payload = z_serialize((UInt8(version), *values)).to_bytes()
        with pytest.raises(DecodeError, match="finite"):
            DECODERS[kind](payload)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_non_finite_numbers_in_nested_messages_are_rejected_on_the_wire(bad: float) -> None:
    for index in range(9):
        values = [1.0] * 9
        values[index] = bad
        ellipse = ("A", *values)
        with pytest.raises(DecodeError):
            decode_ellipse(z_serialize((UInt8(1), *ellipse)).to_bytes())
        with pytest.raises(DecodeError):
            decode_others(z_serialize((UInt8(1), "B", 0.0, [ellipse], [])).to_bytes())
    for index in range(5):
        values = [1.0] * 5
        values[index] = bad
        with pytest.raises(DecodeError):
            decode_obstacles(z_serialize((UInt8(1), 0.0, [("o1", *values)])).to_bytes())
    with pytest.raises(DecodeError):
        decode_obstacles(z_serialize((UInt8(1), bad, [])).to_bytes())


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_constructing_a_message_with_a_non_finite_number_names_the_field(bad: float) -> None:
    with pytest.raises(ValueError, match="^theta must be finite"):
        Pose(0.0, 0.0, bad, 0.0)
    with pytest.raises(ValueError, match="^alpha_rate must be finite"):
        EllipseMsg("A", 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, bad, 0.0)
    with pytest.raises(ValueError, match="^ds must be finite"):
        ObstacleMsg("o1", 0.0, 0.0, 0.0, 0.0, bad)
    with pytest.raises(ValueError, match="^stamp must be finite"):
        Obstacles(bad, ())


def test_field_types_and_ranges_are_checked_on_construction() -> None:
    with pytest.raises(ValueError, match="^x must be a real number"):
        State("1", 0.0, 0.0, 0.0, 0.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="^y must be a real number"):
        State(0.0, True, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="^a must be > 0"):
        EllipseMsg("A", 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="^b must be > 0"):
        EllipseMsg("A", 0.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="^ds must be >= 0"):
        ObstacleMsg("o1", 0.0, 0.0, 0.0, 0.0, -0.1)


def test_others_keeps_its_own_ellipse_apart_from_the_others() -> None:
    with pytest.raises(ValueError, match="own belongs to formation 'A'"):
        Others("B", 0.0, (), E_A)
    with pytest.raises(ValueError, match="must not contain the own formation"):
        Others("A", 0.0, (E_A,), None)
    with pytest.raises(ValueError, match="repeat formation 'A'"):
        Others("B", 0.0, (E_A, E_A), None)
    with pytest.raises(ValueError, match="repeat id 'o1'"):
        Obstacles(0.0, (ObstacleMsg("o1", 0, 0, 0, 0, 0), ObstacleMsg("o1", 1, 1, 0, 0, 0)))


def _wire(*fields: object) -> bytes:
    return z_serialize((UInt8(1), *fields)).to_bytes()


def test_every_rule_of_others_and_obstacles_holds_for_decoded_payloads_too() -> None:
    """The decoders check whole lists at once and skip the per-item constructor checks when all
    pass; a payload breaking any rule still fails, with the constructor's message."""
    a = ("A", 1.0, 2.0, 0.0, 0.5, 0.25, 1.0, 0.0, -1.0, 3.0)
    c = ("C", 5.0, 2.0, 0.0, 0.5, 0.25, 1.0, 0.0, -1.0, 3.0)
    cases = [
        (decode_others, _wire("B", 0.0, [a, a], []), "repeat formation 'A'"),
        (decode_others, _wire("A", 0.0, [a], []), "must not contain the own formation"),
        (decode_others, _wire("B", 0.0, [c], [a]), "own belongs to formation 'A'"),
        (decode_others, _wire("A", 0.0, [c], [a, a]), "own must hold at most 1"),
        (decode_others, _wire("B", 0.0, [(*a[:4], 0.0, *a[5:])], []), "a must be > 0"),
        (decode_others, _wire("B", 0.0, [(*a[:5], -1.0, *a[6:])], []), "b must be > 0"),
        (decode_others, _wire("B", 0.0, [("bad id", *a[1:])], []), "formation"),
        (decode_others, _wire("B", math.nan, [a], []), "stamp"),
        (decode_ellipse, _wire(*a[:4], -0.5, *a[5:]), "a must be > 0"),
        (decode_obstacles, _wire(0.0, [("o1", 0.0, 0.0, 0.0, 0.0, -0.1)]), "ds must be >= 0"),
        (decode_obstacles, _wire(0.0, [("o1", 0.0, 0.0, 0.0, 0.0, 0.1)] * 2), "repeat id 'o1'"),
        (decode_obstacles, _wire(math.inf, []), "stamp"),
    ]
    for decode, payload, message in cases:
        with pytest.raises(DecodeError, match=message):
            decode(payload)
    # and the same lists, valid, decode to messages equal to the constructed ones and as frozen
    got = decode_others(_wire("B", 0.0, [a, c], [("B", *a[1:])]))
    want = Others("B", 0.0, (EllipseMsg(*a), EllipseMsg(*c)), EllipseMsg("B", *a[1:]))
    assert got == want and hash(got) == hash(want)
    with pytest.raises(AttributeError):
        got.ellipses[0].cx = 0.0  # type: ignore[misc]
    obstacles = decode_obstacles(_wire(1.0, [("o1", 0.0, 0.0, 0.0, 0.0, 0.1)]))
    assert obstacles == Obstacles(1.0, (ObstacleMsg("o1", 0.0, 0.0, 0.0, 0.0, 0.1),))
    with pytest.raises(AttributeError):
        obstacles.obstacles[0].ds = 1.0  # type: ignore[misc]


def test_more_than_256_entries_are_rejected_when_built_and_when_decoded() -> None:
    many = [ObstacleMsg(f"o{i}", 0.0, 0.0, 0.0, 0.0, 0.1) for i in range(payloads.MAX_ITEMS + 1)]
    with pytest.raises(ValueError, match="at most 256"):
        Obstacles(0.0, tuple(many))
    wire = z_serialize(
        (UInt8(1), 0.0, [(o.id, o.x, o.y, o.vx, o.vy, o.ds) for o in many])
    ).to_bytes()
    with pytest.raises(DecodeError, match="at most 256"):
        decode_obstacles(wire)
    ellipse = ("A", 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    wire = z_serialize((UInt8(1), "B", 0.0, [ellipse] * 257, [])).to_bytes()
    with pytest.raises(DecodeError, match="at most 256"):
        decode_others(wire)
    own_b = ("B", *ellipse[1:])
    wire = z_serialize((UInt8(1), "B", 0.0, [], [own_b, own_b])).to_bytes()
    with pytest.raises(DecodeError, match="own must hold at most 1"):
        decode_others(wire)


def test_an_absurd_element_count_fails_fast_without_allocating() -> None:
    # version, stamp, then a LEB128 count of 2**62 with nothing after it
    wire = b"\x01" + bytes(8) + b"\x80\x80\x80\x80\x80\x80\x80\x80\x40"
    with pytest.raises(DecodeError):
        decode_obstacles(wire)


def test_the_largest_valid_message_fits_under_the_payload_limit() -> None:
    def big(formation: str) -> EllipseMsg:
        return EllipseMsg(formation, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0,
                          ((0.5, -0.5),) * payloads.MAX_POINTS, (1.5,) * payloads.MAX_POINTS)

    own_id = "\U0001F916" * keys.MAX_ID_LEN  # 4 UTF-8 bytes per character
    others = tuple(big(f"{i:03d}" + "\U0001F916" * 61) for i in range(payloads.MAX_ITEMS))
    msg = Others(own_id, 0.0, others, big(own_id))
    data = encode(msg)
    assert len(data) <= payloads.MAX_PAYLOAD_BYTES
    assert decode_others(data) == msg


def test_an_oversized_payload_is_rejected_before_parsing() -> None:
    with pytest.raises(DecodeError, match="exceeds"):
        decode_obstacles(b"\x01" + bytes(payloads.MAX_PAYLOAD_BYTES))


def leb128(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


@pytest.mark.parametrize("claimed", [2**35, 2**42, 2**63, 100])
def test_a_hostile_string_length_is_rejected_without_allocating_it(claimed: int) -> None:
    # zenoh-python 1.10's z_deserialize aborts the process on the 2**35 case; ours must not
    with pytest.raises(DecodeError, match="truncated"):
        decode_ellipse(b"\x01" + leb128(claimed) + b"abc")
    with pytest.raises(DecodeError, match="truncated"):
        decode_others(b"\x01" + leb128(claimed))
    with pytest.raises(DecodeError, match="truncated"):
        decode_obstacles(b"\x01" + bytes(8) + b"\x01" + leb128(claimed))


def test_an_over_long_varint_is_rejected() -> None:
    with pytest.raises(DecodeError, match="longer than 10 bytes"):
        decode_obstacles(b"\x01" + bytes(8) + b"\xff" * 11)


def test_a_non_canonical_length_varint_is_rejected() -> None:
    # an empty obstacle list written as the two-byte varint 0x80 0x00 instead of 0x00
    wire = b"\x01" + bytes(8) + b"\x80\x00"
    with pytest.raises(DecodeError, match="non-canonical"):
        decode_obstacles(wire)


@pytest.mark.parametrize("bad_id", ["", "a/b", "a*", "$x", "#1", "a?", "a b", "tab\t", "x" * 65])
def test_invalid_ids_are_rejected_on_the_wire_and_on_construction(bad_id: str) -> None:
    with pytest.raises(ValueError, match="formation"):
        EllipseMsg(bad_id, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    ellipse = (bad_id, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(DecodeError, match="invalid message"):
        decode_ellipse(z_serialize((UInt8(1), *ellipse)).to_bytes())
    with pytest.raises(DecodeError, match="invalid message"):
        decode_others(z_serialize((UInt8(1), bad_id, 0.0, [], [])).to_bytes())
    with pytest.raises(DecodeError, match="invalid message"):
        decode_obstacles(z_serialize((UInt8(1), 0.0, [(bad_id, 0.0, 0.0, 0.0, 0.0, 0.0)])).to_bytes())


def test_invalid_utf8_in_an_id_raises_decode_error() -> None:
    wire = b"\x01" + b"\x01\xff" + bytes(72)
    with pytest.raises(DecodeError):
        decode_ellipse(wire)


def test_encode_rejects_an_object_that_is_not_a_payload() -> None:
    with pytest.raises(ValueError, match="msg must be one of"):
        encode((1.0, 2.0))  # type: ignore[arg-type]


def test_decoders_are_listed_per_key_class() -> None:
    assert set(decoders.DECODERS) == set(keys.KEY_CLASSES) - {keys.OTHER}
    assert decoders.DECODERS["state"] is decode_state


# --- keys ------------------------------------------------------------------------------------


def test_key_builders_follow_the_design_key_space() -> None:
    assert keys.pose_key("warehouse", "a1") == "warehouse/robot/a1/pose"
    assert keys.state_key("warehouse", "a1") == "warehouse/robot/a1/state"
    assert keys.cmd_key("warehouse", "a1") == "warehouse/robot/a1/cmd"
    assert keys.ellipse_key("warehouse", "A") == "warehouse/formation/A/ellipse"
    assert keys.others_key("warehouse", "A") == "warehouse/formation/A/others"
    assert keys.obstacles_key("warehouse") == "warehouse/obstacles"
    assert keys.state_key("lab/w2", "b3") == "lab/w2/robot/b3/state"
    assert keys.all_robots_key("warehouse", "state") == "warehouse/robot/*/state"
    assert keys.all_formations_key("warehouse", "ellipse") == "warehouse/formation/*/ellipse"


@pytest.mark.parametrize("bad_id", ["", "a/b", "a*", "**", "$x", "#1", "a?", "a b", "\n", "x" * 65])
def test_key_builders_reject_invalid_ids_naming_them(bad_id: str) -> None:
    with pytest.raises(ValueError, match="^robot_id"):
        keys.state_key("warehouse", bad_id)
    with pytest.raises(ValueError, match="^formation_id"):
        keys.ellipse_key("warehouse", bad_id)


@pytest.mark.parametrize("bad_prefix", ["", "/warehouse", "warehouse/", "a//b", "ware*", "w h"])
def test_key_builders_reject_an_invalid_prefix(bad_prefix: str) -> None:
    with pytest.raises(ValueError, match="^prefix"):
        keys.obstacles_key(bad_prefix)


def test_wildcard_builders_reject_unknown_kinds() -> None:
    with pytest.raises(ValueError, match="^kind"):
        keys.all_robots_key("warehouse", "ellipse")
    with pytest.raises(ValueError, match="^kind"):
        keys.all_formations_key("warehouse", "state")


@pytest.mark.parametrize(
    ("key", "cls"),
    [
        ("warehouse/robot/a1/pose", "pose"),
        ("warehouse/robot/a1/state", "state"),
        ("warehouse/robot/a1/cmd", "cmd"),
        ("warehouse/formation/A/ellipse", "ellipse"),
        ("warehouse/formation/A/others", "others"),
        ("warehouse/obstacles", "obstacles"),
        ("warehouse/robot/a1/ellipse", "other"),
        ("warehouse/formation/A/state", "other"),
        ("warehouse/robot/*/state", "other"),
        ("warehouse/robot/a1/state/extra", "other"),
        ("warehouse/obstacles/o1", "other"),
        ("warehouse2/robot/a1/state", "other"),
        ("otherplace/robot/a1/state", "other"),
        ("cmd_vel", "other"),
        ("", "other"),
    ],
)
def test_key_class_names_the_class_of_a_concrete_key(key: str, cls: str) -> None:
    assert keys.key_class("warehouse", key) == cls


@given(robot=ids, formation=ids)
def test_key_class_inverts_every_builder(robot: str, formation: str) -> None:
    p = "warehouse"
    assert keys.parse_key(p, keys.pose_key(p, robot)) == ("pose", robot)
    assert keys.parse_key(p, keys.state_key(p, robot)) == ("state", robot)
    assert keys.parse_key(p, keys.cmd_key(p, robot)) == ("cmd", robot)
    assert keys.parse_key(p, keys.ellipse_key(p, formation)) == ("ellipse", formation)
    assert keys.parse_key(p, keys.others_key(p, formation)) == ("others", formation)
    assert keys.parse_key(p, keys.obstacles_key(p)) == ("obstacles", None)


def test_key_class_accepts_a_zenoh_key_expression() -> None:
    assert keys.key_class("warehouse", zenoh.KeyExpr("warehouse/robot/a1/state")) == "state"


# --- zenoh configuration ------------------------------------------------------------------------


def _json(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))


def test_make_config_sets_the_zenoh_1x_keys() -> None:
    conf = zconf.make_config(
        "client",
        connect=["tcp/127.0.0.1:7447"],
        listen=["tcp/127.0.0.1:7448"],
        connect_timeout_s=2.5,
        scouting_delay_s=0.0,
    )
    assert _json(conf, "mode") == "client"
    assert _json(conf, "connect/endpoints") == ["tcp/127.0.0.1:7447"]
    assert _json(conf, "listen/endpoints") == ["tcp/127.0.0.1:7448"]
    assert _json(conf, "scouting/multicast/enabled") is False
    assert _json(conf, "connect/timeout_ms") == 2500
    assert _json(conf, "scouting/delay") == 0


def test_multicast_scouting_is_off_by_default_and_can_be_turned_on() -> None:
    assert _json(zconf.make_config(), "scouting/multicast/enabled") is False
    on = zconf.make_config(multicast_scouting=True)
    assert _json(on, "scouting/multicast/enabled") is True


def test_the_auth_hook_fills_the_usrpwd_keys() -> None:
    auth = zconf.UsrPwdAuth("robot", "secret", "/etc/zenoh/users.txt")
    conf = zconf.make_config(auth=auth)
    assert _json(conf, "transport/auth/usrpwd") == {
        "user": "robot",
        "password": "secret",
        "dictionary_file": "/etc/zenoh/users.txt",
    }


def test_bad_zenoh_settings_raise_value_error_naming_the_setting() -> None:
    with pytest.raises(ValueError, match="^mode"):
        zconf.make_config("broker")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="^connect"):
        zconf.make_config("client", connect=["localhost"])
    with pytest.raises(ValueError, match="^connect"):
        zconf.make_config("client", connect="tcp/127.0.0.1:7447")
    with pytest.raises(ValueError, match="^listen"):
        zconf.make_config("peer", listen=["1.2.3.4:7447"])
    with pytest.raises(ValueError, match="^connect_timeout_s"):
        zconf.make_config("client", connect_timeout_s=-1.0)
    with pytest.raises(ValueError, match="^config_file"):
        zconf.make_config(config_file="/nonexistent/zenoh.json5")


def test_zenoh_flags_parse_into_settings_and_back() -> None:
    parser = argparse.ArgumentParser()
    zconf.add_zenoh_args(parser)
    ns = parser.parse_args(
        ["--mode", "client", "--connect", "tcp/127.0.0.1:7447", "--connect",
         "tcp/127.0.0.1:7448", "--connect-timeout", "3", "--key-prefix", "lab"]
    )
    settings_ = zconf.settings_from_args(ns)
    assert settings_ == zconf.ZenohSettings(
        mode="client",
        connect=("tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448"),
        connect_timeout_s=3.0,
    )
    assert ns.key_prefix == "lab"
    conf = zconf.config_from_args(ns)
    assert _json(conf, "connect/endpoints") == ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448"]
    assert _json(conf, "scouting/multicast/enabled") is False
    again = zconf.settings_from_args(parser.parse_args(settings_.to_argv()))
    assert again == settings_


def test_default_flags_give_a_peer_with_multicast_scouting_off() -> None:
    parser = argparse.ArgumentParser()
    zconf.add_zenoh_args(parser)
    ns = parser.parse_args([])
    assert zconf.settings_from_args(ns) == zconf.ZenohSettings()
    assert ns.key_prefix == keys.DEFAULT_PREFIX
    assert parser.parse_args(["--multicast-scouting"]).zenoh_multicast_scouting is True


# --- traffic counters -------------------------------------------------------------------------


def test_traffic_counter_counts_messages_and_bytes_per_class_and_side() -> None:
    counter = traffic.TrafficCounter()
    counter.count_put("warehouse/robot/a1/state", 41)
    counter.count_put("warehouse/robot/a1/state", 41)
    counter.count_recv("warehouse/robot/a2/state", 41)
    counter.count_recv("warehouse/obstacles", 100)
    counter.count_put("cmd_vel", 48)
    snap = counter.snapshot()
    assert snap["put"]["state"] == {"messages": 2, "bytes": 82}
    assert snap["recv"]["state"] == {"messages": 1, "bytes": 41}
    assert snap["recv"]["obstacles"] == {"messages": 1, "bytes": 100}
    assert snap["put"]["other"] == {"messages": 1, "bytes": 48}
    assert set(snap["put"]) == set(keys.KEY_CLASSES)
    assert traffic.totals(snap, "put") == {"messages": 3, "bytes": 130}
    json.dumps(snap)


def test_traffic_counter_snapshot_is_a_copy() -> None:
    counter = traffic.TrafficCounter()
    snap = counter.snapshot()
    snap["put"]["state"]["messages"] = 99
    assert counter.snapshot()["put"]["state"]["messages"] == 0


def test_traffic_counter_rejects_a_negative_size() -> None:
    with pytest.raises(ValueError, match="^nbytes"):
        traffic.TrafficCounter().count_put("warehouse/obstacles", -1)


def test_traffic_counter_is_exact_under_concurrent_threads() -> None:
    counter = traffic.TrafficCounter()

    def work() -> None:
        for _ in range(2000):
            counter.count_recv("warehouse/robot/a1/state", 3)

    threads = [threading.Thread(target=work) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=10)
    assert counter.snapshot()["recv"]["state"] == {"messages": 16000, "bytes": 48000}


def test_merge_adds_snapshots_of_many_processes() -> None:
    a, b = traffic.TrafficCounter(), traffic.TrafficCounter()
    a.count_put("warehouse/robot/a1/state", 41)
    b.count_put("warehouse/robot/a2/state", 41)
    b.count_recv("warehouse/formation/A/ellipse", 75)
    merged = traffic.merge([a.snapshot(), b.snapshot()])
    assert merged["put"]["state"] == {"messages": 2, "bytes": 82}
    assert merged["recv"]["ellipse"] == {"messages": 1, "bytes": 75}
    assert traffic.merge([]) == traffic.empty_snapshot()


def test_merge_rejects_unknown_classes_and_bad_counts() -> None:
    with pytest.raises(ValueError, match="unknown class 'frames'"):
        traffic.merge([{"put": {"frames": {"messages": 1, "bytes": 1}}}])
    with pytest.raises(ValueError, match="unknown side"):
        traffic.merge([{"sent": {}}])
    with pytest.raises(ValueError, match="int >= 0"):
        traffic.merge([{"put": {"state": {"messages": -1, "bytes": 0}}}])


class FakePublisher:
    def __init__(self, key: str) -> None:
        self.key_expr = key
        self.sent: list[object] = []
        self.undeclared = False

    def put(self, payload: object) -> None:
        self.sent.append(payload)

    def undeclare(self) -> None:
        self.undeclared = True


def test_counting_publisher_counts_what_it_puts() -> None:
    counter = traffic.TrafficCounter()
    fake = FakePublisher("warehouse/robot/a1/state")
    with traffic.CountingPublisher(fake, counter) as pub:
        pub.put_message(State(1.0, 2.0, 0.0, 0.0, 0.5))
        pub.put(b"\x01\x02")
    assert counter.snapshot()["put"]["state"] == {"messages": 2, "bytes": 51}
    assert fake.undeclared
    assert decode_state(fake.sent[0]) == State(1.0, 2.0, 0.0, 0.0, 0.5)  # type: ignore[arg-type]


# --- mailbox ----------------------------------------------------------------------------------


def test_mailbox_keeps_the_latest_value_and_counts_malformed_payloads() -> None:
    async def scenario() -> traffic.Mailbox[State]:
        loop = asyncio.get_running_loop()
        counter = traffic.TrafficCounter()
        box: traffic.Mailbox[State] = traffic.Mailbox(loop, decode_state, counter=counter)
        key = "warehouse/robot/a1/state"

        def feed() -> None:  # as zenoh would: from a thread of its own
            box.offer(key, encode(State(0.0, 0.0, 0.0, 0.0, 1.0)))
            box.offer(key, b"\x01garbage")
            box.offer(key, encode(State(1.0, 0.0, 0.0, 0.0, 2.0)))

        thread = threading.Thread(target=feed)
        thread.start()
        first = await box.wait_for(key, timeout=5.0)
        assert first.stamp in (1.0, 2.0)
        thread.join(timeout=5.0)
        for _ in range(100):
            if box.received == 3:
                break
            await asyncio.sleep(0.001)
        assert box.latest(key) == State(1.0, 0.0, 0.0, 0.0, 2.0)
        assert (box.received, box.dropped_malformed, box.accepted) == (3, 1, 2)
        assert counter.snapshot()["recv"]["state"]["messages"] == 3
        assert box.values() == {key: State(1.0, 0.0, 0.0, 0.0, 2.0)}
        assert box.latest("warehouse/robot/a9/state") is None
        return box

    asyncio.run(asyncio.wait_for(scenario(), 10.0))


def test_mailbox_survives_a_decoder_that_raises_anything() -> None:
    def broken(_: bytes) -> int:
        raise KeyError("bug")

    async def scenario() -> None:
        box = traffic.Mailbox(asyncio.get_running_loop(), broken)
        box.offer("k", b"")
        assert await box.wait_update(timeout=0.05) is False
        assert (box.received, box.dropped_malformed) == (1, 1)

    asyncio.run(asyncio.wait_for(scenario(), 10.0))


def test_mailbox_wait_update_wakes_on_a_new_value() -> None:
    async def scenario() -> None:
        loop = asyncio.get_running_loop()
        box = traffic.Mailbox(loop, decode_pose)
        loop.call_later(0.01, box.offer, "k", encode(Pose(0.0, 0.0, 0.0, 1.0)))
        assert await box.wait_update(timeout=5.0) is True
        assert box.seq == 1
        with pytest.raises(TimeoutError):
            await box.wait_for("never", timeout=0.01)

    asyncio.run(asyncio.wait_for(scenario(), 10.0))


def test_mailbox_drops_samples_after_the_loop_closed_without_raising() -> None:
    loop = asyncio.new_event_loop()
    box = traffic.Mailbox(loop, decode_pose)
    loop.close()
    box.offer("k", encode(Pose(0.0, 0.0, 0.0, 1.0)))
    assert box.dropped_closed == 1


class FakeSample:
    def __init__(self, key: str, payload: bytes, kind: zenoh.SampleKind) -> None:
        self.key_expr = zenoh.KeyExpr(key)
        self.payload = zenoh.ZBytes(payload)
        self.kind = kind


def test_mailbox_callback_reads_zenoh_samples_and_ignores_deletes() -> None:
    async def scenario() -> None:
        box = traffic.Mailbox(asyncio.get_running_loop(), decode_pose)
        box.callback(FakeSample("k", b"", zenoh.SampleKind.DELETE))
        box.callback(FakeSample("k", encode(Pose(1.0, 0.0, 0.0, 1.0)), zenoh.SampleKind.PUT))
        assert (await box.wait_for("k", timeout=5.0)).x == 1.0
        assert box.received == 1

    asyncio.run(asyncio.wait_for(scenario(), 10.0))


def test_an_inline_mailbox_stores_on_the_calling_thread_and_cannot_be_waited_on() -> None:
    counter = traffic.TrafficCounter()
    box: traffic.Mailbox[State] = traffic.Mailbox(None, decode_state, counter=counter)
    key = "warehouse/robot/a1/state"
    box.offer(key, encode(State(0.0, 0.0, 0.0, 0.0, 1.0)))
    box.offer(key, b"\x01garbage")
    assert box.latest(key) == State(0.0, 0.0, 0.0, 0.0, 1.0)  # at once, no loop pass
    assert (box.received, box.dropped_malformed, box.seq) == (2, 1, 1)
    assert counter.snapshot()["recv"]["state"]["messages"] == 2
    with pytest.raises(RuntimeError, match="inline"):
        asyncio.run(box.wait_update(timeout=0.01))
    with pytest.raises(RuntimeError, match="inline"):
        asyncio.run(box.wait_for(key, timeout=0.01))


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(min_value=1e307, max_value=1.7e308), min_size=9, max_size=9),
       st.sampled_from([1.0, -1.0]))
def test_huge_finite_fields_whose_sum_overflows_are_still_accepted(values: list[float],
                                                                    sign: float) -> None:
    # the constructors' fast check sums the fields; an overflowing sum must fall back to the
    # field-by-field check, which accepts every finite value
    v = [sign * x for x in values]
    assert Pose(*v[:4]).theta == v[2]
    assert State(*v[:5]).uy == v[3]
    assert Cmd(*v[:5]).stamp == v[4]
    e = EllipseMsg("A", v[0], v[1], v[2], abs(v[3]), abs(v[4]), v[5], v[6], v[7], v[8])
    assert decode_ellipse(encode(e)) == e
    assert ObstacleMsg("o1", v[0], v[1], v[2], v[3], abs(v[4])).ds == abs(v[4])


def test_use_zenoh_threads_sets_a_profile_unless_the_user_chose_their_own(monkeypatch) -> None:
    monkeypatch.delenv(zconf.RUNTIME_ENV, raising=False)
    assert zconf.use_zenoh_threads("relay") is True
    assert os.environ[zconf.RUNTIME_ENV] == zconf.RUNTIME_PROFILES["relay"]
    # a child that inherited the launcher's profile switches to its own
    assert zconf.use_zenoh_threads("agent") is True
    assert os.environ[zconf.RUNTIME_ENV] == zconf.RUNTIME_PROFILES["agent"]
    monkeypatch.setenv(zconf.RUNTIME_ENV, "(app: (worker_threads: 2))")
    assert zconf.use_zenoh_threads("agent") is False
    assert os.environ[zconf.RUNTIME_ENV] == "(app: (worker_threads: 2))"
    with pytest.raises(KeyError):
        zconf.use_zenoh_threads("nonsense")


# --- an ellipse's member points (wire version 2) ------------------------------------------------


def test_an_ellipse_without_points_is_written_as_version_1_byte_for_byte() -> None:
    assert encode(E_A)[0] == 1 and encode(E_A2)[0] == 2
    assert encode(E_A2)[:75] == b"\x02" + encode(E_A)[1:]
    assert encode(Others("B", 4.0, (E_A,), E_B))[0] == 1
    assert encode(Others("B", 4.0, (E_A,), dataclasses.replace(E_B, points=((0.0, 0.0),))))[0] == 2
    assert decode_ellipse(encode(E_A)).points == ()


def test_points_beyond_the_limit_or_not_finite_are_refused_built_and_decoded() -> None:
    fields = [getattr(E_A, f) for f in ("formation", "cx", "cy", "alpha", "a", "b", "vx", "vy",
                                        "alpha_rate", "stamp")]
    with pytest.raises(ValueError, match="at most 64"):
        EllipseMsg(*fields, points=((0.0, 0.0),) * (payloads.MAX_POINTS + 1))
    with pytest.raises(ValueError, match="finite"):
        EllipseMsg(*fields, points=((0.0, math.inf),))
    with pytest.raises(ValueError, match=r"points\[0\]"):
        EllipseMsg(*fields, points=((0.0, 1.0, 2.0),))
    too_many = z_serialize((UInt8(2), *fields, [(0.0, 0.0)] * 65, [])).to_bytes()
    with pytest.raises(DecodeError, match="at most 64"):
        decode_ellipse(too_many)
    for bad in (math.nan, math.inf, -math.inf):
        data = z_serialize((UInt8(2), *fields, [(0.0, 0.0), (bad, 1.0)], [])).to_bytes()
        with pytest.raises(DecodeError, match="finite"):
            decode_ellipse(data)
        data = z_serialize((UInt8(2), *fields, [(0.0, 0.0)], [bad])).to_bytes()
        with pytest.raises(DecodeError, match="finite"):
            decode_ellipse(data)
        others = z_serialize((UInt8(2), "B", 0.0, [(*fields, [(bad, 0.0)], [])], [])).to_bytes()
        with pytest.raises(DecodeError, match="finite"):
            decode_others(others)
    # a version-1 others has no points list: one where version 2 expects it is truncated
    v1_body = encode(Others("B", 4.0, (E_A,), None))[1:]
    with pytest.raises(DecodeError, match="truncated"):
        decode_others(b"\x02" + v1_body)


def test_headings_must_match_the_points_one_for_one_built_and_decoded() -> None:
    fields = [getattr(E_A, f) for f in ("formation", "cx", "cy", "alpha", "a", "b", "vx", "vy",
                                        "alpha_rate", "stamp")]
    with pytest.raises(ValueError, match="1 headings for 2 points"):
        EllipseMsg(*fields, points=((0.0, 0.0), (1.0, 1.0)), headings=(0.5,))
    with pytest.raises(ValueError, match=r"headings\[0\]"):
        EllipseMsg(*fields, points=((0.0, 0.0),), headings=(math.nan,))
    assert decode_ellipse(encode(E_A2)).headings == (0.25, 3.0)
    assert decode_ellipse(encode(dataclasses.replace(E_A2, headings=()))).headings == ()
    wrong = z_serialize((UInt8(2), *fields, [(0.0, 0.0), (1.0, 1.0)], [0.5])).to_bytes()
    with pytest.raises(DecodeError, match="1 headings for 2 points"):
        decode_ellipse(wrong)
    hostile = z_serialize((UInt8(2), *fields, [(0.0, 0.0)], [0.5] * 65)).to_bytes()
    with pytest.raises(DecodeError, match="at most 64"):
        decode_ellipse(hostile)
