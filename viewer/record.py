"""Frames onto Foxglove channels: an MCAP recording, a Foxglove WebSocket, or both at once.

:class:`Channels` owns one ``foxglove.Context`` with three channels; whatever sinks are opened
on that context (``run.mcap`` through :meth:`Channels.open_mcap`, a WebSocket server through
:meth:`Channels.serve`) get the same messages:

=============  ==========================  ======================================================
topic          schema                      what
=============  ==========================  ======================================================
``/scene``     ``foxglove.SceneUpdate``    the floor each tick, frame ``floor``: robots (body
               (protobuf)                  cylinder, heading arrow, control point, label), formation
                                           ellipses, obstacles (with a ring at their safe distance),
                                           goals, loads (translucent, in the formation's colour)
                                           and a red line (and ball) for each load overlap
                                           (0.25 s lifetime).
                                           Each tick replaces every entity (same ids).
``/fleet``     JSON, ``jsonschema``        the whole :mod:`viewer.frame` frame: commands, QP status,
                                           slack, smallest barrier values, formation status (plot
                                           e.g. ``/fleet.robots[:]{id=="a1"}.h_obstacle``)
``/log``       ``foxglove.Log`` (protobuf)  stale inputs, relaxed rows and fallbacks (at onset),
                                           collisions, faults, rejected messages
``/orders``    JSON, ``jsonschema``        a lifelong run's orders (:mod:`viewer.orders`): each
                                           open or recently ended order's state, since when, its
                                           load, stations and team, and the count per state;
                                           logged whenever an order's state changes
=============  ==========================  ======================================================

Under ``controller.localisation: fused`` ``/scene`` also draws each robot's own estimate (a
small sphere in its formation's colour) and a dark ring of its 95 % confidence radius around it,
just above the true body; blind
floor (``world.camera_blind``) is a translucent violet box on the floor. A lifelong run's
loads on the floor (``cargo``) are boxes: brown while resting, in the team's colour while
carried, each named.

Only those two Foxglove schemas and JSON-schema channels: Foxglove (2.x) and Lichtblick (1.x)
render them all (3D, Plot / Raw Messages, Log panels). Message log times are the frame's time
in nanoseconds: simulated seconds for simulations (the run starts at 0), wall time for fleets.

:func:`write_recording` writes ``run.mcap`` of a finished run from its time series, after the
control loop (so recording costs the loop nothing); :func:`run_logs` derives the log messages.
"""

from __future__ import annotations

import functools
import json
import logging
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import foxglove
from foxglove.channels import LogChannel, SceneUpdateChannel
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    CylinderPrimitive,
    Duration,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Timestamp,
    TriangleListPrimitive,
    Vector3,
)
from foxglove.websocket import Capability

from geometry.limits import BURGER_RADIUS
from scenario.cargo import CONTACT_TOL

from .frame import Frame, frames_from_series
from .orders import OrderBoard

logger = logging.getLogger(__name__)

SCENE_TOPIC, FLEET_TOPIC, LOG_TOPIC, ORDERS_TOPIC = "/scene", "/fleet", "/log", "/orders"
FRAME_ID = "floor"
RENDERED_SCHEMAS = ("foxglove.SceneUpdate", "foxglove.Log")  # + JSON-schema channels
ELLIPSE_POINTS = 48
BODY_HEIGHT = 0.19  # [m] TurtleBot3 burger
LOAD_HEIGHT = 0.02  # [m] where a load is drawn: on the floor, under the robots
HIT_HEIGHT = 0.25  # [m] a load overlap's red line: above the robots, to be seen
HIT_LIFETIME = Duration(0, 250_000_000)  # an overlap's line goes once no tick repeats it
HIT_RGB = (0.85, 0.0, 0.0)
ESTIMATE_RGB = (0.07, 0.07, 0.07)  # a fused robot's confidence ring
BLIND_RGB = (0.55, 0.35, 0.75)  # blind floor: violet, translucent
RESTING_RGB = (0.55, 0.38, 0.2)  # a resting load: brown
CARGO_HEIGHT = 0.15  # [m] a load's top: above the robots' bodies' middle, under their tops
# formation colours (RGB 0..1), the same order as the page's palette
PALETTE = ((0.12, 0.47, 0.71), (0.84, 0.15, 0.16), (0.17, 0.63, 0.17), (0.58, 0.40, 0.74),
           (1.00, 0.50, 0.05), (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.09, 0.75, 0.81))

