"""The world's loads on the wire (``{prefix}/world/loads``, :class:`wire.orders.LoadsMsg`): round
trips, the byte layout, hostile bytes, the key's class and decoder, and who may put it under
access control (a Python router enforcing :func:`wire.acl.fleet_acl` with ``orders``)."""

from __future__ import annotations

import queue
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from zenoh.ext import UInt8, z_deserialize

from runtime.testing import fleet_acl_router, open_as
from wire import acl, decoders, keys, traffic
from wire.orders import LOAD_STATES, MAX_LOADS, LoadEntry, LoadsMsg, decode_loads, encode_loads
from wire.reader import MAX_PAYLOAD_BYTES, DecodeError

ROOT = Path(__file__).resolve().parent.parent
P = keys.DEFAULT_PREFIX

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
ids = st.text(alphabet="abcxyz-_0123456789", min_size=1, max_size=8)
entries = st.builds(LoadEntry, ids, ids, finite, finite, finite, st.sampled_from(LOAD_STATES),
                    ids | st.just(""), ids | st.just(""))
messages = st.builds(LoadsMsg, finite, st.lists(entries, max_size=12, unique_by=lambda e: e.name)
                     .map(tuple))

PALLET = LoadEntry("p1", "pallet", 4.0, 3.5, 1.5708, "resting", "rack-3", "")
CARRIED = LoadEntry("o1", "beam", -1.25, 0.5, 0.25, "carried", "", "o1")
MSG = LoadsMsg(12.5, (PALLET, CARRIED))


@settings(max_examples=150, deadline=None)
@given(msg=messages)
def test_every_loads_message_round_trips(msg):
    assert decode_loads(encode_loads(msg)) == msg


@settings(max_examples=400, deadline=None)
@given(data=st.binary(max_size=400))
def test_random_bytes_raise_nothing_but_a_decode_error(data):
    try:
        msg = decode_loads(data)
    except DecodeError:
        return
    assert isinstance(msg, LoadsMsg)  # the rare bytes that happen to be a valid message


@settings(max_examples=200, deadline=None)
@given(msg=messages, at=st.integers(0, 10**6), byte=st.integers(0, 255))
def test_a_valid_message_with_one_byte_changed_decodes_or_is_a_decode_error(msg, at, byte):
    data = bytearray(encode_loads(msg))
    data[at % len(data)] = byte
    try:
        assert isinstance(decode_loads(bytes(data)), LoadsMsg)
    except DecodeError:
        pass


def test_the_layout_is_readable_by_zenohs_own_deserializer():
    layout = tuple[UInt8, float, list[tuple[str, str, float, float, float, str, str, str]]]
    got = z_deserialize(layout, zenoh.ZBytes(encode_loads(MSG)))
    assert got == (UInt8(1), 12.5, [("p1", "pallet", 4.0, 3.5, 1.5708, "resting", "rack-3", ""),
                                    ("o1", "beam", -1.25, 0.5, 0.25, "carried", "", "o1")])


def test_every_truncation_and_every_appended_byte_is_a_decode_error():
    data = encode_loads(MSG)
    for n in range(len(data)):
        with pytest.raises(DecodeError):
            decode_loads(data[:n])
    with pytest.raises(DecodeError, match="trailing"):
        decode_loads(data + b"\x00")


def test_oversized_payloads_and_counts_are_refused_before_anything_is_read():
    with pytest.raises(DecodeError, match=f"exceeds {MAX_PAYLOAD_BYTES}"):
        decode_loads(b"\x01" * (MAX_PAYLOAD_BYTES + 1))
    head = encode_loads(LoadsMsg(1.0))[:-1]  # version, stamp; the count follows
    with pytest.raises(DecodeError, match=f"loads must hold at most {MAX_LOADS}"):
        decode_loads(head + b"\xff\xff\xff\xff\x0f")
    many = tuple(LoadEntry(f"l{k}", "pallet", 0.0, 0.0, 0.0, "resting") for k in range(MAX_LOADS))
    assert len(decode_loads(encode_loads(LoadsMsg(0.0, many))).loads) == MAX_LOADS


