"""The rmw_zenoh wire format: what a plain Zenoh session must put so that ROS 2 on rmw_zenoh_cpp
takes it for one of its own publishers (pure functions; no session here).

Written against the sources of ros2/rmw_zenoh (rmw_zenoh_cpp), branches ``humble`` (0.1.x),
``jazzy`` (0.2.x) and ``rolling`` (``kilted`` is 0.6.x); each piece names the file that writes
and reads it. Four things, per sample or per publisher:

1. **The data key** (``TopicInfo::TopicInfo`` in ``src/detail/liveliness_utils.cpp``)::

       <domain id>/<fully qualified topic name without its leading '/'>/<type>/<type hash>

   e.g. ``0/a1/cmd_vel/geometry_msgs::msg::dds_::TwistStamped_/RIHS01_5f0f...``. The type is the
   DDS-style name of ``src/detail/type_support_common.cpp`` (``<pkg>::msg::dds_::<Name>_``).
   The hash is the REP-2011 type hash ``RIHS01_<sha256 hex>`` (:func:`rihs01`) on Jazzy and
   later; Humble has no type hashes and writes the constant ``TypeHashNotSupported``
   (rmw_zenoh PR #388, "Updates to compile against Humble").
2. **The payload**: the message's CDR with its 4-byte encapsulation header (``00 01 00 00``,
   little endian), exactly what zenoh-bridge-ros2dds carries; ``agent.base`` writes it.
3. **The attachment** every sample must carry (:func:`encode_attachment`): sequence number,
   source timestamp [ns since the UNIX epoch] and the publisher's 16-byte GID, written by
   ``AttachmentData::serialize_to_zbytes`` (``src/detail/attachment_helpers.cpp``) in
   ``PublisherData::publish`` (``src/detail/rmw_publisher_data.cpp``; the sequence number
   starts at 1 and counts up per publisher) and read back by the ``AttachmentData(const
   zenoh::Bytes &)`` constructor. A sample without one is dropped by the subscriber's sample
   callback in ``SubscriptionData::init`` (``src/detail/rmw_subscription_data.cpp``: "Unable
   to obtain attachment for topic ...", then ``return``). Two layouts, both zenoh-ext
   serialization (integers little endian, a string or byte sequence as a LEB128 length then
   its bytes):

   - ``keyed`` (Humble 0.1.0-0.1.1, Jazzy 0.2.0-0.2.3): the string ``"sequence_number"``, an
     int64, ``"source_timestamp"``, an int64, ``"source_gid"``, then the GID as a sequence
     (length 16, 16 bytes); a receiver checks each name and throws on a mismatch;
   - ``positional`` (rmw_zenoh PR #601: Rolling 0.6.0, Jazzy 0.2.4 via #605, Humble 0.1.2
     via #606, and every release since): int64, int64, then the GID as a sequence: 33 bytes.

   The GID is 16 bytes on every release (Humble's ``RMW_GID_STORAGE_SIZE`` is 24, but
   rmw_zenoh's humble branch hard-codes 16, PR #388). rmw_zenoh derives its own from the XXH3
   hash of the publisher's liveliness token (``Entity::Entity``); a subscriber only hands the
   attachment's GID on in ``rmw_message_info_t.publication_gid`` and never checks it against
   the graph, so :func:`publisher_gid` uses a BLAKE2 hash of the token (no extra dependency).
4. **Liveliness tokens** (``Entity::Entity`` and ``Entity::make`` in
   ``src/detail/liveliness_utils.cpp``; the same on Humble, Jazzy and Kilted), one for the
   node and one for each publisher, so that ``ros2 node list`` / ``ros2 topic list`` show them
   and the graph matches the publisher to the robot's subscription::

       @ros2_lv/<domain>/<zid>/<node id>/<entity id>/NN/<enclave>/<namespace>/<node name>
       @ros2_lv/<domain>/<zid>/<node id>/<entity id>/MP/<enclave>/<namespace>/<node name>/
           <topic name>/<type>/<type hash>/<qos>

   Every name is mangled by replacing each ``/`` with ``%`` (the empty namespace ``/`` and the
   default enclave ``/`` become ``%``). A node token repeats its node id as its entity id.
   ``<qos>`` is ``reliability:durability:history,depth:deadline s,ns:lifespan s,ns:liveliness,
   lease s,ns`` with the rmw enum numbers (``qos_to_keyexpr``); rmw_zenoh leaves a component
   empty when it equals *its* default, and that default changed (durability: transient local
   before Jazzy 0.2.3, volatile since, PR #530), so :func:`qos_keyexpr` writes reliability,
   durability, history and depth explicitly and leaves only the durations (infinite on every
   release) empty: every release reads the same QoS from it.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import struct
from dataclasses import dataclass

ADMIN_SPACE = "@ros2_lv"
NODE = "NN"
PUBLISHER = "MP"
SUBSCRIPTION = "MS"
ENTITY_KINDS = (NODE, PUBLISHER, SUBSCRIPTION, "SS", "SC")
TYPE_HASH_NOT_SUPPORTED = "TypeHashNotSupported"
GID_SIZE = 16  # [bytes] on every release (humble hard-codes 16, PR #388)
KEYED = "keyed"
POSITIONAL = "positional"
_ATTACHMENT_NAMES = ("sequence_number", "source_timestamp", "source_gid")

# rmw/types.h enum values (the same on Humble and later for the ones used here)
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST, KEEP_ALL = 1, 2


@dataclass(frozen=True)
class Release:
    """A published rmw_zenoh_cpp release line: what changes its wire format."""

    name: str
    distro: str
    versions: str  # which rmw_zenoh_cpp package versions (CHANGELOG.rst of each branch)
    type_hash: bool  # RIHS01 hash in keys and tokens (False: TypeHashNotSupported)
    attachment: str  # KEYED | POSITIONAL


RELEASES: dict[str, Release] = {
    r.name: r
    for r in (
        Release("humble", "humble", "0.1.2 and later (2025-06-19 on)", False, POSITIONAL),
        Release("humble-0.1.1", "humble", "0.1.0 and 0.1.1", False, KEYED),
        Release("jazzy", "jazzy", "0.2.4 and later (2025-04-20 on)", True, POSITIONAL),
        Release("jazzy-0.2.3", "jazzy", "0.2.0 to 0.2.3", True, KEYED),
        Release("kilted", "kilted", "0.6.0 and later", True, POSITIONAL),
    )
}
DEFAULT_RELEASE = {"humble": "humble", "jazzy": "jazzy", "kilted": "kilted"}


def release(name: str) -> Release:
    """The :class:`Release` called ``name``; ``ValueError`` naming the choices otherwise."""
    try:
        return RELEASES[name]
    except (KeyError, TypeError):
        raise ValueError(f"rmw_zenoh release {name!r} is not one of "
                         f"{', '.join(RELEASES)}") from None


# --- type names and REP-2011 type hashes -----------------------------------------------------

# REP-2011 field type ids (type_description_interfaces/msg/FieldType)
NESTED, INT32, UINT32, FLOAT64, STRING = 1, 6, 7, 11, 17
ARRAY_OFFSET = 48  # a fixed-size array of T has id T + 48


@dataclass(frozen=True)
class Field:
    name: str
    type_id: int
    nested: str = ""  # the nested type's name, e.g. geometry_msgs/msg/Vector3
    capacity: int = 0  # fixed arrays: their length


# The type descriptions (fields in declaration order) of the messages a base speaks, from the
# .msg files of builtin_interfaces, std_msgs, geometry_msgs and nav_msgs (common_interfaces).
TYPES: dict[str, tuple[Field, ...]] = {
    "builtin_interfaces/msg/Time": (Field("sec", INT32), Field("nanosec", UINT32)),
    "std_msgs/msg/Header": (Field("stamp", NESTED, "builtin_interfaces/msg/Time"),
                            Field("frame_id", STRING)),
    "geometry_msgs/msg/Vector3": (Field("x", FLOAT64), Field("y", FLOAT64), Field("z", FLOAT64)),
    "geometry_msgs/msg/Twist": (Field("linear", NESTED, "geometry_msgs/msg/Vector3"),
                                Field("angular", NESTED, "geometry_msgs/msg/Vector3")),
    "geometry_msgs/msg/TwistStamped": (Field("header", NESTED, "std_msgs/msg/Header"),
                                       Field("twist", NESTED, "geometry_msgs/msg/Twist")),
    "geometry_msgs/msg/Point": (Field("x", FLOAT64), Field("y", FLOAT64), Field("z", FLOAT64)),
    "geometry_msgs/msg/Quaternion": (Field("x", FLOAT64), Field("y", FLOAT64),
                                     Field("z", FLOAT64), Field("w", FLOAT64)),
    "geometry_msgs/msg/Pose": (Field("position", NESTED, "geometry_msgs/msg/Point"),
                               Field("orientation", NESTED, "geometry_msgs/msg/Quaternion")),
    "geometry_msgs/msg/PoseWithCovariance": (
        Field("pose", NESTED, "geometry_msgs/msg/Pose"),
        Field("covariance", FLOAT64 + ARRAY_OFFSET, capacity=36)),
    "geometry_msgs/msg/TwistWithCovariance": (
        Field("twist", NESTED, "geometry_msgs/msg/Twist"),
        Field("covariance", FLOAT64 + ARRAY_OFFSET, capacity=36)),
    "nav_msgs/msg/Odometry": (
        Field("header", NESTED, "std_msgs/msg/Header"), Field("child_frame_id", STRING),
        Field("pose", NESTED, "geometry_msgs/msg/PoseWithCovariance"),
        Field("twist", NESTED, "geometry_msgs/msg/TwistWithCovariance")),
}
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
ODOMETRY = "nav_msgs/msg/Odometry"


def dds_type_name(type_name: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (type_support_common.cpp's type name)."""
    parts = type_name.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"type name {type_name!r} is not pkg/msg/Name")
    return f"{parts[0]}::{parts[1]}::dds_::{parts[2]}_"