_N = 0.0

# a lifelong run's orders (viewer.orders), in /fleet frames and on /orders
ORDER_LIST_SCHEMA: dict[str, Any] = {"type": "array", "items": {"type": "object", "properties": {
    **{k: {"type": "string"} for k in ("id", "state", "type", "load", "from", "to", "reason")},
    "since": {"type": "number"}, "robots": {"type": "array", "items": {"type": "string"}}}}}
ORDER_COUNTS_SCHEMA: dict[str, Any] = {"type": "object",
                                       "additionalProperties": {"type": "integer"}}

FLEET_SCHEMA: dict[str, Any] = {
    "title": "formation.Fleet",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "time [s]"},
        "radius": {"type": "number"},
        "robots": {"type": "array", "items": {"type": "object", "properties": {
            "id": {"type": "string"}, "formation": {"type": "string"}, "status": {"type": "string"},
            **{k: {"type": ["number", "null"]} for k in (
                "x", "y", "theta", "px", "py", "ux", "uy", "v", "omega", "slack",
                "h_formation", "h_obstacle", "h_formations", "gx", "gy",
                "est_x", "est_y", "sigma_m")}}}},
        "ellipses": {"type": "array", "items": {"type": "object", "properties": {
            "formation": {"type": "string"},
            **{k: {"type": ["number", "null"]} for k in ("cx", "cy", "alpha", "a", "b")}}}},
        "obstacles": {"type": "array", "items": {"type": "object", "properties": {
            "name": {"type": "string"},
            **{k: {"type": ["number", "null"]} for k in ("x", "y", "ds")}}}},
        "shapes": {"type": "array", "items": {"type": "object", "properties": {
            "name": {"type": "string"}, "kind": {"type": "string"}, "ds": {"type": ["number", "null"]},
            "corners": {"type": "array", "items": {"type": "array"}}}}},
        "loads": {"type": "array", "items": {"type": "object", "properties": {
            "formation": {"type": "string"}, "declared": {"type": "boolean"},
            "outline": {"type": "array", "items": {"type": "array"}}}}},
        "load_hits": {"type": "array", "items": {"type": "object", "properties": {
            "formation": {"type": "string"}, "other": {"type": "string"},
            "clearance": {"type": "number"}, "line": {"type": "array", "items": {"type": "array"}}}}},
        "formations": {"type": "array", "items": {"type": "object", "properties": {
            "name": {"type": "string"}, "status": {"type": "string"}, "qp": {"type": "string"},
            "leader": {"type": ["string", "null"]}, "waypoint": {"type": ["string", "null"]},
            "reason": {"type": ["string", "null"]}, "refusal": {"type": ["string", "null"]},
            "refused": {"type": ["integer", "null"]},
            **{k: {"type": ["number", "null"]} for k in ("gx", "gy", "distance")}}}},
        "routes": {"type": "array", "items": {"type": "object", "properties": {
            "formation": {"type": "string"}, "points": {"type": "array", "items": {"type": "array"}}}}},
        "blind": {"type": "array", "items": {"type": "object", "properties": {
            "corners": {"type": "array", "items": {"type": "array"}}}}},
        "cargo": {"type": "array", "items": {"type": "object", "properties": {
            **{k: {"type": "string"} for k in ("name", "type", "state", "station", "order")},
            "outline": {"type": "array", "items": {"type": "array"}}}}},
        "orders": ORDER_LIST_SCHEMA,
        "order_counts": ORDER_COUNTS_SCHEMA,
    },
}

ORDERS_SCHEMA: dict[str, Any] = {
    "title": "formation.Orders",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "time [s]"},
        "orders": ORDER_LIST_SCHEMA,
        "order_counts": ORDER_COUNTS_SCHEMA,
    },
}

LEVELS = {"debug": LogLevel.Debug, "info": LogLevel.Info, "warning": LogLevel.Warning,
          "error": LogLevel.Error}


