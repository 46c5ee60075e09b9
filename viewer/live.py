"""Watch a running fleet over Zenoh, read-only, and turn what it says into frames.

:class:`FleetWatcher` subscribes with wildcards to the keys a viewer may read (every robot's
``pose``, ``state``, ``cmd`` and ``diag``, every formation's ``ellipse``, ``status`` and
``plan``, the ``obstacles``);
its callbacks only keep the newest payload of each key (raw bytes, no decoding on Zenoh's
threads). :meth:`FleetWatcher.frame` decodes the newest of each with the defensive decoders of
:mod:`wire.payloads` and :mod:`wire.diag` (a malformed payload is dropped and counted in
``rejected``) and builds a :mod:`viewer.frame` frame. The frame's time is the newest pose stamp
(simulated seconds in lock-step, wall time on real fleets). A formation's row says what its
leader reports on ``status`` (state, distance along the route, waypoint, leader) when the leader
has said it, else what its members' diagnostics show; each leader's ``plan`` gives the route
drawn on the floor (``routes``). Given the scenario (``formation run --live``), each
formation's load is placed from its members' poses and its overlaps are found as the run's
safety monitor finds them (:class:`viewer.loads.LoadView`); without one (``formation view``)
the loads are the hulls of the members' body centres, and no overlaps are shown.

A robot whose ``state`` carries a confidence radius (``sigma``: it drives on its own estimate,
``controller.localisation: fused``) gets ``est_x, est_y, sigma_m`` as in a simulation's frame:
the body its estimated control point and heading place (the scenario's control offset; none
without a scenario), beside the pose the camera last saw. Given the scenario, its blind floor
is drawn (``blind``). A lifelong fleet's orders (each order's ``order/{oid}`` and the
``order/{oid}/status`` its team's leader reports) become the frame's ``orders`` and
``order_counts`` (:mod:`viewer.orders`), once one has been heard; its loads its ``cargo``: the
ones ``formation run``'s world puts on ``world/loads`` (resting and carried, each outlined by its
type, given the scenario), else the resting ones published among the shelves.

It never publishes anything, so it works with any fleet, simulated or real, that the session's
credentials may read.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from typing import Any

import zenoh

from geometry.limits import BURGER_RADIUS
from scenario.lifelong import outline_at
from wire import keys
from wire.diag import DIAG, all_diag_key, decode_diag
from wire.navigation import PlanMsg, StatusMsg, decode_plan, decode_status
from wire.orders import (
    LoadsMsg,
    OrderMsg,
    OrderStatusMsg,
    all_orders_key,
    decode_loads,
    decode_order,
    decode_order_status,
    parse_order_key,
)
from wire.payloads import (
    DecodeError,
    Pose,
    decode_cmd,
    decode_ellipse,
    decode_obstacles,
    decode_pose,
    decode_state,
)
from wire.shapes import msg_to_shape
from wire.traffic import in_order

from .frame import Frame, blind_entries, formation_status, num, shape_entries
from .loads import LoadView, hull_entries
from .orders import ordered_counts

# robot key kind -> (field of a robot's entry, decoder); poses are handled apart (they set the time)
_ROBOT_KINDS = {keys.STATE: ("state", decode_state), keys.CMD: ("cmd", decode_cmd),
                DIAG: ("diag", decode_diag)}

# formation key kind -> decoder
_FORMATION_KINDS: dict[str, Callable[[bytes], Any]] = {
    keys.ELLIPSE: decode_ellipse, keys.STATUS: decode_status, keys.PLAN: decode_plan}

logger = logging.getLogger(__name__)

DEFAULT_RADIUS = BURGER_RADIUS  # [m] TurtleBot3 burger, when the fleet does not say
DEFAULT_TOLERANCE = 0.05  # [m]


class FleetWatcher:
    """Newest payload per key of a fleet's key space (see the module docstring)."""

    def __init__(self, session: zenoh.Session, prefix: str = keys.DEFAULT_PREFIX,
                 radius: float = DEFAULT_RADIUS, tolerance: float = DEFAULT_TOLERANCE,
                 scenario: Any = None) -> None:
        """``scenario``: the fleet's, when known (its loads; see the module docstring)."""
        self.prefix = keys.validate_prefix(prefix)
        self.radius = radius
        self.loads = None if scenario is None else LoadView(scenario)
        self.offset = 0.0 if scenario is None else scenario.robot.control_offset
        boxes = () if scenario is None else scenario.world.camera_blind
        life = getattr(scenario, "lifelong", None)
        self.load_names = {ld.name for ld in life.loads} if life is not None else set()
        self.life = life
        self.blind = {"blind": blind_entries(boxes)} if boxes else {}
        self.tolerance = tolerance
        self._lock = threading.Lock()
        self._latest: dict[str, bytes] = {}
        self.received = 0
        self.rejected: dict[str, int] = {}
        self._decoded: dict[str, tuple[bytes, Any]] = {}  # key -> (payload, decoded) cache
        self.t0: float | None = None  # the earliest time heard: the run's start for run --live
        p = self.prefix
        exprs = [keys.all_robots_key(p, keys.POSE), keys.all_robots_key(p, keys.STATE),
                 keys.all_robots_key(p, keys.CMD), all_diag_key(p),
                 keys.all_formations_key(p, keys.ELLIPSE), keys.all_formations_key(p, keys.STATUS),
                 keys.all_formations_key(p, keys.PLAN), keys.obstacles_key(p),
                 all_orders_key(p), all_orders_key(p) + "/status", keys.loads_key(p)]
        self._subs = [session.declare_subscriber(
            e, in_order(self.on_sample)) for e in exprs]

    def on_sample(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        key = str(sample.key_expr)
        with self._lock:
            self._latest[key] = data
            self.received += 1

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # the session may be closed already
                logger.debug("undeclare failed", exc_info=True)
        self._subs.clear()

    def _decode(self, key: str, data: bytes, decode: Callable[[bytes], Any], cls: str) -> Any:
        cached = self._decoded.get(key)
        if cached is not None and cached[0] is data:
            return cached[1]
        try:
            value = decode(data)
        except DecodeError:  # dropped and counted; the last good one stays
            self.rejected[cls] = self.rejected.get(cls, 0) + 1
            value = cached[1] if cached is not None else None
        self._decoded[key] = (data, value)
        return value

    def frame(self) -> Frame | None:
        """The fleet as it was last heard of; ``None`` before any pose arrived."""
        with self._lock:
            latest = dict(self._latest)
        heard = _Heard()
        head = self.prefix + "/"
        for key, data in latest.items():
            if key.startswith(head):
                self._take(heard, key, key[len(head):].split("/"), data)
        if heard.t is None:
            return None
        if self.t0 is None or heard.t < self.t0:
            self.t0 = heard.t
        out_robots = [_robot_entry(rid, pose, heard.robots[rid], self.offset)
                      for rid in sorted(heard.robots)
                      if (pose := heard.robots[rid].get("pose")) is not None]
        told = heard.told
        names = sorted({r["formation"] for r in out_robots})
        ellipses = sorted(({"formation": e.formation, "cx": e.cx, "cy": e.cy, "alpha": e.alpha,
                            "a": e.a, "b": e.b} for e in told[keys.ELLIPSE].values()),
                          key=lambda e: e["formation"])
        # a status or plan about another formation than its key names is not that formation's
        reports: dict[str, StatusMsg] = {f: m for f, m in told[keys.STATUS].items() if m.formation == f}
        plans: dict[str, PlanMsg] = {f: m for f, m in told[keys.PLAN].items() if m.formation == f}
        return {"t": heard.t, "t0": self.t0, "radius": self.radius, "robots": out_robots,
                "ellipses": ellipses,
                "obstacles": heard.obstacles,
                **self._shapes(heard), **self._cargo(heard),
                **self._loads(out_robots, heard.obstacles),
                "routes": [{"formation": f, "points": [[num(x), num(y)] for x, y in plans[f].route]}
                           for f in sorted(plans)],
                "formations": [leader_report(formation_status(n, out_robots, self.tolerance),
                                             reports.get(n)) for n in names],
                **self.blind, **order_fields(heard.orders, heard.order_status)}

    def _shapes(self, heard: _Heard) -> dict[str, list]:
        """The walls and shelves heard; a lifelong fleet's resting loads, published among them
        by name (an order's new load is named by the order, a resting load by the scenario),
        are its ``cargo`` instead."""
        names = set(heard.orders) | self.load_names
        if not names:
            return {"shapes": heard.shapes}
        cargo = [{"name": sh["name"], "type": "", "state": "resting", "station": "", "order": "",
                  "outline": sh["corners"]} for sh in heard.shapes if sh["name"] in names]
        return {"shapes": [sh for sh in heard.shapes if sh["name"] not in names],
                **({"cargo": cargo} if cargo else {})}

    def _cargo(self, heard: _Heard) -> dict[str, list]:
        """The loads the world put on ``world/loads``, outlined by their types (none without
        the scenario, or of a type it does not have)."""
        if heard.loads is None or self.life is None:
            return {}
        types = self.life.type_by_name
        return {"cargo": [{"name": e.name, "type": e.type, "state": e.state, "station": e.station,
                           "order": e.order, "outline": [[x, y] for x, y in outline_at(
                               types[e.type], (e.x, e.y, e.yaw))]}
                          for e in heard.loads.loads if e.type in types]}

    def _loads(self, robots: list[dict], obstacles: list[dict]) -> dict[str, list]:
        if self.loads is None:
            return {"loads": hull_entries(robots), "load_hits": []}
        return self.loads.fields(robots, obstacles)

    def _take(self, heard: _Heard, key: str, parts: list[str], data: bytes) -> None:
        """Decode the newest payload ``data`` of ``key`` (``parts``: its path below the prefix)
        into ``heard``; keys a viewer does not draw are left alone."""
        if parts[:1] == ["order"]:
            self._take_order(heard, key, data)
            return
        if parts == ["world", keys.LOADS]:
            heard.loads = self._decode(key, data, decode_loads, keys.LOADS)
            return
        if parts == [keys.OBSTACLES]:
            msg = self._decode(key, data, decode_obstacles, keys.OBSTACLES)
            if msg is not None:
                heard.obstacles = [{"name": o.id, "x": o.x, "y": o.y, "ds": o.ds}
                                   for o in msg.obstacles]
                heard.shapes = shape_entries(msg_to_shape(m) for m in msg.shapes)
            return
        if len(parts) != 3:
            return
        group, ident, kind = parts
        if group == "formation" and kind in _FORMATION_KINDS:
            msg = self._decode(key, data, _FORMATION_KINDS[kind], kind)
            if msg is not None:
                heard.told[kind][ident] = msg
        elif group == "robot":
            self._take_robot(heard, key, ident, kind, data)

    def _take_order(self, heard: _Heard, key: str, data: bytes) -> None:
        """An order as posted, or its status as its team's leader reports it (a status about
        another order than its key names is not that order's); bids are not drawn."""
        parsed = parse_order_key(key, self.prefix)
        if parsed is None or parsed[1] == "bid":
            return
        oid, what, _ = parsed
        if what == "order":
            msg = self._decode(key, data, decode_order, "order")
            if msg is not None and msg.oid == oid:
                heard.orders[oid] = msg
        else:
            msg = self._decode(key, data, decode_order_status, "order_status")
            if msg is not None and msg.oid == oid:
                heard.order_status[oid] = msg

    def _take_robot(self, heard: _Heard, key: str, rid: str, kind: str, data: bytes) -> None:
        r = heard.robots.setdefault(rid, {})
        if kind == keys.POSE:
            msg = self._decode(key, data, decode_pose, keys.POSE)
            if msg is not None:
                r["pose"] = msg
                heard.t = msg.stamp if heard.t is None else max(heard.t, msg.stamp)
        elif kind in _ROBOT_KINDS:
            field, decode = _ROBOT_KINDS[kind]
            r[field] = self._decode(key, data, decode, kind)


@dataclass
class _Heard:
    """What one :meth:`FleetWatcher.frame` has decoded so far."""

    robots: dict[str, dict[str, Any]] = dataclass_field(default_factory=dict)  # id -> kind -> msg
    obstacles: list[dict] = dataclass_field(default_factory=list)
    shapes: list[dict] = dataclass_field(default_factory=list)
    # formation kind -> formation id -> msg
    told: dict[str, dict[str, Any]] = dataclass_field(
        default_factory=lambda: {k: {} for k in _FORMATION_KINDS})
    t: float | None = None  # the newest pose stamp
    orders: dict[str, OrderMsg] = dataclass_field(default_factory=dict)  # oid -> as posted
    order_status: dict[str, OrderStatusMsg] = dataclass_field(default_factory=dict)
    loads: LoadsMsg | None = None  # the world's loads, as last put


def order_fields(orders: dict[str, OrderMsg], status: dict[str, OrderStatusMsg]
                 ) -> dict[str, Any]:
    """A frame's ``orders`` and ``order_counts`` from the orders heard (none heard: no keys).
    An order without a status yet is ``waiting`` since it was posted; a cancel or priority
    message names an order posted before, so only a new or load order lists one."""
    posted = {oid: m for oid, m in orders.items() if m.kind in ("new", "load")}
    if not posted and not status:
        return {}
    listed = []
    counts: dict[str, int] = {}
    for oid in sorted(set(posted) | set(status), key=lambda o: (_posted(posted.get(o)), o)):
        m, st = posted.get(oid), status.get(oid)
        state = st.state if st is not None else "waiting"
        counts[state] = counts.get(state, 0) + 1
        listed.append({"id": oid, "state": state,
                       "since": st.stamp if st is not None else _posted(m),
                       "type": m.type if m is not None else "", "load": m.load if m is not None else "",
                       "from": m.source if m is not None else "", "to": m.to if m is not None else "",
                       "robots": list(st.roster) if st is not None else [],
                       "reason": st.reason if st is not None else ""})
    return {"orders": listed, "order_counts": ordered_counts(counts)}


def _posted(m: OrderMsg | None) -> float:
    return m.stamp if m is not None else 0.0


def _robot_entry(rid: str, pose: Pose, r: dict[str, Any], offset: float = 0.0) -> dict[str, Any]:
    """A robot's row of the frame from its newest pose, state, command and diagnostics (and
    its own estimate, when its state carries a confidence radius: :func:`estimate_of`)."""
    state, cmd, diag = (r.get(k) for k in ("state", "cmd", "diag"))
    return {**_row(rid, pose, state, cmd, diag), **estimate_of(state, offset)}


def estimate_of(state: Any, offset: float) -> dict[str, float]:
    """``est_x, est_y, sigma_m`` of a state that carries ``sigma``: the body ``offset`` behind
    the estimated control point along the heading; {} for a state without one."""
    sigma = getattr(state, "sigma", None)
    if sigma is None:
        return {}
    return {"est_x": state.x - offset * math.cos(state.theta),
            "est_y": state.y - offset * math.sin(state.theta), "sigma_m": sigma}


def _row(rid: str, pose: Pose, state: Any, cmd: Any, diag: Any) -> dict[str, Any]:
    return {
        "id": rid,
        "formation": diag.formation if diag is not None else "?",
        "x": pose.x, "y": pose.y, "theta": pose.theta,
        "px": state.x if state else None, "py": state.y if state else None,
        "ux": cmd.ux if cmd else None, "uy": cmd.uy if cmd else None,
        "v": cmd.v if cmd else None, "omega": cmd.omega if cmd else None,
        **_diag_entry(diag),
    }


def _diag_entry(diag: Any) -> dict[str, Any]:
    """A robot's diagnostics fields of its row (None without diagnostics; status "")."""
    if diag is None:
        return {"status": "", "slack": None, "h_formation": None, "h_obstacle": None,
                "h_formations": None, "gx": None, "gy": None}
    return {"status": diag.status, "slack": num(diag.slack), "h_formation": num(diag.h_formation),
            "h_obstacle": num(diag.h_obstacle), "h_formations": num(diag.h_formations),
            "gx": diag.goal_x, "gy": diag.goal_y}


def leader_report(row: dict, report: StatusMsg | None) -> dict:
    """A formation's row with what its leader reports (``status``): the leader's state, goal and
    distance to go along the route replace those derived from the members; ``leader``,
    ``waypoint`` ("k/n"), why the state (``reason``: why ``unreachable``), the goals the leader
    refused (``refused``) and why it refused the last one (``refusal``) are added. Without a
    report the row stays as derived."""
    if report is None:
        return {**row, "leader": None, "waypoint": None, "reason": None, "refused": None,
                "refusal": None}
    return {**row, "status": report.state, "gx": num(report.gx), "gy": num(report.gy),
            "distance": num(report.distance), "leader": report.leader,
            "waypoint": f"{report.waypoint}/{report.waypoints}" if report.waypoints else None,
            "reason": report.reason or None, "refused": report.refused,
            "refusal": report.refusal or None}