@pytest.mark.parametrize("make, why", [
    (lambda: LoadEntry("p 1", "pallet", 0, 0, 0, "resting"), "name"),
    (lambda: LoadEntry("p1", "", 0, 0, 0, "resting"), "type"),
    (lambda: LoadEntry("p1", "pallet", float("nan"), 0, 0, "resting"), "x must be finite"),
    (lambda: LoadEntry("p1", "pallet", 0, 0, 0, "gone"), "state must be one of"),
    (lambda: LoadEntry("p1", "pallet", 0, 0, 0, "resting", station="a/b"), "station"),
    (lambda: LoadsMsg(0.0, (PALLET, PALLET)), "names a load twice"),
    (lambda: LoadsMsg(float("inf")), "stamp must be finite"),
    (lambda: LoadsMsg(0.0, (PALLET,) * (MAX_LOADS + 1)), "at most 256 loads"),
])
def test_invalid_fields_are_refused_naming_the_field(make, why):
    with pytest.raises(ValueError, match=why):
        make()


def test_a_decoded_invalid_entry_is_a_decode_error_naming_the_kind():
    bad = encode_loads(MSG).replace(b"resting", b"resized", 1)
    with pytest.raises(DecodeError, match="^loads: invalid message .*state"):
        decode_loads(bad)


def test_the_key_its_class_its_decoder_and_its_traffic_apart_from_the_orders():
    assert keys.loads_key("lab/w") == "lab/w/world/loads"
    assert keys.parse_key(P, f"{P}/world/loads") == (keys.LOADS, None)
    for other in (f"{P}/world", f"{P}/world/loads/x", f"{P}/world/other"):
        assert keys.key_class(P, other) == keys.OTHER
    assert decoders.DECODERS[keys.LOADS] is decode_loads
    counter = traffic.TrafficCounter(P)
    counter.count_put(f"{P}/world/loads", 90)
    snap = counter.snapshot()
    assert snap["put"][keys.LOADS] == {"messages": 1, "bytes": 90}
    assert traffic.orders_line(snap)["put"] == {"messages": 0, "bytes": 0}


def test_the_world_loads_row_exists_only_with_orders():
    robots = {"r1": "r1", "r2": "r2"}
    plain = acl.fleet_acl(robots, robots)
    assert not any(k.endswith("/world/loads") for r in plain["rules"] for k in r["key_exprs"])
    rows = acl.fleet_acl(robots, robots, orders=True)
    policy = {p["subjects"][0]: set(p["rules"]) for p in rows["policies"]}
    assert "world-loads" in policy[acl.CAMERA_USER]
    assert not any("world-loads" in policy[u] for u in ("r1", "r2", acl.VIEWER_USER,
                                                          acl.MANAGER_USER))


ROBOTS = {"r1": "r1"}


@pytest.fixture(scope="module")
def router(tmp_path_factory) -> Iterator[tuple[str, dict]]:
    with fleet_acl_router(tmp_path_factory.mktemp("loads-acl"), ROBOTS) as r:
        yield r


MARKERS = {acl.CAMERA_USER: keys.obstacles_key(P), "r1": keys.state_key(P, "r1"),
           acl.MANAGER_USER: keys.goal_key(P, "r1")}  # a key each talker may put


@pytest.mark.parametrize("user, allowed", [(acl.CAMERA_USER, True), ("r1", False),
                                           (acl.MANAGER_USER, False)])
def test_only_the_world_puts_the_loads_and_robots_and_viewers_hear_them(router, user, allowed):
    """Each talker puts the loads, then a marker on a key of its own on the same session: once
    the marker arrives at a robot and at a viewer, the loads would have arrived before it."""
    got: dict[str, queue.SimpleQueue[str]] = {}
    sessions = []
    try:
        for who in ("r1", acl.VIEWER_USER):
            got[who] = queue.SimpleQueue()
            session = open_as(router, who)
            sessions.append(session)
            session.declare_subscriber(f"{P}/**", lambda s, q=got[who]: q.put(str(s.key_expr)))
        with open_as(router, user) as talker:
            for who, heard in got.items():
                seen = _until_marker(talker, heard, MARKERS[user])
                assert (keys.loads_key(P) in seen) is allowed, who
    finally:
        for session in sessions:
            session.close()


def _until_marker(talker: zenoh.Session, heard: queue.SimpleQueue[str], marker: str) -> list[str]:
    seen: list[str] = []
    for _ in range(200):
        talker.put(keys.loads_key(P), encode_loads(MSG))
        talker.put(marker, b"m")
        try:
            while True:
                key = heard.get(timeout=0.1)
                if key == marker:
                    return seen
                seen.append(key)
        except queue.Empty:
            continue
    raise AssertionError(f"the marker {marker} never arrived")