def _referenced(type_name: str, seen: set[str]) -> None:
    for f in TYPES[type_name]:
        if f.nested and f.nested not in seen:
            seen.add(f.nested)
            _referenced(f.nested, seen)


def _description(type_name: str) -> dict[str, object]:
    return {"type_name": type_name, "fields": [
        {"name": f.name, "type": {"type_id": f.type_id, "capacity": f.capacity,
                                  "string_capacity": 0, "nested_type_name": f.nested}}
        for f in TYPES[type_name]]}


def type_description_json(type_name: str) -> str:
    """REP-2011's hashed text: the type's description and every type it refers to (sorted by
    name), field default values left out, as compact JSON with ``", "`` and ``": "``."""
    if type_name not in TYPES:
        raise ValueError(f"type {type_name!r} has no description here (known: {', '.join(TYPES)})")
    refs: set[str] = set()
    _referenced(type_name, refs)
    doc = {"type_description": _description(type_name),
           "referenced_type_descriptions": [_description(t) for t in sorted(refs)]}
    return json.dumps(doc, ensure_ascii=True, allow_nan=False, separators=(", ", ": "))


def rihs01(type_name: str) -> str:
    """The REP-2011 type hash ``RIHS01_<sha256 hex of type_description_json>``."""
    return "RIHS01_" + hashlib.sha256(type_description_json(type_name).encode()).hexdigest()