def ns(t: float) -> int:
    """Seconds -> integer nanoseconds (MCAP log time)."""
    return int(round(t * 1e9))


def _stamp(t: float) -> Timestamp:
    n = max(ns(t), 0)
    return Timestamp(n // 1_000_000_000, n % 1_000_000_000)


@functools.lru_cache(maxsize=64)
def _color(rgb: tuple[float, float, float], a: float = 1.0) -> Color:
    return Color(r=rgb[0], g=rgb[1], b=rgb[2], a=a)


@functools.lru_cache(maxsize=64)
def _size(x: float, y: float, z: float) -> Vector3:
    return Vector3(x=x, y=y, z=z)


@functools.lru_cache(maxsize=4096)
def _goal(rid: str, gx: float, gy: float, rgb: tuple[float, float, float]) -> SceneEntity:
    """A robot's goal square (static: built once, no timestamp)."""
    return SceneEntity(frame_id=FRAME_ID, id=f"goal/{rid}",
                       cubes=[CubePrimitive(pose=_pose(gx, gy, 0.005), size=_size(0.08, 0.08, 0.01),
                                            color=_color(rgb, 0.6))])


def _pose(x: float, y: float, z: float = 0.0, yaw: float = 0.0) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z),
                orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))


@functools.lru_cache(maxsize=256)
def _ring(a: float, b: float) -> list[Point3]:
    """An ellipse of semi-axes ``a`` (along x) and ``b`` around the origin; the line's pose
    places and turns it (semi-axes rarely change, so the points are built once)."""
    return [Point3(x=a * math.cos(2 * math.pi * k / ELLIPSE_POINTS),
                   y=b * math.sin(2 * math.pi * k / ELLIPSE_POINTS), z=0.0)
            for k in range(ELLIPSE_POINTS)]


def formation_colors(frame: Frame) -> dict[str, tuple[float, float, float]]:
    """Formation -> colour, by order of first appearance among the frame's robots."""
    out: dict[str, tuple[float, float, float]] = {}
    for r in frame["robots"]:
        if r["formation"] not in out:
            out[r["formation"]] = PALETTE[len(out) % len(PALETTE)]
    return out


def scene_update(frame: Frame) -> SceneUpdate:
    """The ``/scene`` message of a frame (see the module docstring)."""
    stamp = _stamp(frame["t"])
    radius = frame.get("radius") or BURGER_RADIUS
    colors = formation_colors(frame)
    entities: list[SceneEntity] = []
    for r in frame["robots"]:
        if r["x"] is not None and r["y"] is not None:
            entities += _robot_entities(r, colors[r["formation"]], radius, stamp)
    for e in frame["ellipses"]:
        if None not in (e["cx"], e["cy"], e["alpha"], e["a"], e["b"]):
            entities.append(_ellipse_entity(e, colors.get(e["formation"], PALETTE[0]), stamp))
    for o in frame["obstacles"]:
        if None not in (o["x"], o["y"], o["ds"]):
            entities.append(_obstacle_entity(o, radius, stamp))
    for s in frame.get("shapes", ()):  # walls and shelves: their outline, 0.3 m high
        shape = _shape_entity(s, stamp)
        if shape is not None:
            entities.append(shape)
    entities += [_load_entity(ld, colors.get(ld["formation"], PALETTE[0]), stamp)
                 for ld in frame.get("loads", ())]
    entities += [_hit_entity(h, stamp) for h in frame.get("load_hits", ())]
    entities += [_blind_entity(k, b, stamp) for k, b in enumerate(frame.get("blind", ()))]
    entities += [_cargo_entity(c, colors.get(c["order"], RESTING_RGB)
                               if c["state"] == "carried" else RESTING_RGB, stamp)
                 for c in frame.get("cargo", ())]
    entities += [_estimate_entity(r, colors[r["formation"]], stamp) for r in frame["robots"]
                 if None not in (r.get("est_x"), r.get("est_y"), r.get("sigma_m"))]
    return SceneUpdate(entities=entities)


