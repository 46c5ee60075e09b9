"""The camera section of ``formation bench``: capture -> publish latency of the real process.

A camera PC's view is simulated: ``robots`` robots (default 16) drive on circles in a 4 x 3 m
arena seen by a 1280x960 camera (about 3.1 mm of floor per pixel, 0.10 m markers), the frames
are rendered beforehand (:func:`camera_service.render.render_aruco_frame`, blur and noise) and
encoded as JPEG (quality 90, what an IP camera streams). This process runs a Zenoh router
session on loopback and publishes frame ``k`` at ``start + k / fps`` (paced on deadlines),
stamped with the wall clock at the moment it is published: the capture stamp. The camera
process (``python -m camera_service``, a client of that router, ``source: zenoh:KEY``) decodes,
detects, publishes the obstacles and the 16 poses, and measures ``publish time - capture
stamp`` per frame (transfer to it, JPEG decode, detection, floor mapping and the puts); its
counters come back on stdout when it is stopped (SIGTERM) after the last frame. A process
slower than the frame rate drops frames (it keeps the newest); they are counted ``skipped``.
This process also times each frame's last pose arriving back (capture -> last pose received,
one loopback hop more).
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import yaml
import zenoh

from camera_service.calibration import Calibration, save_calibration, synthetic_camera
from camera_service.node import has_matching_subscribers, percentile
from camera_service.render import render_aruco_frame
from experiments.machine import proc_cpu_s
from runtime.ports import free_tcp_port, tcp_endpoint
from wire.frames import Frame, encode_frame, frame_key
from wire.payloads import decode_pose
from wire.zconf import make_config

ROOT = Path(__file__).resolve().parents[1]
SIZE = (1280, 960)  # [px]
ARENA = (0.0, 0.0, 4.0, 3.0)  # [m]
MARKER = 0.10  # [m]
DISTINCT = 30  # frames rendered; the stream cycles through them
JPEG_QUALITY = 90
PREFIX = "bench"
DRAIN_S = 2.0  # [s] after the last frame, before the camera process is stopped


def synthetic_frames(robots: int, fps: float) -> tuple[list[bytes], Calibration, dict[str, int]]:
    """JPEG frames of ``robots`` markers moving for the benchmark, at ``fps``, with the camera's
    calibration and the robots' marker ids."""
    cal = synthetic_camera(SIZE, ARENA, tilt=0.1)
    ids = {f"r{i}": i for i in range(robots)}
    rng = np.random.default_rng(5)
    cols = math.ceil(math.sqrt(robots * 4 / 3))
    rows = math.ceil(robots / cols)
    out: list[bytes] = []
    for k in range(DISTINCT):
        t = k / fps
        poses: dict[str, tuple[float, float, float]] = {}
        for i in range(robots):
            cx = 0.5 + 3.0 * ((i % cols) + 0.5) / cols
            cy = 0.4 + 2.2 * ((i // cols) + 0.5) / rows
            a = 0.2 / 0.15 * t + i
            poses[f"r{i}"] = (cx + 0.15 * math.cos(a), cy + 0.15 * math.sin(a), a + math.pi / 2)
        frame = render_aruco_frame(poses, cal, ids, marker_side=MARKER, noise_std=2.0,
                                   blur_sigma=0.7, rng=rng)
        ok, jpg = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        out.append(jpg.tobytes())
    return out, cal, ids


def _child_error(proc: subprocess.Popen[str]) -> str:
    """What a child that did not subscribe said: its stderr once it has exited, else 'timeout'."""
    if proc.poll() is None or proc.stderr is None:
        return "timeout"
    return proc.stderr.read()


def bench_camera(robots: int = 16, fps: float = 15.0, frames: int = 450,
                 work: Path | None = None) -> dict:
    """Run the camera process on ``frames`` frames (see the module docstring)."""
    jpgs, cal, ids = synthetic_frames(robots, fps)
    with tempfile.TemporaryDirectory(prefix="bench-camera-") as tmp:
        d = Path(work) if work is not None else Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        save_calibration(cal, d / "calib.yaml")
        port = free_tcp_port()
        (d / "camera.yaml").write_text(yaml.safe_dump({
            "source": f"zenoh:{frame_key(PREFIX)}", "fps": fps, "calibration": "calib.yaml",
            "markers": {"size_m": MARKER, "height_m": 0.0},
            "robots": {i: rid for rid, i in ids.items()}, "prefix": PREFIX,
            "zenoh": {"mode": "client", "connect": [tcp_endpoint(port)]}}))
        arrived: dict[float, list[float]] = {}
        lock = threading.Lock()

        def on_pose(sample: zenoh.Sample) -> None:
            now = time.time()
            stamp = decode_pose(sample.payload.to_bytes()).stamp
            with lock:
                arrived.setdefault(stamp, []).append(now)

        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", ""))
                                            if p)
        with zenoh.open(make_config("router", listen=[tcp_endpoint(port)])) as session:
            sub = session.declare_subscriber(f"{PREFIX}/robot/*/pose", on_pose)
            pub = session.declare_publisher(frame_key(PREFIX))
            proc = subprocess.Popen([sys.executable, "-m", "camera_service", str(d / "camera.yaml")],
                                    env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True)
            try:
                deadline = time.monotonic() + 60.0
                while not has_matching_subscribers(pub):
                    if proc.poll() is not None or time.monotonic() > deadline:
                        raise RuntimeError("camera process did not subscribe: "
                                           + _child_error(proc))
                    time.sleep(0.02)
                time.sleep(0.3)
                cpu0 = proc_cpu_s(proc.pid)
                start = time.monotonic() + 0.1
                sent = []
                for k in range(frames):
                    wait = start + k / fps - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                    stamp = time.time()
                    pub.put(encode_frame(Frame(stamp, "jpeg", jpgs[k % len(jpgs)])))
                    sent.append(stamp)
                time.sleep(DRAIN_S)  # the last frames' poses
                cpu1 = proc_cpu_s(proc.pid)
                proc.send_signal(signal.SIGTERM)  # it prints its counters and exits
                stdout, stderr = proc.communicate(timeout=60.0)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
                sub.undeclare()
                pub.undeclare()
    if proc.returncode != 0:
        raise RuntimeError(f"camera process failed ({proc.returncode}): {stderr.strip()}")
    stats = json.loads(stdout.strip().splitlines()[-1])["camera"]
    e2e = [(max(arrived[s]) - s) * 1e3 for s in sent if len(arrived.get(s, ())) == robots]
    return {
        "robots": robots, "fps": fps, "frames": frames, "image": list(SIZE),
        "encoding": f"jpeg q{JPEG_QUALITY}", "frame_bytes_median": int(np.median([len(j) for j in jpgs])),
        "latency_ms_p50": stats["latency_ms"]["p50"], "latency_ms_p99": stats["latency_ms"]["p99"],
        "latency_ms_max": stats["latency_ms"]["max"],
        "processing_ms_p50": stats["processing_ms"]["p50"],
        "processing_ms_p99": stats["processing_ms"]["p99"],
        "received_ms_p50": percentile(e2e, 50), "received_ms_p99": percentile(e2e, 99),
        "frames_handled": stats["frames"], "frames_skipped": stats["skipped"],
        "detections_min": min(stats["detections"].values()),
        "within_one_period_p99": (stats["latency_ms"]["p99"] or math.inf) <= 1e3 / fps,
        "cpu_ms_per_frame": (None if cpu0 is None or cpu1 is None or not stats["frames"]
                             else (cpu1 - cpu0) * 1e3 / stats["frames"]),
        "load_avg_1min": os.getloadavg()[0],
    }




def format_camera(c: dict) -> list[str]:
    """Table lines of a :func:`bench_camera` result."""
    def f(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    return [
        f"camera process: {c['robots']} robots, {c['image'][0]}x{c['image'][1]} {c['encoding']} "
        f"({c['frame_bytes_median'] // 1024} kB), {c['fps']:.0f} fps, {c['frames']} frames",
        f"  capture -> publish p50 {f(c['latency_ms_p50'])} ms, p99 {f(c['latency_ms_p99'])} ms "
        f"(max {f(c['latency_ms_max'])}); in the process p50 {f(c['processing_ms_p50'])} ms, "
        f"p99 {f(c['processing_ms_p99'])} ms; capture -> last pose received p50 "
        f"{f(c['received_ms_p50'])} ms, p99 {f(c['received_ms_p99'])} ms",
        f"  frames handled {c['frames_handled']}, skipped {c['frames_skipped']}, fewest "
        f"detections of a robot {c['detections_min']}; p99 within one period: "
        f"{c['within_one_period_p99']}; camera process CPU {f(c['cpu_ms_per_frame'])} ms per "
        f"frame; load average {f(c['load_avg_1min'])}",
    ]