def type_hash(type_name: str, rel: Release) -> str:
    """The hash part of keys and tokens on release ``rel``."""
    return rihs01(type_name) if rel.type_hash else TYPE_HASH_NOT_SUPPORTED


# --- names and the data key ------------------------------------------------------------------

_NAME_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _check_name(name: str, what: str) -> None:
    for tok in name.strip("/").split("/") if name.strip("/") else []:
        if not _NAME_TOKEN.match(tok):
            raise ValueError(f"{what} {name!r}: each part must be a ROS name (letters, digits, "
                             f"_, not starting with a digit)")


def namespace_of(ns: str | None) -> str:
    """A ROS namespace as rcl hands it over: ``/`` (none) or ``/a/b`` (no trailing ``/``)."""
    ns = ns or ""
    _check_name(ns, "namespace")
    return "/" + ns.strip("/") if ns.strip("/") else "/"


def fully_qualified(namespace: str | None, topic: str) -> str:
    """``topic`` (relative, or absolute when it starts with ``/``) in ``namespace``."""
    if not topic.strip("/"):
        raise ValueError(f"topic {topic!r} is empty")
    _check_name(topic, "topic")
    if topic.startswith("/"):
        return "/" + topic.strip("/")
    ns = namespace_of(namespace)
    return (ns.rstrip("/") + "/" + topic.strip("/")) if ns != "/" else "/" + topic.strip("/")


def check_domain(domain: int) -> int:
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= 232:
        raise ValueError(f"ROS domain id must be an integer in 0..232, got {domain!r}")
    return domain


