"""Front ends of ``formation camera`` / ``python -m camera_service`` and ``formation calibrate``.

``formation camera CONFIG.yaml [--frames N] [--source S] [--auth FILE]`` runs the camera service
(:mod:`camera_service.node`) until Ctrl-C or SIGTERM (the handlers only set a flag; the loop
then undeclares everything and closes the session), the source's end, or N frames; it prints its
counters as one JSON line on exit. ``formation calibrate IMAGE --floor-markers FLOOR.yaml --out
CALIB.yaml [--intrinsics INTR.yaml] [--camera-height H] [--max-error M]`` fits the calibration
(:mod:`camera_service.calibrate`) and prints each marker's error.

Exit status: 0 done; 2 invalid input (config, calibration, source, image) with one line naming
the culprit; 1 anything else (the Zenoh session does not open, ...), with a message.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
import yaml
import zenoh

from camera_service.calibrate import (
    MAX_ERROR_M,
    CalibrationError,
    CalibrationReport,
    calibrate_image,
    load_intrinsics,
)
from camera_service.calibration import calibration_to_dict
from camera_service.config import ConfigError, FloorMarkers, ServiceConfig, load_config, load_floor
from camera_service.node import CameraNode
from camera_service.sources import Source, SourceError, make_source, source_kind
from wire.zconf import read_auth_file, use_zenoh_threads

EXIT_OK, EXIT_ERROR, EXIT_INVALID = 0, 1, 2
REPLAY_WAIT_S = 3.0  # [s] a file or glob source waits this long for a subscriber before playing

logger = logging.getLogger(__name__)


def add_camera_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="the camera service's CONFIG.yaml")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="stop after N frames")
    p.add_argument("--source", default=None, metavar="S", help="override the config's source")
    p.add_argument("--auth", default=None, metavar="FILE",
                   help="Zenoh credentials file (user:password) for a secured router")


def add_calibrate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("image", help="overhead image of the floor markers")
    p.add_argument("--floor-markers", required=True, metavar="FLOOR.yaml",
                   help="the floor markers' dictionary, printed size and surveyed centres")
    p.add_argument("--out", required=True, metavar="CALIB.yaml",
                   help="where to write the calibration")
    p.add_argument("--intrinsics", default=None, metavar="INTR.yaml",
                   help="camera_matrix and dist_coeffs of the lens (frames are undistorted)")
    p.add_argument("--camera-height", type=float, default=None, metavar="M",
                   help="camera height above the floor [m], for a camera looking straight down "
                        "without --intrinsics")
    p.add_argument("--max-error", type=float, default=None, metavar="M",
                   help="largest accepted marker error [m] (default 0.02)")


class Subparsers(Protocol):
    """What ``add_subparsers()`` returns, as far as adding a subcommand uses it."""

    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser: ...


def add_parsers(sub: Subparsers) -> dict[str, Callable[[argparse.Namespace], int]]:
    """Add ``camera`` and ``calibrate`` to ``formation``'s subcommands; returns their handlers."""
    add_camera_args(sub.add_parser("camera", help="the camera service: frames -> poses, obstacles"))
    add_calibrate_args(sub.add_parser("calibrate", help="floor homography from ArUco markers"))
    return {"camera": camera_command, "calibrate": calibrate_command}


def _fail(command: str, message: str, code: int = EXIT_INVALID) -> int:
    print(f"{command}: error: {message}", file=sys.stderr)
    return code


class _CommandFailed(Exception):
    """A command's failure: ``message`` and the exit ``code`` to return."""

    def __init__(self, message: str, code: int = EXIT_INVALID) -> None:
        super().__init__(message)
        self.code = code


def _load_camera_config(ns: argparse.Namespace) -> tuple[ServiceConfig, zenoh.Config]:
    """The config (with ``--source`` and ``--auth`` applied) and its Zenoh config."""
    try:
        cfg = load_config(ns.config)
        if ns.source is not None:
            cfg = replace(cfg, source=ns.source)
        settings = cfg.zenoh
        if ns.auth is not None:
            settings = replace(settings, auth=read_auth_file(ns.auth).auth)
        return cfg, settings.to_config()
    except (ConfigError, ValueError) as exc:
        raise _CommandFailed(f"{ns.config}: {exc}" if isinstance(exc, ConfigError)
                             and not str(exc).startswith(str(ns.config)) else str(exc)) from None


def camera_command(ns: argparse.Namespace, prog: str = "formation camera") -> int:
    """``formation camera``; see the module docstring."""
    if ns.frames is not None and ns.frames < 1:
        return _fail(prog, f"--frames: need N >= 1, got {ns.frames}")
    stop_flag = {"stop": False}

    def on_signal(signum: int, _frame: object) -> None:
        stop_flag["stop"] = True

    def stop() -> bool:
        return stop_flag["stop"]

    try:
        cfg, conf = _load_camera_config(ns)
        previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            use_zenoh_threads("relay")
            stats = _run_camera(cfg, conf, stop, ns.frames)
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)
    except _CommandFailed as exc:
        return _fail(prog, str(exc), exc.code)
    print(json.dumps({"camera": stats}))
    return EXIT_OK


