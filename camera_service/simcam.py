"""The simulated world's overhead camera for ``formation run --camera process``.

:class:`FramePublisher` renders what the lab's camera would see (the robots' ArUco markers,
every obstacle as a grey disc, and one marker on each moving obstacle), encodes it as PNG and
publishes it with its capture stamp on ``{prefix}/camera/frame`` (:mod:`wire.frames`). The real
camera process (``python -m camera_service``, the program a lab runs) subscribes to that key,
detects the markers and publishes the poses and obstacles the agents drive on.

:func:`write_camera_files` writes that process's ``CONFIG.yaml`` and calibration for a
scenario: robot ``k`` (scenario order) carries marker ``k``, moving obstacle ``j`` carries
marker ``n_robots + j``; the static obstacles come from the scenario file itself.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import yaml
import zenoh

from camera_service.calibration import Calibration, save_calibration, synthetic_camera
from camera_service.markers import DEFAULT_DICTIONARY, dictionary_size
from camera_service.node import has_matching_subscribers
from camera_service.render import render_aruco_frame
from scenario.model import Scenario
from scenario.world import blind_at
from wire.frames import Frame, encode_frame, frame_key

logger = logging.getLogger(__name__)

IMAGE = (1280, 960)  # [px] the lab camera's frame
MIN_MARKER_PX = 26.0  # [px] smallest marker side the camera must resolve
PNG_LEVEL = 1  # fast PNG compression: lossless, about 10 ms for a 1280x960 frame


class FramePublisher:
    """Renders and publishes the overhead frames of a simulated scenario."""

    def __init__(self, scenario: Scenario, session: zenoh.Session | None, prefix: str) -> None:
        """``session`` None: only the geometry (for :func:`write_camera_files`)."""
        xs = [r.start[0] for r in scenario.robots] + [r.goal[0] for r in scenario.robots]
        ys = [r.start[1] for r in scenario.robots] + [r.goal[1] for r in scenario.robots]
        for o in scenario.obstacles:
            xs += [o.center[0] - o.safe_distance, o.center[0] + o.safe_distance]
            ys += [o.center[1] - o.safe_distance, o.center[1] + o.safe_distance]
            if o.velocity != (0.0, 0.0):
                end = o.position(scenario.duration)
                xs.append(end[0])
                ys.append(end[1])
        arena = (min(xs) - 1.0, min(ys) - 1.0, max(xs) + 1.0, max(ys) + 1.0)
        self.calibration: Calibration = synthetic_camera(image_size=IMAGE, arena=arena)
        scale = min((IMAGE[0] - 32) / (arena[2] - arena[0]),
                    (IMAGE[1] - 32) / (arena[3] - arena[1]))  # [px/m]
        self.marker_side = max(0.08, MIN_MARKER_PX / scale)  # [m]
        self.robot_ids = tuple(scenario.robot_ids)
        self.moving = tuple(o for o in scenario.obstacles if o.velocity != (0.0, 0.0))
        n = len(self.robot_ids) + len(self.moving)
        if n > dictionary_size(DEFAULT_DICTIONARY):
            raise ValueError(f"camera: {n} markers do not fit {DEFAULT_DICTIONARY}")
        self.marker_ids = {rid: k for k, rid in enumerate(self.robot_ids)}
        base = len(self.robot_ids)
        self.obstacle_markers = {o.name: base + j for j, o in enumerate(self.moving)}
        self.radius = scenario.robot.radius
        self.blind = scenario.world.camera_blind  # floor the camera does not see
        self.key = frame_key(prefix)
        self.publisher = None if session is None else session.declare_publisher(self.key)

    def publish(self, state: Sequence[tuple[float, float, float]],
                obstacles: Sequence[tuple[str, float, float, float]], stamp: float) -> None:
        """Render the robots at ``state`` (scenario order; none on blind floor) and
        ``obstacles`` (name, x, y, ds), publish the frame stamped ``stamp``."""
        poses = {rid: (s[0], s[1], s[2]) for rid, s in zip(self.robot_ids, state, strict=True)
                 if not blind_at(self.blind, s[0], s[1])}
        ids = dict(self.marker_ids)
        for name, x, y, _ds in obstacles:
            if name in self.obstacle_markers:
                poses[f"obstacle-{name}"] = (x, y, 0.0)
                ids[f"obstacle-{name}"] = self.obstacle_markers[name]
        frame = render_aruco_frame(poses, self.calibration, ids,
                                   [(x, y, ds) for _n, x, y, ds in obstacles],
                                   marker_side=self.marker_side, robot_radius=self.radius)
        if self.publisher is None:
            raise RuntimeError("camera: this FramePublisher has no session")
        ok, png = cv2.imencode(".png", frame, [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL])
        if not ok:
            raise RuntimeError("camera: cannot encode a frame as PNG")
        self.publisher.put(encode_frame(Frame(stamp, "png", png.tobytes())))

    def wait_subscribed(self, timeout: float, abort: Callable[[], None] = lambda: None) -> None:
        """Wait until the camera process subscribes to the frames."""
        if self.publisher is None:
            raise RuntimeError("camera: this FramePublisher has no session")
        deadline = time.monotonic() + timeout
        while not has_matching_subscribers(self.publisher):
            abort()
            if time.monotonic() > deadline:
                raise TimeoutError(f"the camera process did not subscribe to {self.key} "
                                   f"within {timeout} s")
            time.sleep(0.02)

    def undeclare(self) -> None:
        if self.publisher is not None:
            self.publisher.undeclare()
            self.publisher = None


def write_camera_files(pub: FramePublisher, scenario: Scenario, scenario_path: str | Path,
                       folder: Path, endpoint: str, prefix: str) -> Path:
    """The camera process's ``camera.yaml`` and ``calib.yaml`` in ``folder``; returns the
    config's path."""
    folder.mkdir(parents=True, exist_ok=True)
    save_calibration(pub.calibration, folder / "calib.yaml")
    config = {
        "source": f"zenoh:{pub.key}",
        "fps": round(1.0 / scenario.dt, 6),
        "calibration": "calib.yaml",
        "markers": {"dictionary": DEFAULT_DICTIONARY, "size_m": pub.marker_side,
                    "height_m": 0.0},
        "robots": {k: rid for rid, k in pub.marker_ids.items()},
        "obstacles": {pub.obstacle_markers[o.name]: {"name": o.name,
                                                     "safe_distance": o.safe_distance}
                      for o in pub.moving},
        "static_obstacles": str(Path(scenario_path).resolve()),
        "prefix": prefix,
        "zenoh": {"mode": "client", "connect": [endpoint]},
    }
    path = folder / "camera.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    return path
