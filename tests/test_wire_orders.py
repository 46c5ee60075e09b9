"""Order, bid and order-status payloads and their keys: round trips, the byte layout, defensive
decoding of hostile bytes, and the forged-bid check."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from zenoh.ext import UInt8, z_deserialize

from wire import decoders, keys, traffic
from wire.orders import (
    BID_PHASES,
    MAX_SLOTS,
    ORDER_STATES,
    BidMsg,
    OrderMsg,
    OrderStatusMsg,
    all_orders_key,
    bid_is_forged,
    bid_key,
    bids_key,
    decode_bid,
    decode_order,
    decode_order_status,
    encode_order,
    order_key,
    order_status_key,
    parse_order_key,
    read_order_message,
)
from wire.reader import DecodeError

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
costs = st.floats(0.0, 1e6, allow_nan=False, width=64)
ids = st.text(alphabet="abcxyz-_0123456789", min_size=1, max_size=8)
rosters = st.lists(ids, max_size=MAX_SLOTS, unique=True).map(tuple)
orders = st.one_of(
    st.builds(OrderMsg, ids, st.just("new"), ids, st.just(""), ids, ids, st.integers(0, 9), finite),
    st.builds(OrderMsg, ids, st.just("load"), st.just(""), ids, st.just(""), ids, st.integers(0, 9), finite),
    st.builds(OrderMsg, ids, st.sampled_from(("cancel", "priority")), priority=st.integers(0, 9),
              stamp=finite))
bids = st.one_of(
    st.builds(BidMsg, ids, ids, st.integers(0, 10**6), st.just("bid"),
              st.lists(costs, min_size=1, max_size=MAX_SLOTS).map(tuple), st.just(()), finite),
    st.builds(BidMsg, ids, ids, st.integers(0, 10**6), st.just("vote"), st.just(()),
              rosters.filter(bool), finite),
    st.builds(BidMsg, ids, ids, st.integers(0, 10**6), st.just("decline"), stamp=finite))
statuses = st.builds(OrderStatusMsg, ids, st.sampled_from(ORDER_STATES), st.integers(0, 10**6),
                     rosters, ids | st.just(""), st.text(max_size=40), finite)
DECODE = {OrderMsg: decode_order, BidMsg: decode_bid, OrderStatusMsg: decode_order_status}

ORDER = OrderMsg("o1", "new", type="pallet", source="dock-in", to="rack-3", priority=1, stamp=2.5)
BID = BidMsg("o1", "r4", 7, "bid", costs=(1.5, 2.0, 0.25, 3.0), stamp=7.0)
VOTE = BidMsg("o1", "r4", 7, "vote", roster=("r1", "r4", "r2", "r9"), stamp=7.0)
STATUS = OrderStatusMsg("o1", "failed", 7, ("r1", "r4"), "r1", "member lost: r4", 31.0)


@settings(max_examples=150, deadline=None)
@given(msg=st.one_of(orders, bids, statuses))
def test_every_order_bid_and_status_round_trips(msg):
    assert DECODE[type(msg)](encode_order(msg)) == msg


def test_the_bid_layout_is_readable_by_zenohs_own_deserializer():
    layout = tuple[UInt8, str, str, float, str, list[float], list[str], float]
    got = z_deserialize(layout, zenoh.ZBytes(encode_order(BID)))
    assert got == (UInt8(1), "o1", "r4", 7.0, "bid", [1.5, 2.0, 0.25, 3.0], [], 7.0)


@pytest.mark.parametrize("msg", [ORDER, BID, VOTE, STATUS])
def test_every_truncation_and_every_appended_byte_is_a_decode_error(msg):
    data = encode_order(msg)
    decode = DECODE[type(msg)]
    for n in range(len(data)):
        with pytest.raises(DecodeError):
            decode(data[:n])
    with pytest.raises(DecodeError, match="trailing"):
        decode(data + b"\x00")


def test_a_roster_claiming_a_huge_count_is_refused_before_anything_is_read():
    data = encode_order(OrderStatusMsg("o1", "assigned"))
    head = data.index(b"assigned") + len(b"assigned") + 8  # after the round's f64
    hostile = data[:head] + b"\xff\xff\xff\xff\x0f" + data[head + 1:]
    with pytest.raises(DecodeError, match="roster must hold at most 16"):
        decode_order_status(hostile)


@pytest.mark.parametrize("make, why", [
    (lambda: OrderMsg("o1", "new", type="pallet", to="rack-3"), "needs source"),
    (lambda: OrderMsg("o1", "load", to="rack-3"), "needs load"),
    (lambda: OrderMsg("o1", "steal"), "kind must be one of"),
    (lambda: OrderMsg("o/1", "cancel"), "oid"),
    (lambda: OrderMsg("o1", "priority", priority=float("nan")), "priority must be a finite number"),
    (lambda: OrderMsg("o1", "priority", priority=2e6), "priority must be a finite number"),
    (lambda: BidMsg("o1", "r1", 1, "bid"), "a bid needs its costs"),
    (lambda: BidMsg("o1", "r1", 1, "bid", costs=(float("nan"),)), r"costs\[0\]"),
    (lambda: BidMsg("o1", "r1", 1, "bid", costs=(-1.0,)), r"costs\[0\]"),
    (lambda: BidMsg("o1", "r1", 1, "bid", costs=(1.0,) * (MAX_SLOTS + 1)), "at most 16 slots"),
    (lambda: BidMsg("o1", "r1", 1.5, "bid", costs=(1.0,)), "round must be a whole number"),
    (lambda: BidMsg("o1", "r1", 1, "vote"), "a vote needs its roster"),
    (lambda: BidMsg("o1", "r1", 1, "vote", roster=("r2", "r2")), "names a robot twice"),
    (lambda: OrderStatusMsg("o1", "lost"), "state must be one of"),
    (lambda: OrderStatusMsg("o1", "failed", reason="x" * 201), "reason must be text"),
    (lambda: OrderStatusMsg("o1", "failed", stamp=float("inf")), "stamp must be finite"),
])
def test_invalid_fields_are_refused_naming_the_field(make, why):
    with pytest.raises(ValueError, match=why):
        make()


def test_a_decoded_invalid_message_is_a_decode_error_naming_its_kind():
    bad = encode_order(BID).replace(b"bid", b"bad", 1)
    with pytest.raises(DecodeError, match="^bid: invalid message .*phase"):
        decode_bid(bad)


def test_the_keys_and_their_parse():
    assert order_key("warehouse", "o1") == "warehouse/order/o1"
    assert all_orders_key("lab/w") == "lab/w/order/*"
    assert bid_key("warehouse", "o1", "r4") == "warehouse/order/o1/bid/r4"
    assert bids_key("warehouse", "o1") == "warehouse/order/o1/bid/*"
    assert order_status_key("warehouse", "o1") == "warehouse/order/o1/status"
    assert parse_order_key("warehouse/order/o1", "warehouse") == ("o1", "order", "")
    assert parse_order_key("warehouse/order/o1/bid/r4", "warehouse") == ("o1", "bid", "r4")
    assert parse_order_key("warehouse/order/o1/status", "warehouse") == ("o1", "status", "")
    for other in ("warehouse/order/", "warehouse/order/o1/bid", "warehouse/order/o1/bid/",
                  "warehouse/order/o1/goal", "warehouse/robot/r1/pose", "lab/order/o1",
                  "warehouse/order/o 1/status"):
        assert parse_order_key(other, "warehouse") is None, other
    with pytest.raises(ValueError, match="order id"):
        order_key("warehouse", "o*")


@pytest.mark.parametrize("key, forged", [
    ("warehouse/order/o1/bid/r4", False),
    ("warehouse/order/o1/bid/r5", True),   # r5 speaking for r4
    ("warehouse/order/o2/bid/r4", True),   # a bid on o1 put on o2's key
    ("warehouse/order/o1/status", True),
])
def test_a_bid_is_forged_unless_its_key_names_its_robot_and_order(key, forged):
    assert bid_is_forged(key, "warehouse", BID) is forged


def test_every_phase_and_state_is_named_once():
    assert len(set(BID_PHASES)) == len(BID_PHASES) == 3
    assert ORDER_STATES == ("waiting", "assigned", "gathering", "carrying", "delivered",
                            "cancelled", "failed")


def test_a_priority_is_the_scenarios_any_finite_number():
    msg = OrderMsg("o1", "priority", priority=-2.5, stamp=1.0)
    assert decode_order(encode_order(msg)).priority == -2.5


@pytest.mark.parametrize("key, cls, ident", [
    ("warehouse/order/o1", keys.ORDER, "o1"),
    ("warehouse/order/o1/bid/r4", keys.BID, "o1"),
    ("warehouse/order/o1/status", keys.ORDER_STATUS, "o1"),
    ("warehouse/order/o1/bid", keys.OTHER, None),
    ("warehouse/order/o1/goal", keys.OTHER, None),
    ("warehouse/order", keys.OTHER, None),
    ("warehouse/order/o 1/status", keys.OTHER, None),
    ("warehouse/order/o1/bid/r 4", keys.OTHER, None),
])
def test_the_order_keys_have_their_own_classes(key, cls, ident):
    assert keys.parse_key("warehouse", key) == (cls, ident)


def test_each_order_class_has_its_decoder_and_the_traffic_its_own_line():
    assert decoders.DECODERS[keys.ORDER] is decode_order
    assert decoders.DECODERS[keys.BID] is decode_bid
    assert decoders.DECODERS[keys.ORDER_STATUS] is decode_order_status
    counter = traffic.TrafficCounter("warehouse")
    for key, n in (("warehouse/order/o1", 30), ("warehouse/order/o1/bid/r4", 50),
                   ("warehouse/order/o1/status", 40), ("warehouse/robot/r4/state", 49)):
        counter.count_put(key, n)
        counter.count_recv(key, n)
    counter.count_recv("warehouse/order/o1/bid/r4", 50)
    line = traffic.orders_line(counter.snapshot())
    assert line == {"put": {"messages": 3, "bytes": 120}, "recv": {"messages": 4, "bytes": 170}}


@pytest.mark.parametrize("key, msg", [
    ("warehouse/order/o1", ORDER),
    ("warehouse/order/o1/bid/r4", BID),
    ("warehouse/order/o1/status", STATUS),
])
def test_read_order_message_decodes_by_the_keys_kind(key, msg):
    assert read_order_message("warehouse", key, encode_order(msg)) == msg


@pytest.mark.parametrize("key, payload, why", [
    ("warehouse/order/o2", encode_order(ORDER), "forged"),            # o1 on o2's key
    ("warehouse/order/o2/status", encode_order(STATUS), "forged"),
    ("warehouse/order/o1/bid/r5", encode_order(BID), "forged"),      # r5 speaking for r4
    ("warehouse/order/o1/status", encode_order(ORDER), "order status"),  # the wrong layout
    ("warehouse/order/o1", b"\x01" + b"\xff" * 64, "order"),
    ("warehouse/order/o1", b"\x01" * (600 * 1024), "order"),        # oversized
    ("warehouse/robot/r1/state", encode_order(ORDER), "not an order key"),
])
def test_read_order_message_refuses_forged_malformed_and_oversized_alike(key, payload, why):
    with pytest.raises(DecodeError, match=why):
        read_order_message("warehouse", key, payload)