def _flat(outline: list, z: float) -> tuple[list[Point3], list[int]]:
    """A convex outline at height ``z``: its points and a triangle fan's indices."""
    pts = [Point3(x=x, y=y, z=z) for x, y in outline if x is not None and y is not None]
    return pts, [i for k in range(1, len(pts) - 1) for i in (0, k, k + 1)]


def _blind_entity(k: int, b: dict[str, Any], stamp: Timestamp) -> SceneEntity:
    """Blind floor: a translucent violet box on the floor, its edge drawn."""
    pts, fan = _flat(b["corners"], 0.003)
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=f"blind/{k}",
                       triangles=[TriangleListPrimitive(pose=_pose(0.0, 0.0), points=pts,
                                                        indices=fan,
                                                        color=_color(BLIND_RGB, 0.18))],
                       lines=[LinePrimitive(type=LinePrimitiveLineType.LineLoop, thickness=0.02,
                                            pose=_pose(0.0, 0.0), points=pts,
                                            color=_color(BLIND_RGB, 0.8))])


def _cargo_entity(c: dict[str, Any], rgb: tuple[float, float, float],
                  stamp: Timestamp) -> SceneEntity:
    """A lifelong run's load on the floor: its top at :data:`CARGO_HEIGHT` (brown resting, the
    team's colour carried), its edge and its name."""
    pts, fan = _flat(c["outline"], CARGO_HEIGHT)
    carried = c["state"] == "carried"
    cx = sum(p[0] for p in c["outline"]) / len(c["outline"])
    cy = sum(p[1] for p in c["outline"]) / len(c["outline"])
    label = TextPrimitive(pose=_pose(cx, cy, CARGO_HEIGHT + 0.05), billboard=True, font_size=12,
                          scale_invariant=True, color=_color((0, 0, 0)),
                          text=c["name"] + (f" ({c['order']})" if c["order"] else ""))
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=f"cargo/{c['name']}",
                       triangles=[TriangleListPrimitive(pose=_pose(0.0, 0.0), points=pts,
                                                        indices=fan,
                                                        color=_color(rgb, 0.45 if carried else 0.8))],
                       lines=[LinePrimitive(type=LinePrimitiveLineType.LineLoop, thickness=0.02,
                                            pose=_pose(0.0, 0.0), points=pts,
                                            color=_color(rgb))],
                       texts=[label])


def _estimate_entity(r: dict[str, Any], rgb: tuple[float, float, float],
                     stamp: Timestamp) -> SceneEntity:
    """A fused robot's own estimate (a sphere) and the ring of its 95 % confidence radius."""
    x, y, sigma = r["est_x"], r["est_y"], r["sigma_m"]
    z = BODY_HEIGHT + 0.03  # above the body: a ring is often smaller than one
    ring = LinePrimitive(type=LinePrimitiveLineType.LineLoop, thickness=0.012,
                         pose=_pose(x, y, z), points=_ring(sigma, sigma), color=_color(ESTIMATE_RGB))
    dot = SpherePrimitive(pose=_pose(x, y, z), size=_size(0.03, 0.03, 0.03),
                          color=_color(rgb, 0.9))
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=f"estimate/{r['id']}",
                       lines=[ring], spheres=[dot])


def _robot_entities(r: dict[str, Any], rgb: tuple[float, float, float], radius: float,
                    stamp: Timestamp) -> list[SceneEntity]:
    """A robot's body, heading arrow, label and state point; its goal when it has one."""
    th = r["theta"] or 0.0
    body = CylinderPrimitive(pose=_pose(r["x"], r["y"], BODY_HEIGHT / 2),
                             size=_size(2 * radius, 2 * radius, BODY_HEIGHT),
                             bottom_scale=1.0, top_scale=1.0, color=_color(rgb, 0.9))
    arrow = ArrowPrimitive(pose=_pose(r["x"], r["y"], BODY_HEIGHT + 0.01, th),
                           shaft_length=radius * 1.4, shaft_diameter=0.02,
                           head_length=0.06, head_diameter=0.06, color=_color((0.1, 0.1, 0.1)))
    spheres = []
    if r["px"] is not None and r["py"] is not None:
        spheres.append(SpherePrimitive(pose=_pose(r["px"], r["py"], BODY_HEIGHT + 0.02),
                                       size=_size(0.04, 0.04, 0.04),
                                       color=_color((1.0, 1.0, 1.0))))
    label = TextPrimitive(pose=_pose(r["x"], r["y"], BODY_HEIGHT + 0.15), billboard=True,
                          font_size=14, scale_invariant=True, color=_color((0, 0, 0)),
                          text=f"{r['id']} {r['status']}".strip())
    out = [SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=f"robot/{r['id']}",
                       cylinders=[body], arrows=[arrow], spheres=spheres, texts=[label])]
    if r["gx"] is not None and r["gy"] is not None:
        out.append(_goal(r["id"], r["gx"], r["gy"], rgb))
    return out


