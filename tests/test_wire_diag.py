"""The ``diag`` payload: round trip, defensive decoding, and its key outside the control classes."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from wire import keys
from wire.diag import Diag, decode_diag, diag_key, encode_diag
from wire.payloads import DecodeError


def sample(**kw) -> Diag:
    values = dict(formation="A", status="relaxed", stamp=12.5, slack=0.01, h_formation=0.02,
                  h_obstacle=math.inf, h_formations=1.5, goal_x=2.0, goal_y=-1.0, ticks=250,
                  stale=3, relaxed=7, fallback=0, dropped=1)
    values.update(kw)
    return Diag(**values)


def test_a_diag_survives_encoding_with_infinite_barriers_kept():
    d = sample()
    back = decode_diag(encode_diag(d))
    assert back == d and back.h_obstacle == math.inf


@given(st.binary(max_size=200))
def test_arbitrary_bytes_decode_to_a_diag_or_raise_decode_error(data):
    try:
        decode_diag(data)
    except DecodeError:
        pass


def test_truncated_or_trailing_or_non_finite_counters_are_rejected():
    raw = encode_diag(sample())
    for bad in (raw[:-1], raw + b"\0", b"", bytes([9]) + raw[1:]):
        with pytest.raises(DecodeError):
            decode_diag(bad)
    with pytest.raises(ValueError):
        sample(stamp=math.nan)
    with pytest.raises(ValueError):
        sample(status="two words")


def test_the_diag_key_is_counted_as_other_not_as_control_traffic():
    key = diag_key("warehouse", "a1")
    assert key == "warehouse/robot/a1/diag"
    assert keys.key_class("warehouse", key) == keys.OTHER