def topic_key(domain: int, topic_name: str, type_name: str, rel: Release) -> str:
    """The data key of fully qualified ``topic_name`` (see the module's point 1)."""
    check_domain(domain)
    if not topic_name.startswith("/"):
        raise ValueError(f"topic name {topic_name!r} must be fully qualified (start with /)")
    return (f"{domain}/{topic_name.strip('/')}/{dds_type_name(type_name)}/"
            f"{type_hash(type_name, rel)}")


# --- the attachment --------------------------------------------------------------------------


@dataclass(frozen=True)
class Attachment:
    sequence_number: int
    source_timestamp: int  # [ns since the UNIX epoch]
    gid: bytes  # GID_SIZE bytes


def _leb128(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _read_leb128(buf: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while at < len(buf) and shift <= 63:
        byte = buf[at]
        value |= (byte & 0x7F) << shift
        at += 1
        if not byte & 0x80:
            return value, at
        shift += 7
    raise ValueError("attachment: truncated or overlong length")


def _seq(data: bytes) -> bytes:
    return _leb128(len(data)) + data


def encode_attachment(att: Attachment, layout: str) -> bytes:
    """The attachment bytes of ``layout`` (:data:`KEYED` or :data:`POSITIONAL`)."""
    if len(att.gid) != GID_SIZE:
        raise ValueError(f"gid must be {GID_SIZE} bytes, got {len(att.gid)}")
    seq, ts = struct.pack("<q", att.sequence_number), struct.pack("<q", att.source_timestamp)
    if layout == POSITIONAL:
        return seq + ts + _seq(bytes(att.gid))
    if layout == KEYED:
        names = [_seq(n.encode()) for n in _ATTACHMENT_NAMES]
        return names[0] + seq + names[1] + ts + names[2] + _seq(bytes(att.gid))
    raise ValueError(f"attachment layout {layout!r} is not {KEYED} or {POSITIONAL}")


def _take_seq(buf: bytes, at: int, what: str) -> tuple[bytes, int]:
    n, at = _read_leb128(buf, at)
    if at + n > len(buf):
        raise ValueError(f"attachment: {what} truncated")
    return buf[at:at + n], at + n


def _take_i64(buf: bytes, at: int, what: str) -> tuple[int, int]:
    if at + 8 > len(buf):
        raise ValueError(f"attachment: {what} truncated")
    return struct.unpack_from("<q", buf, at)[0], at + 8


def _take_name(buf: bytes, at: int, name: str) -> int:
    got, at = _take_seq(buf, at, f"the name {name}")
    if got != name.encode():
        raise ValueError(f"attachment: expected the name {name!r}, got {got[:32]!r}")
    return at


def decode_attachment(data: bytes, layout: str) -> Attachment:
    """Inverse of :func:`encode_attachment`; ``ValueError`` on anything else (trailing bytes
    included)."""
    buf, at = bytes(data), 0
    if layout not in (KEYED, POSITIONAL):
        raise ValueError(f"attachment layout {layout!r} is not {KEYED} or {POSITIONAL}")
    values: list[int] = []
    for name in _ATTACHMENT_NAMES[:2]:
        at = _take_name(buf, at, name) if layout == KEYED else at
        value, at = _take_i64(buf, at, name)
        values.append(value)
    at = _take_name(buf, at, "source_gid") if layout == KEYED else at
    gid, at = _take_seq(buf, at, "source_gid")
    if len(gid) != GID_SIZE:
        raise ValueError(f"attachment: gid must be {GID_SIZE} bytes, got {len(gid)}")
    if at != len(buf):
        raise ValueError(f"attachment: {len(buf) - at} trailing bytes")
    return Attachment(values[0], values[1], gid)


# --- liveliness tokens -----------------------------------------------------------------------


def mangle(name: str) -> str:
    """``/`` -> ``%`` (liveliness_utils.cpp ``mangle_name``)."""
    return name.replace("/", "%")


def demangle(name: str) -> str:
    return name.replace("%", "/")


def qos_keyexpr(reliability: int = RELIABLE, durability: int = VOLATILE,
                history: int = KEEP_LAST, depth: int = 10) -> str:
    """A publisher's QoS chunk, explicit where rmw_zenoh's defaults differ by release."""
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
        raise ValueError(f"QoS depth must be an integer >= 0, got {depth!r}")
    return f"{reliability}:{durability}:{history},{depth}:,:,:,,"


@dataclass(frozen=True)
class Entity:
    """What one liveliness token says."""

    domain: int
    zid: str
    node_id: int
    entity_id: int
    kind: str  # NN, MP, MS, SS, SC
    enclave: str
    namespace: str
    node_name: str
    topic: str = ""  # fully qualified; empty for a node
    type_name: str = ""  # DDS-style, e.g. geometry_msgs::msg::dds_::Twist_
    type_hash: str = ""
    qos: str = ""


def token(e: Entity) -> str:
    """The liveliness key expression of ``e`` (module point 4)."""
    check_domain(e.domain)
    if e.kind not in ENTITY_KINDS:
        raise ValueError(f"entity kind {e.kind!r} is not one of {ENTITY_KINDS}")
    parts = [ADMIN_SPACE, str(e.domain), e.zid, str(e.node_id), str(e.entity_id), e.kind,
             mangle(e.enclave), mangle(e.namespace), mangle(e.node_name)]
    if e.kind != NODE:
        parts += [mangle(e.topic), mangle(e.type_name), mangle(e.type_hash), e.qos]
    if any(not p for p in parts):
        raise ValueError(f"liveliness token of {e!r} would have an empty part")
    return "/".join(parts)


def parse_token(key: str) -> Entity:
    """Inverse of :func:`token`, with ``Entity::make(keyexpr)``'s checks; ``ValueError``."""
    parts = str(key).split("/")
    if len(parts) < 9 or any(not p for p in parts) or parts[0] != ADMIN_SPACE:
        raise ValueError(f"not an rmw_zenoh liveliness token: {str(key)[:120]!r}")
    kind = parts[5]
    if kind not in ENTITY_KINDS:
        raise ValueError(f"liveliness token: unknown entity {kind!r}")
    if kind != NODE and len(parts) < 13:
        raise ValueError(f"liveliness token: a {kind} token needs 13 parts, got {len(parts)}")
    try:
        domain, nid, eid = int(parts[1]), int(parts[3]), int(parts[4])
    except ValueError:
        raise ValueError(f"liveliness token: non-numeric domain or ids in {key!r}") from None
    topic = (demangle(parts[9]), demangle(parts[10]), demangle(parts[11]), parts[12]) \
        if kind != NODE else ("", "", "", "")
    return Entity(domain, parts[2], nid, eid, kind, demangle(parts[6]), demangle(parts[7]),
                  demangle(parts[8]), *topic)


def liveliness_selector(domain: int) -> str:
    """Every token of ``domain`` (what each rmw_zenoh context subscribes to)."""
    return f"{ADMIN_SPACE}/{check_domain(domain)}/**"


def publisher_gid(token_key: str) -> bytes:
    """A stable 16-byte GID for the publisher whose token is ``token_key`` (module point 3)."""
    return hashlib.blake2b(token_key.encode(), digest_size=GID_SIZE).digest()


@dataclass(frozen=True)
class PublisherSpec:
    """Everything an rmw_zenoh publisher needs: its data key, tokens and attachment layout."""

    key: str
    node_token: str
    publisher_token: str
    gid: bytes
    layout: str


def publisher_spec(
    rel: Release,
    zid: str,
    *,
    domain: int = 0,
    namespace: str | None = None,
    node_name: str = "formation_agent",
    topic: str = "cmd_vel",
    type_name: str = TWIST_STAMPED,
    node_id: int = 0,
    qos: str | None = None,
) -> PublisherSpec:
    """The key, tokens, GID and layout of one publisher of ``topic`` in ``namespace``."""
    if not _NAME_TOKEN.match(node_name):
        raise ValueError(f"node name {node_name!r} is not a ROS name")
    if not re.match(r"^[0-9a-f]+$", zid):
        raise ValueError(f"zid {zid!r} is not a Zenoh id (lowercase hex)")
    ns = namespace_of(namespace)
    name = fully_qualified(ns, topic)
    node = Entity(domain, zid, node_id, node_id, NODE, "/", ns, node_name)
    pub = Entity(domain, zid, node_id, node_id + 1, PUBLISHER, "/", ns, node_name, name,
                 dds_type_name(type_name), type_hash(type_name, rel), qos or qos_keyexpr())
    pub_token = token(pub)
    return PublisherSpec(topic_key(domain, name, type_name, rel), token(node), pub_token,
                         publisher_gid(pub_token), rel.attachment)


def subscription_selector(domain: int, topic_name: str, type_name: str, rel: Release) -> str:
    """Tokens of every subscription to ``topic_name`` of ``type_name`` (``--status``); the
    QoS chunk and whatever follows it (rolling appends an optional buffer-backends chunk)."""
    return (f"{ADMIN_SPACE}/{check_domain(domain)}/*/*/*/{SUBSCRIPTION}/*/*/*/"
            f"{mangle(topic_name)}/{mangle(dds_type_name(type_name))}/"
            f"{mangle(type_hash(type_name, rel))}/**")


# --- a robot's settings (agent config, deploy inventory, formation run) ----------------------

CMD_TYPES = {"Twist": TWIST, "TwistStamped": TWIST_STAMPED}


@dataclass(frozen=True)
class RmwSettings:
    """How one robot's base is reached over rmw_zenoh (no bridge). Empty strings take the
    base's defaults (:func:`resolve`): the release and command type of its ROS distribution."""

    release: str = ""  # a key of RELEASES
    cmd_type: str = ""  # Twist | TwistStamped
    namespace: str = ""  # the robot's ROS namespace ("" = none)
    domain: int = 0  # ROS_DOMAIN_ID

    def __post_init__(self) -> None:
        check_settings(self)  # a robot file's values are checked where they are built


def check_settings(s: RmwSettings) -> RmwSettings:
    """``s`` if every field is valid, else ``ValueError`` naming the field."""
    if s.release:
        release(s.release)
    if s.cmd_type and s.cmd_type not in CMD_TYPES:
        raise ValueError(f"cmd_type {s.cmd_type!r} is not one of {', '.join(CMD_TYPES)}")
    namespace_of(s.namespace)
    check_domain(s.domain)
    return s


def resolve(s: RmwSettings, distro: str) -> tuple[Release, str]:
    """The release and message type name (``pkg/msg/Name``) for a base of ``distro``
    (humble: Twist; jazzy and later: TwistStamped, as their TurtleBot3 bringup reads)."""
    check_settings(s)
    if not s.release and distro not in DEFAULT_RELEASE:
        raise ValueError(f"ROS distribution {distro!r} is not one of {', '.join(DEFAULT_RELEASE)}")
    rel = release(s.release or DEFAULT_RELEASE[distro])
    cmd = s.cmd_type or ("Twist" if rel.distro == "humble" else "TwistStamped")
    return rel, CMD_TYPES[cmd]


def settings_from_dict(d: object) -> RmwSettings:
    """An :class:`RmwSettings` from a plain mapping (an agent config file's ``rmw``)."""
    if not isinstance(d, dict):
        raise ValueError(f"rmw: must be a mapping, got {d!r}")
    unknown = sorted(set(d) - {"release", "cmd_type", "namespace", "domain"})
    if unknown:
        raise ValueError(f"rmw: unknown field {unknown[0]!r}")
    return check_settings(RmwSettings(
        release=str(d.get("release", "")), cmd_type=str(d.get("cmd_type", "")),
        namespace=str(d.get("namespace", "")), domain=d.get("domain", 0)))


def distro_of(base: str) -> str:
    """``turtlebot3-jazzy`` -> ``jazzy`` (the ROS distribution a TurtleBot3 base runs)."""
    return base.rsplit("-", 1)[-1]


def data_key(s: RmwSettings, distro: str, topic: str = "cmd_vel") -> str:
    """The data key of ``topic`` in the robot's namespace, as its base reads it."""
    rel, type_name = resolve(s, distro)
    return topic_key(s.domain, fully_qualified(s.namespace, topic), type_name, rel)


def graph_key(s: RmwSettings) -> str:
    """Every liveliness token in the robot's namespace and domain (its nodes, publishers,
    subscriptions): ``@ros2_lv/<domain>/<zid>/<nid>/<id>/<kind>/<enclave>/<namespace>/**``."""
    return f"{ADMIN_SPACE}/{check_domain(s.domain)}/*/*/*/*/*/{mangle(namespace_of(s.namespace))}/**"


# --- a ROS 2 base's odometry (nav_msgs/msg/Odometry), over the bridge and over rmw_zenoh ---

CDR_LE = b"\x00\x01\x00\x00"  # the payload's encapsulation header: CDR, little endian
_ODOMETRY_DOUBLES = 3 + 4 + 36 + 6 + 36  # pose, orientation, its covariance, twist, covariance


@dataclass(frozen=True)
class Odometry:
    """What the agent reads of a ``nav_msgs/msg/Odometry``: the header's stamp [s] and frame,
    the child frame, the pose in the odometry frame (x, y [m], yaw [rad] from the quaternion)
    and the body-frame velocity (vx [m/s], wz [rad/s])."""

    stamp: float
    frame_id: str
    child_frame_id: str
    x: float
    y: float
    yaw: float
    vx: float
    wz: float


def _cdr_string(body: bytes, at: int, what: str) -> tuple[str, int]:
    """A CDR string at ``at`` (aligned to 4): uint32 length with its NUL, then the bytes."""
    at = (at + 3) // 4 * 4
    if at + 4 > len(body):
        raise ValueError(f"Odometry: {what} truncated")
    (length,) = struct.unpack_from("<I", body, at)
    end = at + 4 + length
    if length < 1 or end > len(body) or body[end - 1] != 0:
        raise ValueError(f"Odometry: {what} is malformed")
    try:
        return body[at + 4:end - 1].decode("utf-8"), end
    except UnicodeDecodeError:
        raise ValueError(f"Odometry: {what} is not UTF-8") from None


def decode_odometry(payload: bytes) -> Odometry:
    """A ``nav_msgs/msg/Odometry`` payload as zenoh-bridge-ros2dds and rmw_zenoh carry it (its
    CDR with the encapsulation header; alignment counts from after the header). ValueError on
    a malformed or non-finite one."""
    data = bytes(payload)
    if data[:4] != CDR_LE:
        raise ValueError(f"Odometry: expected the CDR_LE header 00 01 00 00, got {data[:4].hex(' ')}")
    body = data[4:]
    if len(body) < 8:
        raise ValueError("Odometry: truncated in its header")
    sec, nanosec = struct.unpack_from("<iI", body, 0)
    frame_id, at = _cdr_string(body, 8, "frame_id")
    child, at = _cdr_string(body, at, "child_frame_id")
    at = (at + 7) // 8 * 8
    if len(body) != at + 8 * _ODOMETRY_DOUBLES:
        raise ValueError(f"Odometry: must be {4 + at + 8 * _ODOMETRY_DOUBLES} bytes, got {len(data)}")
    v = struct.unpack_from(f"<{_ODOMETRY_DOUBLES}d", body, at)
    if not all(math.isfinite(x) for x in v[:7] + v[43:49]):
        raise ValueError("Odometry: a non-finite pose or twist")
    qx, qy, qz, qw = v[3:7]
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return Odometry(sec + nanosec * 1e-9, frame_id, child, v[0], v[1], yaw, v[43], v[48])


def _put_cdr_string(body: bytearray, text: str) -> None:
    body += bytes(-len(body) % 4)
    raw = text.encode("utf-8") + b"\x00"
    body += struct.pack("<I", len(raw)) + raw


def encode_odometry(stamp: float, pose: tuple[float, float, float],
                    twist: tuple[float, float] = (0.0, 0.0), frame_id: str = "odom",
                    child_frame_id: str = "base_footprint") -> bytes:
    """The ``nav_msgs/msg/Odometry`` payload :func:`decode_odometry` reads: ``stamp`` [s] in the
    header, ``pose`` (x, y [m], yaw [rad]) as position and a quaternion about z, ``twist`` (vx
    [m/s], wz [rad/s]); zero covariances. What a base publishes (a test's fake base)."""
    sec = math.floor(stamp)
    nanosec = min(999_999_999, round((stamp - sec) * 1e9))
    body = bytearray(struct.pack("<iI", sec, nanosec))
    _put_cdr_string(body, frame_id)
    _put_cdr_string(body, child_frame_id)
    body += bytes(-len(body) % 8)
    x, y, yaw = pose
    quaternion = (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))
    zeros = (0.0,) * 36
    body += struct.pack("<43d", x, y, 0.0, *quaternion, *zeros)  # pose, orientation, covariance
    body += struct.pack("<42d", twist[0], 0.0, 0.0, 0.0, 0.0, twist[1], *zeros)  # twist, covariance
    return CDR_LE + bytes(body)


def odom_data_key(s: RmwSettings, distro: str) -> str:
    """The data key of the base's ``odom`` topic (nav_msgs/msg/Odometry, every distribution)
    in the robot's namespace, under rmw_zenoh; over zenoh-bridge-ros2dds it is the topic's name
    in the bridge's namespace (``{namespace}/odom``), carrying the same CDR."""
    rel, _cmd = resolve(s, distro)
    return topic_key(s.domain, fully_qualified(s.namespace, "odom"), ODOMETRY, rel)
