"""The camera process: frames in, ``pose`` and ``obstacles`` out over Zenoh.

:class:`CameraNode` owns one Zenoh session, a frame source (:mod:`camera_service.sources`), a
:class:`camera_service.locate.Locator` and an :class:`camera_service.tracking.ObstacleTracker`.
For each frame, stamped with its capture time:

1. detect the markers and map them to the floor (undistorted, parallax-corrected);
2. publish one ``obstacles`` message: the static obstacles of the config's scenario plus every
   tracked moving obstacle (filtered velocity; an unseen one held for ``obstacle_hold_s`` with a
   growing safe distance, then dropped and counted);
3. publish the ``pose`` of every robot seen, stamped with the frame's capture stamp (a robot not
   seen gets nothing: its agent goes stale and stops).

Counters (:meth:`CameraNode.stats`) are answered on the queryable ``{prefix}/camera/stats``
(JSON) and returned when the loop ends: frames, detections per robot, missing robot-frames,
dropped and held obstacles, capture -> publish latency (p50/p99, only for stamps on this
machine's clock; a lock-step simulation stamps simulated time), processing time, and every
problem met (wrong-size, undecodable or skipped frames, empty frames, duplicate, unknown or
implausible markers, read failures and reconnects). Nothing a frame holds stops the loop: it
runs until ``stop()`` is true (a flag set by the signal handlers), the source ends, or
``frames`` frames were handled.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np
import zenoh

from camera_service.config import ServiceConfig
from camera_service.locate import Located, Locator
from camera_service.sources import EndOfSource, Source
from camera_service.tracking import ObstacleTracker
from wire import keys
from wire.frames import stats_key
from wire.payloads import ObstacleMsg, Obstacles, Pose, encode_zbytes
from wire.shapes import shape_to_msg

logger = logging.getLogger(__name__)

LATENCY_SAMPLES = 20000  # latest capture -> publish samples kept for the percentiles
SAME_CLOCK_S = 60.0  # [s] a stamp within this of the wall clock is taken to be on it
LOG_EVERY = 100  # a recurring problem is logged at its 1st, 101st, 201st, ... occurrence


def percentile(values: list[float] | deque, q: float) -> float | None:
    """The ``q``-th percentile (nearest rank) of ``values``; None when empty."""
    if not values:
        return None
    xs = sorted(values)
    return xs[min(len(xs) - 1, max(0, math.ceil(q / 100.0 * len(xs)) - 1))]


def has_matching_subscribers(publisher: zenoh.Publisher) -> bool:
    """Whether ``publisher`` has a matching subscriber.

    zenoh-python 1.10's ``Publisher.matching_status`` is a ``MatchingStatus`` object (always
    truthy) although its stub says ``bool``; the answer is its ``matching`` attribute.
    """
    status: object = publisher.matching_status
    return bool(getattr(status, "matching", status))


class CameraNode:
    """See the module docstring."""

    def __init__(self, cfg: ServiceConfig, session: zenoh.Session, source: Source) -> None:
        self.cfg = cfg
        self.session = session
        self.source = source
        overrides = {mid: (o.size_m or cfg.marker_size,
                           cfg.marker_height if o.height_m is None else o.height_m)
                     for mid, o in cfg.obstacles.items()}
        self.locator = Locator(cfg.calibration, cfg.dictionary, cfg.marker_size,
                               cfg.marker_height, wanted=[*cfg.robots, *cfg.obstacles],
                               overrides=overrides)
        self.tracker = ObstacleTracker({o.name: o.safe_distance for o in cfg.obstacles.values()},
                                       cfg.obstacle_hold_s)
        self.statics = tuple(ObstacleMsg(o.name, o.x, o.y, 0.0, 0.0, o.safe_distance)
                             for o in cfg.static_obstacles)
        self.static_shapes = tuple(shape_to_msg(sh) for sh in cfg.static_shapes)  # walls, shelves
        self._pose_pubs = {rid: session.declare_publisher(keys.pose_key(cfg.prefix, rid))
                           for rid in cfg.robots.values()}
        self._obs_pub = session.declare_publisher(keys.obstacles_key(cfg.prefix))
        self._lock = threading.Lock()
        self.counts = dict.fromkeys(
            ("frames", "published", "empty_frames", "wrong_size", "bad_frames",
             "unknown_markers", "duplicate_markers", "implausible_markers", "missing",
             "obstacle_frames"), 0)
        self.detections = dict.fromkeys(cfg.robots.values(), 0)
        self.latency_ms: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self.processing_ms: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self.other_clock = 0  # frames whose stamp is not on this machine's clock
        self._queryable = session.declare_queryable(stats_key(cfg.prefix), self._on_query)

    # --- counters ------------------------------------------------------------------------------

    def _count(self, name: str, n: int = 1, why: str = "") -> None:
        with self._lock:
            before = self.counts[name]
            self.counts[name] = before + n
        if why and before % LOG_EVERY == 0:
            logger.warning("%s (%s: %d so far)", why, name, before + n)

    def stats(self) -> dict:
        """Every counter (see the module docstring), JSON-friendly."""
        with self._lock:
            lat = list(self.latency_ms)
            proc = list(self.processing_ms)
            out: dict = dict(self.counts)
            out["detections"] = dict(self.detections)
        out.update({k: v for k, v in self.source.counts.items()})
        out["obstacles_dropped"] = self.tracker.dropped
        out["obstacles_held"] = self.tracker.held
        out["latency_ms"] = {"samples": len(lat), "p50": percentile(lat, 50),
                             "p99": percentile(lat, 99), "max": max(lat) if lat else None}
        out["processing_ms"] = {"samples": len(proc), "p50": percentile(proc, 50),
                                "p99": percentile(proc, 99)}
        out["stamps_on_other_clock"] = self.other_clock
        return out

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            query.reply(str(query.key_expr), json.dumps(self.stats()))
        except Exception as exc:  # noqa: BLE001 - a failed reply must not kill Zenoh's thread
            logger.warning("stats query: %s", exc)

    # --- the loop ------------------------------------------------------------------------------

    def wait_for_subscribers(self, timeout: float, stop: Callable[[], bool]) -> bool:
        """Wait up to ``timeout`` seconds until someone subscribes to the obstacles (a replay
        of files should not run before anyone listens); True if someone does."""
        deadline = time.monotonic() + timeout
        while not stop() and time.monotonic() < deadline:
            if has_matching_subscribers(self._obs_pub):
                return True
            time.sleep(0.02)
        return False

    def run(self, stop: Callable[[], bool], frames: int | None = None) -> dict:
        """Handle frames until ``stop()``, the source's end, or ``frames`` frames."""
        handled = 0
        while not stop() and (frames is None or handled < frames):
            try:
                item = self.source.read()
            except EndOfSource:
                logger.info("source ended after %d frames", handled)
                break
            if item is None:
                continue
            handled += 1
            frame, stamp = item
            if frame is None:
                self._count("bad_frames")
                continue
            self.handle(frame, stamp)
        return self.stats()

    def handle(self, frame: np.ndarray, stamp: float) -> None:
        """One frame captured at ``stamp``: detect, publish, count."""
        t0 = time.time()
        self._count("frames")
        try:
            found = self.locator.locate(frame)
        except ValueError as exc:
            self._count("wrong_size" if "size" in str(exc) else "bad_frames",
                        why=f"dropped a frame: {exc}")
            return
        cfg = self.cfg
        self._count_problems(found)
        seen_obstacles = {cfg.obstacles[mid].name: (p[0], p[1])
                          for mid, p in found.poses.items() if mid in cfg.obstacles}
        tracked = self.tracker.step(seen_obstacles, stamp)
        moving = tuple(ObstacleMsg(t.name, t.x, t.y, t.vx, t.vy, t.ds) for t in tracked)
        self._obs_pub.put(encode_zbytes(Obstacles(stamp, self.statics + moving, self.static_shapes)))
        if moving:
            self._count("obstacle_frames")
        seen = 0
        for mid, rid in cfg.robots.items():
            pose = found.poses.get(mid)
            if pose is None:
                continue
            seen += 1
            self._pose_pubs[rid].put(encode_zbytes(Pose(pose[0], pose[1], pose[2], stamp)))
        t1 = time.time()
        with self._lock:
            for mid, rid in cfg.robots.items():
                if mid in found.poses:
                    self.detections[rid] += 1
            self.counts["missing"] += len(cfg.robots) - seen
            self.counts["published"] += 1
            self.processing_ms.append((t1 - t0) * 1e3)
            if abs(t1 - stamp) <= SAME_CLOCK_S:
                self.latency_ms.append((t1 - stamp) * 1e3)
            else:
                self.other_clock += 1

    def _count_problems(self, found: Located) -> None:
        """Count (and log now and then) an empty frame and unknown, duplicate or implausible markers."""
        if found.markers_seen == 0:
            self._count("empty_frames", why="a frame with no marker")
        if found.unknown:
            self._count("unknown_markers", len(found.unknown),
                        why=f"marker ids nobody owns: {list(found.unknown)}")
        if found.duplicates:
            self._count("duplicate_markers", len(found.duplicates),
                        why=f"marker ids seen twice in one frame: {list(found.duplicates)}")
        if found.implausible:
            self._count("implausible_markers", len(found.implausible),
                        why=f"markers of the wrong size: {list(found.implausible)}")

    def close(self) -> None:
        """Undeclare everything (the session is closed by its owner)."""
        undeclares: list[Callable[[], None]] = [
            self._queryable.undeclare, self._obs_pub.undeclare,
            *(pub.undeclare for pub in self._pose_pubs.values())]
        for undeclare in undeclares:
            try:
                undeclare()
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        self.source.close()
