"""Overhead camera -> robot poses: calibration (homography), rendering of synthetic frames,
ArUco marker and colour-blob detection, and the service that ties them together."""

from camera_service.calibration import (
    Calibration,
    fit_homography,
    floor_to_pixel,
    load_calibration,
    pixel_to_floor,
    save_calibration,
    synthetic_camera,
)
from camera_service.markers import detect_markers, make_detector
from camera_service.render import default_hues, render_aruco_frame, render_blob_frame
from camera_service.service import CameraConfig, CameraService, PoseObservation, open_source

__all__ = [
    "Calibration", "CameraConfig", "CameraService", "PoseObservation", "default_hues",
    "detect_markers", "fit_homography", "floor_to_pixel", "load_calibration", "make_detector",
    "open_source", "pixel_to_floor", "render_aruco_frame", "render_blob_frame", "save_calibration",
    "synthetic_camera",
]
