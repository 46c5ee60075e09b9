"""Goal, plan and status payloads: round trips, the byte layout and defensive decoding."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from zenoh.ext import UInt8, z_deserialize

from wire import keys
from wire.decoders import DECODERS
from wire.navigation import (
    STATUS_STATES,
    GoalMsg,
    PlanMsg,
    StatusMsg,
    decode_goal,
    decode_plan,
    decode_status,
    encode_nav,
)
from wire.payloads import DecodeError

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
ids = st.text(alphabet="abcxyz-_0123456789", min_size=1, max_size=8)
points = st.lists(st.tuples(finite, finite), max_size=6).map(tuple)
headings = st.none() | finite
goals = st.builds(GoalMsg, ids, finite, finite, headings, points, finite)
plans = st.builds(PlanMsg, ids, finite, finite, finite, headings,
                  st.lists(st.tuples(finite, finite), min_size=1, max_size=6).map(tuple),
                  st.lists(st.tuples(ids, finite, finite), max_size=5, unique_by=lambda m: m[0]).map(tuple),
                  finite)
reasons = st.text(max_size=40)
statuses = st.builds(StatusMsg, ids, st.sampled_from(STATUS_STATES), ids,
                     finite, finite, finite, headings, st.floats(0, 1e6), st.integers(0, 64),
                     st.integers(0, 64), finite, finite, finite, reasons,
                     st.integers(0, 2**31 - 1), reasons, st.lists(ids, max_size=4).map(tuple))
DECODE = {GoalMsg: decode_goal, PlanMsg: decode_plan, StatusMsg: decode_status}

GOAL = GoalMsg("A", 1.0, 2.0, 0.5, ((1.0, 0.0),), 3.0)
PLAN = PlanMsg("A", 3.0, 1.0, 2.0, None, ((1.0, 0.0), (1.0, 2.0)),
               (("a1", 1.0, 2.25), ("a2", 1.0, 1.75)), 3.5)
STATUS = StatusMsg("A", "moving", "a1", 3.0, 1.0, 2.0, 0.5, 2.25, 1, 2, 1.0, 2.0, 4.0)
STATUS2 = StatusMsg("A", "unreachable", "a1", 3.0, 1.0, 2.0, 0.5, 2.25, 1, 2, 1.0, 2.0, 4.0,
                    reason="no route: the goal lies in a closed room", refused=2,
                    refusal="waypoint 0 lies within the safe distance of box 'shelf'")
STATUS3 = StatusMsg("A", "moving", "a1", 3.0, 1.0, 2.0, 0.5, 2.25, 1, 2, 1.0, 2.0, 4.0,
                    fleet=("A", "B", "shelf-movers"))
EXAMPLES = [GOAL, PLAN, STATUS, STATUS2, STATUS3]


@settings(max_examples=150, deadline=None)
@given(msg=st.one_of(goals, plans, statuses))
def test_every_goal_plan_and_status_round_trips(msg):
    assert DECODE[type(msg)](encode_nav(msg)) == msg


def test_the_goal_layout_is_readable_by_zenohs_own_deserializer():
    got = z_deserialize(tuple[UInt8, str, float, float, list[float], list[tuple[float, float]], float],
                        zenoh.ZBytes(encode_nav(GOAL)))
    assert got == (1, "A", 1.0, 2.0, [0.5], [(1.0, 0.0)], 3.0)
    got = z_deserialize(tuple[UInt8, str, float, float, float, list[float], list[tuple[float, float]],
                              list[tuple[str, float, float]], float], zenoh.ZBytes(encode_nav(PLAN)))
    assert got[-2] == [("a1", 1.0, 2.25), ("a2", 1.0, 1.75)]


def test_a_status_with_nothing_new_stays_version_1_byte_for_byte_and_v2_carries_the_rest():
    v1 = encode_nav(STATUS)
    assert v1[0] == 1  # an older fleet manager still reads it
    got = z_deserialize(tuple[UInt8, str, str, str, float, float, float, list[float], float, float,
                              float, float, float, float], zenoh.ZBytes(v1))
    assert got == (1, "A", "moving", "a1", 3.0, 1.0, 2.0, [0.5], 2.25, 1.0, 2.0, 1.0, 2.0, 4.0)
    v2 = encode_nav(STATUS2)
    assert v2[0] == 2
    got2 = decode_status(v2)
    assert (got2.state, got2.refused) == ("unreachable", 2) and got2.reason.startswith("no route")
    v2f = encode_nav(STATUS3)  # the fleet alone is version 2 as well
    assert v2f[0] == 2 and v2f.startswith(b"\x02" + encode_nav(STATUS)[1:])
    assert decode_status(v2f).fleet == ("A", "B", "shelf-movers")
    with pytest.raises(DecodeError, match="unsupported version 3"):
        decode_status(b"\x03" + v2f[1:])


def test_a_status_refuses_a_fleet_naming_a_bad_id_or_too_many():
    with pytest.raises(ValueError, match=r"fleet\[1\]"):
        StatusMsg("A", "moving", "a1", 0.0, 0.0, 0.0, None, 0.0, 0, 1, 0.0, 0.0, 0.0,
                  fleet=("A", "a/b"))
    with pytest.raises(ValueError, match="at most 256"):
        StatusMsg("A", "moving", "a1", 0.0, 0.0, 0.0, None, 0.0, 0, 1, 0.0, 0.0, 0.0,
                  fleet=tuple(f"f{k}" for k in range(257)))


def test_a_status_refuses_a_reason_too_long_or_a_negative_count():
    with pytest.raises(ValueError, match="reason"):
        StatusMsg("A", "moving", "a1", 0.0, 0.0, 0.0, None, 0.0, 0, 1, 0.0, 0.0, 0.0, reason="x" * 201)
    with pytest.raises(ValueError, match="refused"):
        StatusMsg("A", "moving", "a1", 0.0, 0.0, 0.0, None, 0.0, 0, 1, 0.0, 0.0, 0.0, refused=-1)


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_truncated_or_padded_payloads_raise_decode_error(msg):
    data = encode_nav(msg)
    for cut in range(len(data)):
        with pytest.raises(DecodeError):
            DECODE[type(msg)](data[:cut])
    with pytest.raises(DecodeError, match="trailing"):
        DECODE[type(msg)](data + b"\x00")


@settings(max_examples=300, deadline=None)
@given(blob=st.binary(max_size=120))
def test_random_bytes_never_raise_anything_but_decode_error(blob):
    for decode in DECODE.values():
        try:
            decode(blob)
        except DecodeError:
            pass


def test_bad_values_are_refused_naming_the_field():
    with pytest.raises(ValueError, match="heading must be finite"):
        GoalMsg("A", 0.0, 0.0, float("nan"))
    with pytest.raises(ValueError, match=r"waypoints\[0\] must hold finite numbers"):
        GoalMsg("A", 0.0, 0.0, None, ((float("inf"), 0.0),))
    with pytest.raises(ValueError, match="state must be one of"):
        StatusMsg("A", "lost", "a1", 0.0, 0.0, 0.0, None, 0.0, 0, 1, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="route must hold at least the goal"):
        PlanMsg("A", 0.0, 0.0, 0.0, None, (), (), 0.0)
    with pytest.raises(ValueError, match="members repeat id 'a1'"):
        PlanMsg("A", 0.0, 0.0, 0.0, None, ((0.0, 0.0),), (("a1", 0.0, 0.0), ("a1", 1.0, 0.0)), 0.0)
    bad = bytearray(encode_nav(STATUS))
    bad[bad.index(b"moving")] = ord("x")
    with pytest.raises(DecodeError, match="state must be one of"):
        decode_status(bytes(bad))


def test_the_keys_follow_the_design_and_have_decoders():
    assert keys.goal_key("warehouse", "A") == "warehouse/formation/A/goal"
    assert keys.status_key("warehouse", "A") == "warehouse/formation/A/status"
    assert keys.plan_key("warehouse", "A") == "warehouse/formation/A/plan"
    for cls in (keys.GOAL, keys.STATUS, keys.PLAN):
        assert keys.key_class("warehouse", f"warehouse/formation/A/{cls}") == cls
    assert DECODERS[keys.PLAN] is decode_plan
    assert PLAN.goal_of("a2") == (1.0, 1.75) and PLAN.goal_of("zz") is None