def _ellipse_entity(e: dict[str, Any], rgb: tuple[float, float, float],
                    stamp: Timestamp) -> SceneEntity:
    line = LinePrimitive(type=LinePrimitiveLineType.LineLoop, thickness=0.02,
                         pose=_pose(e["cx"], e["cy"], 0.01, e["alpha"]),
                         points=_ring(e["a"], e["b"]),
                         color=_color(rgb))
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=f"ellipse/{e['formation']}",
                       lines=[line])


def _obstacle_entity(o: dict[str, Any], radius: float, stamp: Timestamp) -> SceneEntity:
    ds = o["ds"]
    core = max(ds - radius, 0.05)  # the obstacle's own body: its safe distance less a robot
    cyl = CylinderPrimitive(pose=_pose(o["x"], o["y"], 0.15),
                            size=_size(2 * core, 2 * core, 0.3), bottom_scale=1.0,
                            top_scale=1.0, color=_color((0.35, 0.35, 0.35), 0.9))
    ring = LinePrimitive(type=LinePrimitiveLineType.LineLoop, thickness=0.01,
                         pose=_pose(o["x"], o["y"], 0.005), points=_ring(ds, ds),
                         color=_color((0.9, 0.3, 0.1)))
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=f"obstacle/{o['name']}",
                       cylinders=[cyl], lines=[ring])


def _shape_entity(s: dict[str, Any], stamp: Timestamp) -> SceneEntity | None:
    """A wall's or shelf's outline, 0.3 m high; None with fewer than two known corners."""
    pts = [Point3(x=x, y=y, z=0.3) for x, y in s["corners"] if x is not None and y is not None]
    if len(pts) < 2:
        return None
    kind = LinePrimitiveLineType.LineLoop if s["kind"] == "box" else LinePrimitiveLineType.LineStrip
    line = LinePrimitive(type=kind, thickness=0.04, pose=_pose(0.0, 0.0), points=pts,
                         color=_color((0.35, 0.35, 0.35)))
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=f"shape/{s['name']}", lines=[line])


def _load_entity(ld: dict[str, Any], rgb: tuple[float, float, float],
                 stamp: Timestamp) -> SceneEntity:
    """A formation's load: its outline (a segment for a pair's hull), and a translucent fill
    (denser for a declared load than for the default hull) when it is a polygon."""
    pts = [Point3(x=x, y=y, z=LOAD_HEIGHT) for x, y in ld["outline"]]
    kind = LinePrimitiveLineType.LineLoop if len(pts) > 2 else LinePrimitiveLineType.LineStrip
    line = LinePrimitive(type=kind, thickness=0.03 if ld["declared"] else 0.015,
                         pose=_pose(0.0, 0.0), points=pts, color=_color(rgb))
    fill = [TriangleListPrimitive(pose=_pose(0.0, 0.0), points=pts,
                                  indices=[i for k in range(1, len(pts) - 1) for i in (0, k, k + 1)],
                                  color=_color(rgb, 0.35 if ld["declared"] else 0.15))
            ] if len(pts) > 2 else []
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, id=f"load/{ld['formation']}",
                       lines=[line], triangles=fill)


