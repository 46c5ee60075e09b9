"""The ``odom`` payload (wire.odom): round trip, its byte layout in the Zenoh serialization
format, and hostile input refused as a DecodeError."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st
from zenoh.ext import z_serialize

from wire.odom import Odom, decode_odom, encode_odom, odom_key
from wire.reader import DecodeError

GOOD = Odom(0.01, -0.002, 0.003, 1.0, 1.05)


def test_round_trip_and_layout():
    data = encode_odom(GOOD)
    assert len(data) == 41 and decode_odom(data) == GOOD
    # the same bytes zenoh-ext writes for the tuple (u8, f64 x 5)
    from zenoh.ext import UInt8
    assert z_serialize((UInt8(1), 0.01, -0.002, 0.003, 1.0, 1.05)).to_bytes() == data


def test_the_key():
    assert odom_key("warehouse", "r1") == "warehouse/robot/r1/odom"
    with pytest.raises(ValueError):
        odom_key("warehouse", "r/1")


@pytest.mark.parametrize("data", [
    b"",
    b"\x02" + bytes(40),  # unknown version
    encode_odom(GOOD)[:-1],  # truncated
    encode_odom(GOOD) + b"\x00",  # trailing bytes
    struct.pack("<B5d", 1, math.nan, 0, 0, 0, 0),
    struct.pack("<B5d", 1, math.inf, 0, 0, 0, 0),
    struct.pack("<B5d", 1, 11.0, 0, 0, 0, 1),  # a step too long
    struct.pack("<B5d", 1, 0, 0, 7.0, 0, 1),  # a turn too large
    struct.pack("<B5d", 1, 0, 0, 0, 2.0, 1.0),  # stamp before since
])
def test_hostile_payloads_are_decode_errors(data):
    with pytest.raises(DecodeError, match="odom"):
        decode_odom(data)


@given(st.binary(max_size=64))
def test_any_bytes_decode_or_raise_decode_error(data):
    try:
        decode_odom(data)
    except DecodeError:
        pass
