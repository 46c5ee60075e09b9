"""The rmw_zenoh wire format (wire.rmw_zenoh, agent.base.RmwZenohBase), checked against
independent implementations: rosbags for the REP-2011 type hashes and the CDR bytes, zenoh-ext's
serializer (zenoh-python) for the attachment, and golden bytes per rmw_zenoh release."""

from __future__ import annotations

import math

import pytest
import zenoh.ext as zext
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from agent.base import RmwZenohBase, decode_cmd, encode_cmd
from wire import rmw_zenoh as rmw

STORE = get_typestore(Stores.ROS2_JAZZY)
ZID = "aac3178e146ba6f1fc6e6a4085e77f21"


@pytest.mark.parametrize("type_name", [rmw.TWIST, rmw.TWIST_STAMPED, rmw.ODOMETRY])
def test_type_hashes_match_rosbags(type_name):
    assert rmw.rihs01(type_name) == STORE.hash_rihs01(type_name)


def test_type_hash_literals():
    # the published hashes of the stock messages (also `ros2 interface show --hash` on Jazzy)
    assert rmw.rihs01(rmw.TWIST) == (
        "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a")
    assert rmw.rihs01(rmw.TWIST_STAMPED) == (
        "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64")


def test_keys_per_release():
    jazzy, humble = rmw.release("jazzy"), rmw.release("humble")
    assert rmw.topic_key(0, "/a1/cmd_vel", rmw.TWIST_STAMPED, jazzy) == (
        "0/a1/cmd_vel/geometry_msgs::msg::dds_::TwistStamped_/RIHS01_"
        "5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64")
    assert rmw.topic_key(7, "/cmd_vel", rmw.TWIST, humble) == (
        "7/cmd_vel/geometry_msgs::msg::dds_::Twist_/TypeHashNotSupported")
    with pytest.raises(ValueError, match="fully qualified"):
        rmw.topic_key(0, "cmd_vel", rmw.TWIST, humble)
    with pytest.raises(ValueError, match="domain"):
        rmw.topic_key(233, "/cmd_vel", rmw.TWIST, humble)


def test_names_are_qualified_like_rcl():
    assert rmw.fully_qualified(None, "cmd_vel") == "/cmd_vel"
    assert rmw.fully_qualified("a1", "cmd_vel") == "/a1/cmd_vel"
    assert rmw.fully_qualified("/fleet/a1/", "cmd_vel") == "/fleet/a1/cmd_vel"
    assert rmw.fully_qualified("a1", "/cmd_vel") == "/cmd_vel"
    for bad in ("a-1", "1a", "a b"):
        with pytest.raises(ValueError, match="namespace"):
            rmw.namespace_of(bad)


@settings(deadline=None)  # the first call loads rosbags' generated classes
@given(v=st.floats(-1, 1), omega=st.floats(-4, 4))
def test_twist_cdr_matches_rosbags(v, omega):
    payload = encode_cmd(rmw.TWIST, v, omega, 0.0)
    msg = STORE.deserialize_cdr(payload, rmw.TWIST)
    assert (msg.linear.x, msg.angular.z) == pytest.approx(
        (max(-0.22, min(0.22, v)), max(-2.84, min(2.84, omega))))
    assert STORE.serialize_cdr(msg, rmw.TWIST).tobytes() == payload


@settings(deadline=None)
@given(v=st.floats(-0.2, 0.2), omega=st.floats(-2, 2), stamp=st.floats(0, 2e9),
       frame=st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=12))
def test_twist_stamped_cdr_matches_rosbags(v, omega, stamp, frame):
    payload = encode_cmd(rmw.TWIST_STAMPED, v, omega, stamp, frame)
    msg = STORE.deserialize_cdr(payload, rmw.TWIST_STAMPED)
    assert msg.header.frame_id == frame
    assert (msg.twist.linear.x, msg.twist.angular.z) == (v, omega)
    assert STORE.serialize_cdr(msg, rmw.TWIST_STAMPED).tobytes() == payload
    got_v, got_w, got_stamp = decode_cmd(rmw.TWIST_STAMPED, payload)
    assert (got_v, got_w) == (v, omega) and math.isclose(got_stamp or 0.0, stamp, abs_tol=1e-6)


