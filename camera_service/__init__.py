"""Overhead camera -> robot poses on the floor.

Calibration (floor <-> pixel homography), rendering of synthetic overhead frames, ArUco marker
and colour-blob detection, and the :class:`CameraService` that ties them together. Importable
without Zenoh: the networking wrapper lives elsewhere and calls :meth:`CameraService.process`.
"""

from camera_service.blobs import BlobDetection, detect_blobs, motion_heading
from camera_service.calibration import (
    Calibration,
    fit_homography,
    floor_to_pixel,
    heading_to_floor,
    heading_to_pixel,
    load_calibration,
    pixel_to_floor,
    reprojection_error,
    save_calibration,
    synthetic_camera,
)
from camera_service.markers import (
    MarkerDetection,
    aruco_dictionary,
    detect_markers,
    make_detector,
    marker_floor_pose,
)
from camera_service.render import (
    default_hues,
    hue_to_bgr,
    render_aruco_frame,
    render_blob_frame,
)
from camera_service.service import CameraConfig, CameraService, PoseObservation, open_source

__all__ = [
    "BlobDetection",
    "Calibration",
    "CameraConfig",
    "CameraService",
    "MarkerDetection",
    "PoseObservation",
    "aruco_dictionary",
    "default_hues",
    "detect_blobs",
    "detect_markers",
    "fit_homography",
    "floor_to_pixel",
    "heading_to_floor",
    "heading_to_pixel",
    "hue_to_bgr",
    "load_calibration",
    "make_detector",
    "marker_floor_pose",
    "motion_heading",
    "open_source",
    "pixel_to_floor",
    "render_aruco_frame",
    "render_blob_frame",
    "reprojection_error",
    "save_calibration",
    "synthetic_camera",
]