def _hit_entity(h: dict[str, Any], stamp: Timestamp) -> SceneEntity:
    """A load overlap: a red line from the load's outline to what it overlaps, and a red ball
    where it leaves the load (seen where the line has no length: a wall across a pair's load)."""
    (ax, ay), (bx, by) = h["line"]
    line = LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=0.04, pose=_pose(0.0, 0.0),
                         points=[Point3(x=ax, y=ay, z=HIT_HEIGHT), Point3(x=bx, y=by, z=HIT_HEIGHT)],
                         color=_color(HIT_RGB))
    ball = SpherePrimitive(pose=_pose(ax, ay, HIT_HEIGHT), size=_size(0.08, 0.08, 0.08),
                           color=_color(HIT_RGB))
    return SceneEntity(timestamp=stamp, frame_id=FRAME_ID, lifetime=HIT_LIFETIME,
                       id=f"load_hit/{h['formation']}/{h['other']}", lines=[line], spheres=[ball])


class Channels:
    """The recording's channels on their own ``foxglove.Context`` (see the module docstring)."""

    def __init__(self) -> None:
        self.context = foxglove.Context()
        self.scene = SceneUpdateChannel(SCENE_TOPIC, context=self.context)
        self.fleet = foxglove.Channel(FLEET_TOPIC, schema=FLEET_SCHEMA, message_encoding="json",
                                      context=self.context)
        self.logs = LogChannel(LOG_TOPIC, context=self.context)
        self.orders: Any = None  # the /orders channel, opened by a frame that has orders
        self._listed: list[tuple[str, str]] | None = None  # the orders last logged
        self._writer: Any = None
        self._server: Any = None

    def open_mcap(self, path: Path) -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        self._writer = foxglove.open_mcap(path, allow_overwrite=True, context=self.context)

    def serve(self, host: str = "127.0.0.1", port: int = 0, name: str = "formation-cbf") -> int:
        """Start the Foxglove WebSocket server on this context; returns its port."""
        self._server = foxglove.start_server(name=name, host=host, port=port, context=self.context,
                                             capabilities=[Capability.Time])
        return int(self._server.port)

    def frame(self, frame: Frame) -> None:
        """Log one frame on ``/scene`` and ``/fleet`` at the frame's time."""
        t = ns(frame["t"])
        self.scene.log(scene_update(frame), log_time=t)
        self.fleet.log(json.dumps(frame, allow_nan=False).encode("utf-8"), log_time=t)
        if "orders" in frame:
            self._log_orders(frame, t)
        if self._server is not None:
            self._server.broadcast_time(max(t, 0))

    def _log_orders(self, frame: Frame, t: int) -> None:
        """``/orders`` when the frame's orders differ from those last logged."""
        listed = [(o["id"], o["state"]) for o in frame["orders"]]
        if listed == self._listed:
            return
        self._listed = listed
        if self.orders is None:
            self.orders = foxglove.Channel(ORDERS_TOPIC, schema=ORDERS_SCHEMA,
                                           message_encoding="json", context=self.context)
        msg = {"t": frame["t"], "orders": frame["orders"],
               "order_counts": frame.get("order_counts", {})}
        self.orders.log(json.dumps(msg, allow_nan=False).encode("utf-8"), log_time=t)

    def log(self, t: float, level: str, name: str, message: str) -> None:
        self.logs.log(Log(timestamp=_stamp(t), level=LEVELS.get(level, LogLevel.Info),
                          message=message, name=name), log_time=ns(t))

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._server is not None:
            self._server.stop()
            self._server = None


# --- logs of a finished run ---------------------------------------------------------------------

ONSET_LEVEL = {"relaxed": "warning", "fallback": "error", "failed": "error", "stale": "warning"}
ONSET_TEXT = {
    "relaxed": "formation rows relaxed (slack {slack})",
    "fallback": "hard rows infeasible: least-risk command",
    "failed": "QP solver failed: zero command",
    "stale": "stale input: zero command",
}