GID = bytes(range(16))
ATT = rmw.Attachment(1, 1_700_000_000_123_456_789, GID)
# golden bytes: int64 LE 1, int64 LE 1700000000123456789, LEB128 16, the GID
POSITIONAL = bytes.fromhex("0100000000000000" "15cd853dfe9c9717" "10") + GID
KEYED = (b"\x0fsequence_number" + bytes.fromhex("0100000000000000")
         + b"\x10source_timestamp" + bytes.fromhex("15cd853dfe9c9717")
         + b"\x0asource_gid" + b"\x10" + GID)


def test_attachment_golden_bytes_per_release():
    # positional: rmw_zenoh PR #601 (rolling 0.6.0), #605 (jazzy 0.2.4), #606 (humble 0.1.2)
    assert rmw.release("jazzy").attachment == rmw.release("humble").attachment == rmw.POSITIONAL
    assert rmw.encode_attachment(ATT, rmw.POSITIONAL) == POSITIONAL
    assert len(POSITIONAL) == 33
    # keyed: humble 0.1.0-0.1.1 and jazzy 0.2.0-0.2.3
    assert rmw.release("jazzy-0.2.3").attachment == rmw.release("humble-0.1.1").attachment
    assert rmw.encode_attachment(ATT, rmw.KEYED) == KEYED
    assert rmw.decode_attachment(POSITIONAL, rmw.POSITIONAL) == ATT
    assert rmw.decode_attachment(KEYED, rmw.KEYED) == ATT


@settings(deadline=None)
@given(seq=st.integers(-(2**63), 2**63 - 1), ts=st.integers(-(2**63), 2**63 - 1),
       gid=st.binary(min_size=16, max_size=16))
def test_attachment_is_zenoh_ext_serialization(seq, ts, gid):
    """zenoh-ext's own serializer (what rmw_zenoh_cpp links) writes the same bytes."""
    att = rmw.Attachment(seq, ts, gid)
    positional = zext.z_serialize((zext.Int64(seq), zext.Int64(ts), gid)).to_bytes()
    keyed = zext.z_serialize(("sequence_number", zext.Int64(seq), "source_timestamp",
                              zext.Int64(ts), "source_gid", gid)).to_bytes()
    assert rmw.encode_attachment(att, rmw.POSITIONAL) == positional
    assert rmw.encode_attachment(att, rmw.KEYED) == keyed
    assert rmw.decode_attachment(positional, rmw.POSITIONAL) == att
    assert rmw.decode_attachment(keyed, rmw.KEYED) == att


@pytest.mark.parametrize("data,layout,match", [
    (POSITIONAL[:-1], rmw.POSITIONAL, "truncated"),
    (POSITIONAL + b"\x00", rmw.POSITIONAL, "trailing"),
    (POSITIONAL[:16] + b"\x0f" + GID[:15], rmw.POSITIONAL, "16 bytes"),
    (KEYED, rmw.POSITIONAL, "gid|truncated|trailing"),
    (POSITIONAL, rmw.KEYED, "expected the name|truncated"),
    (KEYED.replace(b"source_gid", b"source_gix"), rmw.KEYED, "source_gid"),
    (b"", rmw.POSITIONAL, "truncated"),
])
def test_malformed_attachments_are_refused(data, layout, match):
    with pytest.raises(ValueError, match=match):
        rmw.decode_attachment(data, layout)


def test_tokens_parse_as_documented():
    # the examples of rmw_zenoh's docs/design.md ("Graph Cache")
    node = rmw.parse_token(f"@ros2_lv/0/{ZID}/0/0/NN/%/%/listener")
    assert (node.kind, node.namespace, node.node_name, node.enclave) == ("NN", "/", "listener", "/")
    talker = rmw.parse_token(
        "@ros2_lv/0/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        "std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503"
        "259e948f6b1a18/::,7:,:,:,,")
    assert (talker.kind, talker.topic, talker.entity_id, talker.qos) == (
        "MP", "/chatter", 10, "::,7:,:,:,,")
    for bad in ("@ros2_lv/0/z/0/0/NN/%/%", "@ros2/0/z/0/0/NN/%/%/n", "@ros2_lv/0/z/0/0/XX/%/%/n",
                "@ros2_lv/0/z/0/0/MP/%/%/n/%t", "@ros2_lv/0/z//0/NN/%/%/n"):
        with pytest.raises(ValueError):
            rmw.parse_token(bad)


