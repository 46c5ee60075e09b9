"""The ``obstacles`` payload with walls and shelves (version 2), and what an older decoder does."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from zenoh.ext import UInt8, z_deserialize

from wire.payloads import (
    MAX_ITEMS,
    SHAPE_BOX,
    SHAPE_SEGMENT,
    DecodeError,
    ObstacleMsg,
    Obstacles,
    ShapeMsg,
    decode_obstacles,
    encode,
)
from wire.reader import decode_payload

finite = st.floats(allow_nan=False, allow_infinity=False)
non_negative = st.floats(min_value=0.0, allow_infinity=False)
ids = st.text(alphabet="abcxyz-_0123456789", min_size=1, max_size=8)
circles = st.builds(ObstacleMsg, ids, finite, finite, finite, finite, non_negative)
segments = st.builds(ShapeMsg, ids, st.just(SHAPE_SEGMENT), finite, finite, non_negative, st.just(0.0),
                     finite, non_negative)
boxes = st.builds(ShapeMsg, ids, st.just(SHAPE_BOX), finite, finite, non_negative, non_negative, finite,
                  non_negative)


@st.composite
def with_shapes(draw: st.DrawFn) -> Obstacles:
    items = draw(st.lists(st.one_of(circles, segments, boxes), min_size=1, max_size=8,
                          unique_by=lambda o: o.id))
    shapes = tuple(o for o in items if isinstance(o, ShapeMsg))
    if not shapes:
        shapes = (ShapeMsg("wall0", SHAPE_SEGMENT, 0.0, 0.0, 1.0, 0.0, 0.0, 0.1),)
        items = [o for o in items if o.id != "wall0"]
    return Obstacles(draw(finite), tuple(o for o in items if isinstance(o, ObstacleMsg)), shapes)


F1, F2, F05, F3, F0, F025 = ("000000000000f03f", "0000000000000040", "000000000000e03f",
                             "0000000000000840", "0000000000000000", "000000000000d03f")
EXAMPLE = Obstacles(3.0, (ObstacleMsg("o1", 1.0, 2.0, 0.0, 0.0, 0.5),),
                    (ShapeMsg("w", SHAPE_SEGMENT, 1.0, 2.0, 3.0, 0.0, 0.0, 0.25),
                     ShapeMsg("s", SHAPE_BOX, 0.0, 1.0, 0.5, 0.25, 0.0, 0.5)))


def test_walls_and_shelves_have_the_hand_written_version_2_layout():
    expected = bytes.fromhex(
        "02" + F3 + "01" + "026f31" + F1 + F2 + F0 + F0 + F05  # version 2, stamp, 1 circle
        + "02" + "0177" + "01" + F1 + F2 + F3 + F0 + F0 + F025  # 2 shapes: "w", kind 1 (segment)
        + "0173" + "02" + F0 + F1 + F05 + F025 + F0 + F05  # "s", kind 2 (box)
    )
    assert encode(EXAMPLE) == expected
    assert decode_obstacles(expected) == EXAMPLE


def test_circles_alone_keep_version_1_byte_for_byte():
    circles_only = Obstacles(3.0, EXAMPLE.obstacles)
    data = encode(circles_only)
    assert data[0] == 1
    assert data == bytes.fromhex("01" + F3 + "01" + "026f31" + F1 + F2 + F0 + F0 + F05)
    assert decode_obstacles(data) == circles_only


def test_a_decoder_that_predates_shapes_refuses_them_naming_the_version():
    # the version-1-only decoder, as every build before shapes had it
    with pytest.raises(DecodeError, match=r"obstacles: unsupported version 2 \(expected 1\)"):
        decode_payload(encode(EXAMPLE), lambda r: None, "obstacles")
    bad = bytearray(encode(EXAMPLE))
    bad[0] = 3
    with pytest.raises(DecodeError, match=r"unsupported version 3 \(expected 1 or 2\)"):
        decode_obstacles(bytes(bad))


@settings(max_examples=150, deadline=None)
@given(msg=with_shapes())
def test_any_list_of_shapes_round_trips_and_zenoh_reads_it(msg: Obstacles):
    data = encode(msg)
    assert decode_obstacles(data) == msg
    circle = tuple[str, float, float, float, float, float]
    shape = tuple[str, UInt8, float, float, float, float, float, float]
    got = z_deserialize(tuple[UInt8, float, list[circle], list[shape]], zenoh.ZBytes(data))
    assert got[0] == 2 and got[1] == msg.stamp and len(got[3]) == len(msg.shapes)
    assert [s[0] for s in got[3]] == [s.id for s in msg.shapes]


def test_truncation_at_every_byte_position_raises_decode_error():
    data = encode(EXAMPLE)
    for cut in range(len(data)):
        with pytest.raises(DecodeError):
            decode_obstacles(data[:cut])


@settings(max_examples=300, deadline=None)
@given(pos=st.integers(0, 200), value=st.integers(0, 255))
def test_a_corrupted_byte_decodes_to_a_valid_message_or_raises_decode_error(pos, value):
    data = bytearray(encode(EXAMPLE))
    data[pos % len(data)] = value
    try:
        msg = decode_obstacles(bytes(data))
    except DecodeError:
        return
    assert isinstance(msg, Obstacles)
    assert all(s.kind in (SHAPE_SEGMENT, SHAPE_BOX) for s in msg.shapes)


def test_an_unknown_kind_a_thick_segment_and_repeated_ids_are_refused():
    data = bytearray(encode(EXAMPLE))
    kind_at = data.index(bytes.fromhex("0177")) + 2
    data[kind_at] = 7
    with pytest.raises(DecodeError, match="kind must be 1"):
        decode_obstacles(bytes(data))
    with pytest.raises(ValueError, match="a segment has hy = 0"):
        ShapeMsg("w", SHAPE_SEGMENT, 0.0, 0.0, 1.0, 0.2, 0.0, 0.1)
    with pytest.raises(ValueError, match="repeat id 'o1'"):
        Obstacles(0.0, EXAMPLE.obstacles, (ShapeMsg("o1", SHAPE_BOX, 0.0, 0.0, 1.0, 0.2, 0.0, 0.1),))
    many = tuple(ShapeMsg(f"s{k}", SHAPE_BOX, 0.0, 0.0, 1.0, 1.0, 0.0, 0.1) for k in range(MAX_ITEMS))
    with pytest.raises(ValueError, match=f"at most {MAX_ITEMS}"):
        Obstacles(0.0, EXAMPLE.obstacles, many)