def status_logs(frames: Iterable[Frame]) -> Iterable[tuple[float, str, str, str]]:
    """``(t, level, name, message)`` each time a robot's QP status becomes relaxed, fallback,
    failed or stale (the onset; the tick count follows when it ends)."""
    current: dict[str, tuple[str, float, int]] = {}  # robot -> (status, since, ticks)
    for f in frames:
        for r in f["robots"]:
            s = r["status"]
            rid = r["id"]
            prev = current.get(rid)
            if prev is not None and prev[0] == s:
                current[rid] = (s, prev[1], prev[2] + 1)
                continue
            if prev is not None and prev[0] in ONSET_LEVEL:
                yield (f["t"], "info", rid, f"{prev[0]} ended after {prev[2]} ticks")
            current[rid] = (s, f["t"], 1)
            if s in ONSET_LEVEL:
                slack = "n/a" if r["slack"] is None else f"{r['slack']:.4f}"
                yield (f["t"], ONSET_LEVEL[s], rid, ONSET_TEXT[s].format(slack=slack))


def summary_logs(summary: dict, t_end: float) -> list[tuple[float, str, str, str]]:
    """Log lines from a run's ``summary.json``: collisions and fault events at their times,
    rejected messages and missing commands at the end."""
    out: list[tuple[float, str, str, str]] = []
    for c in summary.get("collision_log") or ():
        who = f"load {c['a']}" if c.get("kind") == "load" else c["a"]
        out.append((float(c["t"]), "error", "safety",
                    f"collision {who} - {c['b']}: clearance {c['clearance_m']:.4f} m"))
    faults = summary.get("faults") or {}
    for ev in faults.get("events") or ():
        out.append((float(ev["t_s"]), "warning", "faults", f"{ev['event']} agent {ev['robot']}"))
    for c in faults.get("camera_dropouts") or ():
        out.append((float(c["at_s"]), "warning", "faults",
                    f"camera loses {c['robot']} for {c['duration_s']} s"))
    agents = summary.get("agents") or {}
    dropped = {k: v for k, v in (agents.get("dropped") or {}).items() if v}
    if dropped:
        out.append((t_end, "warning", "agents", f"rejected messages: {json.dumps(dropped)}"))
    if agents.get("stale"):
        out.append((t_end, "warning", "agents", f"stale ticks (zero command): {agents['stale']}"))
    world = summary.get("world") or {}
    for key in ("missing_cmds", "malformed_cmds"):
        if world.get(key):
            out.append((t_end, "warning", "world", f"{key.replace('_', ' ')}: {world[key]}"))
    return out


def route_logs(summary: dict) -> list[tuple[float, str, str, str]]:
    """Log lines for each route planned again (``summary.json``'s ``replans``, method rigid in
    process): when, which formation, why, and its waypoints or that no route reaches its goal."""
    no_route = summary.get("unreachable") or {}
    out = []
    for r in summary.get("replans") or ():
        what = (f"{r['waypoints']} waypoints" if r["waypoints"]
                else f"no route: {no_route.get(r['formation'], 'unreachable')}")
        out.append((float(r["t"]), "info" if r["waypoints"] else "warning", "routes",
                    f"formation {r['formation']} plans again ({r['why']}): {what}"))
    return out


def write_recording(summary: dict, series: Any, scenario: Any, out: Path,
                    board: OrderBoard | None = None) -> Path:
    """``out/run.mcap`` of a finished run: one ``/scene`` and ``/fleet`` message per tick, and
    the logs of :func:`status_logs`, :func:`summary_logs` and :func:`route_logs`, in time order;
    a lifelong run's loads and orders from ``board`` (``/orders`` at each change)."""
    path = Path(out) / "run.mcap"
    ch = Channels()
    ch.open_mcap(path)
    try:
        # overlaps are looked for only where the run's safety monitor saw a load overlap
        load = (summary.get("min_clearance_m") or {}).get("load")
        hits = load is not None and load < -CONTACT_TOL
        frames = list(frames_from_series(series, scenario, load_hits=hits, board=board))
        t_end = frames[-1]["t"] if frames else 0.0
        logs = sorted([*status_logs(frames), *summary_logs(summary, t_end), *route_logs(summary)],
                      key=lambda e: e[0])
        k = 0
        for f in frames:
            while k < len(logs) and logs[k][0] <= f["t"]:
                ch.log(*logs[k])
                k += 1
            ch.frame(f)
        for entry in logs[k:]:
            ch.log(*entry)
    finally:
        ch.close()
    return path