@pytest.mark.parametrize("name", ["humble", "jazzy", "jazzy-0.2.3"])
def test_publisher_spec_tokens_round_trip(name):
    rel = rmw.release(name)
    type_name = rmw.TWIST if rel.distro == "humble" else rmw.TWIST_STAMPED
    spec = rmw.publisher_spec(rel, ZID, domain=3, namespace="a1", type_name=type_name)
    assert spec.node_token == f"@ros2_lv/3/{ZID}/0/0/NN/%/%a1/formation_agent"
    pub = rmw.parse_token(spec.publisher_token)
    assert (pub.domain, pub.zid, pub.node_id, pub.entity_id, pub.kind) == (3, ZID, 0, 1, "MP")
    assert (pub.namespace, pub.node_name, pub.topic) == ("/a1", "formation_agent", "/a1/cmd_vel")
    assert pub.type_name == rmw.dds_type_name(type_name)
    assert pub.type_hash == rmw.type_hash(type_name, rel)
    assert pub.qos == "1:2:1,10:,:,:,,"  # reliable, volatile, keep last 10, explicitly
    assert rmw.token(pub) == spec.publisher_token
    assert spec.key == rmw.topic_key(3, "/a1/cmd_vel", type_name, rel)
    assert spec.layout == rel.attachment and len(spec.gid) == rmw.GID_SIZE


def test_settings_resolve_per_distribution():
    s = rmw.RmwSettings(namespace="a1")
    assert rmw.resolve(s, "humble") == (rmw.release("humble"), rmw.TWIST)
    assert rmw.resolve(s, "jazzy") == (rmw.release("jazzy"), rmw.TWIST_STAMPED)
    s2 = rmw.RmwSettings(release="jazzy-0.2.3", cmd_type="Twist")
    assert rmw.resolve(s2, "humble") == (rmw.release("jazzy-0.2.3"), rmw.TWIST)
    for bad, match in (({"release": "iron"}, "release"), ({"cmd_type": "Twist2"}, "cmd_type"),
                       ({"domain": -1}, "domain")):
        with pytest.raises(ValueError, match=match):  # checked where built
            rmw.RmwSettings(**bad)
    assert rmw.settings_from_dict({"namespace": "a1", "domain": 4}) == rmw.RmwSettings(
        namespace="a1", domain=4)
    with pytest.raises(ValueError, match="unknown field 'ns'"):
        rmw.settings_from_dict({"ns": "a1"})


def test_base_numbers_its_samples_and_stops_once():
    spec = rmw.publisher_spec(rmw.release("jazzy"), ZID, namespace="a1")
    sent: list[tuple[bytes, bytes]] = []
    closed: list[int] = []
    clock = iter(range(100, 200))
    base = RmwZenohBase(rmw.TWIST_STAMPED, spec, lambda p, a: sent.append((p, a)),
                        clock_ns=lambda: next(clock), close=lambda: closed.append(1))
    base.send(0.1, 0.5, 3.25)
    base.send(9.0, float("nan"), 3.5)  # clamped / non-finite -> stop
    base.stop()
    base.stop()
    atts = [rmw.decode_attachment(a, rmw.POSITIONAL) for _, a in sent]
    assert [a.sequence_number for a in atts] == [1, 2, 3, 4]
    assert [a.source_timestamp for a in atts] == [100, 101, 102, 103]
    assert {a.gid for a in atts} == {spec.gid}
    cmds = [decode_cmd(rmw.TWIST_STAMPED, p) for p, _ in sent]
    assert cmds[0] == pytest.approx((0.1, 0.5, 3.25))
    assert cmds[1][:2] == (0.0, 0.0) and cmds[2][:2] == (0.0, 0.0)
    assert closed == [1]