def _open_source(cfg: ServiceConfig, stop: Callable[[], bool],
                 session: zenoh.Session | None = None) -> Source:
    try:
        return make_source(cfg.source, cfg.fps, stop, session)
    except SourceError as exc:
        raise _CommandFailed(str(exc)) from None


def _run_camera(cfg: ServiceConfig, conf: zenoh.Config, stop: Callable[[], bool],
                frames: int | None) -> dict:
    """Open the source and the session, run the camera node, close both; its counters."""
    source = None
    if source_kind(cfg.source) != "zenoh":  # a bad file or camera fails before any network
        source = _open_source(cfg, stop)
    try:
        session = zenoh.open(conf)
    except Exception as exc:  # noqa: BLE001 - zenoh.ZError: router unreachable, ...
        if source is not None:
            source.close()
        raise _CommandFailed(f"cannot open the Zenoh session: {exc}", EXIT_ERROR) from None
    try:
        if source is None:
            source = _open_source(cfg, stop, session)
        node = CameraNode(cfg, session, source)
        if source_kind(cfg.source) in ("glob", "file"):
            node.wait_for_subscribers(REPLAY_WAIT_S, stop)  # a replay waits for a listener
        try:
            return node.run(stop, frames)
        finally:
            node.close()
    finally:
        session.close()


def _calibrate_inputs(
    ns: argparse.Namespace,
) -> tuple[float, FloorMarkers, tuple[np.ndarray, np.ndarray] | None]:
    """``--max-error``, the floor markers and the intrinsics (None without ``--intrinsics``)."""
    max_error = MAX_ERROR_M if ns.max_error is None else ns.max_error
    if not (max_error > 0):
        raise _CommandFailed(f"--max-error: must be > 0 m, got {ns.max_error}")
    if ns.camera_height is not None and not (0 < ns.camera_height < 100):
        raise _CommandFailed(f"--camera-height: must be > 0 m, got {ns.camera_height}")
    try:
        floor = load_floor(ns.floor_markers)
    except ConfigError as exc:
        raise _CommandFailed(f"{ns.floor_markers}: {exc}" if not str(exc).startswith(
            str(ns.floor_markers)) else str(exc)) from None
    if ns.intrinsics is None:
        return max_error, floor, None
    try:
        return max_error, floor, load_intrinsics(ns.intrinsics)
    except ConfigError as exc:
        raise _CommandFailed(str(exc)) from None


def _read_image(path: str) -> np.ndarray:
    if not Path(path).is_file():
        raise _CommandFailed(f"{path}: no such image")
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise _CommandFailed(f"{path}: not a readable image")
    return image


def calibrate_command(ns: argparse.Namespace, prog: str = "formation calibrate") -> int:
    """``formation calibrate``; see the module docstring."""
    try:
        max_error, floor, intrinsics = _calibrate_inputs(ns)
        image = _read_image(ns.image)
    except _CommandFailed as exc:
        return _fail(prog, str(exc), exc.code)
    try:
        report = calibrate_image(image, floor, intrinsics, ns.camera_height, max_error)
    except CalibrationError as exc:
        return _fail(prog, str(exc).removeprefix("calibrate: "))
    _print_marker_errors(report)
    cal = report.calibration
    data = calibration_to_dict(cal)
    data["residual_m"] = round(report.max_error_m, 6)
    Path(ns.out).write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    where = ("unknown" if cal.camera_position is None
             else "({:.3f}, {:.3f}, {:.3f}) m".format(*cal.camera_position))
    print(f"wrote {ns.out}: {len(report.errors_m)} markers, largest error "
          f"{report.max_error_m * 1e3:.1f} mm; camera at {where} "
          f"(focal length from {report.focal_source})")
    return EXIT_OK


def _print_marker_errors(report: CalibrationReport) -> None:
    for mid in sorted(report.errors_m):
        print(f"marker {mid}: {report.errors_m[mid] * 1e3:.1f} mm")
    for mid, err in sorted(report.rejected.items()):
        print(f"marker {mid}: {err * 1e3:.1f} mm  REJECTED as an outlier")
    for mid in report.missing:
        if mid not in report.rejected:
            print(f"marker {mid}: not found in the image")


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m camera_service CONFIG.yaml [--frames N] [--source S] [--auth FILE]``."""
    parser = argparse.ArgumentParser(prog="python -m camera_service",
                                     description="The camera service: frames -> poses over Zenoh.")
    add_camera_args(parser)
    parser.add_argument("--log-level", default="WARNING")
    ns = parser.parse_args(argv)
    logging.basicConfig(level=ns.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    return camera_command(ns, prog="camera_service")


if __name__ == "__main__":
    sys.exit(main())
