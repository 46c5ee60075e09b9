"""The camera service as a process (issue 17): ``formation calibrate`` and ``formation camera``
on frames from an independent renderer (tests/overhead_rig.py: a tilted pinhole camera with lens
distortion, blur, noise and uneven light), poses and obstacles checked over real Zenoh."""

from __future__ import annotations

import json
import math
import os
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import overhead_rig as rig_mod
import pytest
import yaml
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from camera_service.cli import main as camera_main
from camera_service.config import ConfigError, config_from_dict
from camera_service.tracking import ObstacleTracker, start_track, update_track
from formation.cli import main
from runtime.testing import free_tcp_port, tcp_endpoint
from wire import keys
from wire.frames import Frame, decode_frame, encode_frame, frame_key, stats_key
from wire.payloads import DecodeError, decode_obstacles, decode_pose
from wire.zconf import make_config

REPO = Path(__file__).resolve().parent.parent
FPS = 15.0
N_FRAMES = 24
HEIGHT = 0.19  # [m] robots' markers above the floor
FORK_HEIGHT = 0.5  # [m] the forklift's marker
FLOOR = {40: (0.45, 0.45), 41: (1.9, 0.4), 42: (3.35, 0.45), 43: (3.35, 2.35), 44: (1.9, 2.4),
         45: (0.45, 2.35)}
ROBOTS = {1: "r1", 2: "r2", 3: "r3", 4: "r4", 5: "r5", 6: "r6"}
FORK_V = (0.3, 0.05)  # [m/s]
DIST = np.array([-0.22, 0.06, 0.0005, -0.0004, 0.0])  # a wide-angle lens's distortion


def robots_at(t: float) -> dict[int, tuple[float, float, float]]:
    """Robots on circles (0.25 m radius, 0.2 m/s), heading along the path."""
    out = {}
    for i in range(6):
        cx, cy = 1.1 + 0.8 * (i % 3), 1.2 + 0.8 * (i // 3)
        w = 0.2 / 0.25 * (1 if i % 2 else -1)
        a = w * t + i
        th = a + math.copysign(math.pi / 2, w)
        out[i + 1] = (cx + 0.25 * math.cos(a), cy + 0.25 * math.sin(a),
                      math.atan2(math.sin(th), math.cos(th)))
    return out


def fork_at(t: float) -> tuple[float, float]:
    return 0.9 + FORK_V[0] * t, 0.7 + FORK_V[1] * t


def render(rig, t: float, rng, robots: bool = True, floor: dict | None = None) -> np.ndarray:
    canvas = rig_mod.blank()
    for mid, (x, y) in (FLOOR if floor is None else floor).items():
        rig_mod.draw_square_marker(canvas, rig, mid, x, y, 0.3 * mid, 0.16, 0.0)
    if robots:
        for mid, (x, y, th) in robots_at(t).items():
            rig_mod.draw_disc(canvas, rig, x, y, 0.105, HEIGHT - 0.005, 40)
            rig_mod.draw_square_marker(canvas, rig, mid, x, y, th, 0.10, HEIGHT)
        fx, fy = fork_at(t)
        rig_mod.draw_square_marker(canvas, rig, 30, fx, fy, 0.0, 0.2, FORK_HEIGHT)
    return rig_mod.finish(canvas, rig, rng)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A rendered lab: calibration image, intrinsics, FLOOR.yaml, 24 frames of robots."""
    d = tmp_path_factory.mktemp("lab")
    rng = np.random.default_rng(7)
    rig = rig_mod.make_rig(rng, tilt_deg=(6.0, 12.0), dist=DIST)
    cv2.imwrite(str(d / "calib.png"), render(rig, 0.0, rng, robots=False))
    (d / "floor.yaml").write_text(yaml.safe_dump(
        {"dictionary": "DICT_4X4_50", "size_m": 0.16,
         "markers": {k: list(v) for k, v in FLOOR.items()}}))
    (d / "intr.yaml").write_text(yaml.safe_dump(
        {"camera_matrix": rig.K.tolist(), "dist_coeffs": DIST.tolist()}))
    (d / "frames").mkdir()
    for k in range(N_FRAMES):
        cv2.imwrite(str(d / "frames" / f"{k:04d}.png"), render(rig, k / FPS, rng))
    (d / "static.yaml").write_text((REPO / "tests/scenarios/two-small.yaml").read_text())
    # a calibration for the config tests (the first test makes its own with the command)
    from camera_service.calibrate import calibrate_image
    from camera_service.calibration import save_calibration
    from camera_service.config import load_floor

    report = calibrate_image(cv2.imread(str(d / "calib.png")), load_floor(d / "floor.yaml"),
                             (rig.K, DIST))
    save_calibration(report.calibration, d / "calib.yaml")
    return d, rig


def write_config(d: Path, port: int, **over) -> Path:
    cfg = {
        "source": str(d / "frames" / "*.png"), "fps": FPS, "calibration": "calib.yaml",
        "markers": {"dictionary": "DICT_4X4_50", "size_m": 0.10, "height_m": HEIGHT},
        "robots": ROBOTS,
        "obstacles": {30: {"name": "forklift", "safe_distance": 0.45, "size_m": 0.2,
                           "height_m": FORK_HEIGHT}},
        "static_obstacles": "static.yaml", "prefix": "lab",
        "zenoh": {"mode": "client", "connect": [tcp_endpoint(port)]},
    }
    cfg.update(over)
    path = d / "camera.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


@pytest.mark.integration
def test_calibrate_and_camera_give_poses_and_obstacles_within_the_bounds_over_zenoh(lab, capsys):
    d, rig = lab
    assert main(["calibrate", str(d / "calib.png"), "--floor-markers", str(d / "floor.yaml"),
                 "--out", str(d / "calib.yaml"), "--intrinsics", str(d / "intr.yaml")]) == 0
    out = capsys.readouterr().out
    assert all(f"marker {m}:" in out for m in FLOOR)
    cal = yaml.safe_load((d / "calib.yaml").read_text())
    np.testing.assert_allclose(cal["camera_position"], rig.centre, atol=0.02)

    port = free_tcp_port()
    router = zenoh.open(make_config("router", listen=[tcp_endpoint(port)]))
    poses: list[tuple[str, float, float, float, float]] = []
    obstacles: list = []
    lock = threading.Lock()

    def on_pose(sample):
        p = decode_pose(sample.payload.to_bytes())
        with lock:
            poses.append((str(sample.key_expr).split("/")[2], p.stamp, p.x, p.y, p.theta))

    def on_obstacles(sample):
        with lock:
            obstacles.append(decode_obstacles(sample.payload.to_bytes()))

    subs = [router.declare_subscriber("lab/robot/*/pose", on_pose),
            router.declare_subscriber(keys.obstacles_key("lab"), on_obstacles)]
    cfg = write_config(d, port)
    proc = subprocess.Popen([sys.executable, "-m", "camera_service", str(cfg)], env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while len(obstacles) < 8 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        replies = list(router.get(stats_key("lab"), timeout=5.0))
        live = json.loads(replies[0].ok.payload.to_string())
        assert live["frames"] >= 8
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        for s in subs:
            s.undeclare()
        router.close()
    assert proc.returncode == 0, stderr
    stats = json.loads(stdout.strip().splitlines()[-1])["camera"]
    assert stats["frames"] == N_FRAMES and stats["wrong_size"] == 0
    assert stats["unknown_markers"] == 0  # the floor markers in view are known to the calibration
    assert cal["floor_markers"] == sorted(FLOOR)

    # frame k's stamp is the k-th obstacles message's (one per frame, published first)
    stamps = sorted({o.stamp for o in obstacles})
    assert len(stamps) == N_FRAMES
    index = {s: k for k, s in enumerate(stamps)}
    pos_err, head_err = [], []
    seen = {r: 0 for r in ROBOTS.values()}
    for rid, stamp, x, y, th in poses:
        k = index[stamp]
        tx, ty, tth = robots_at(k / FPS)[int(rid[1:])]
        pos_err.append(math.hypot(x - tx, y - ty))
        head_err.append(abs(math.remainder(th - tth, 2 * math.pi)))
        seen[rid] += 1
    assert min(seen.values()) >= 0.95 * N_FRAMES, seen
    assert np.median(pos_err) <= 0.003 and np.percentile(pos_err, 95) <= 0.008
    assert math.degrees(np.median(head_err)) <= 2.0
    fork_err, vel_err = [], []
    for msg in obstacles:
        k = index[msg.stamp]
        names = {o.id: o for o in msg.obstacles}
        assert {"o1", "forklift"} <= set(names)  # the static scenario's and the tracked one
        f = names["forklift"]
        fx, fy = fork_at(k / FPS)
        fork_err.append(math.hypot(f.x - fx, f.y - fy))
        if k >= 6:  # the filter has settled
            vel_err.append(math.hypot(f.vx - FORK_V[0], f.vy - FORK_V[1]))
    assert max(fork_err) <= 0.010
    assert max(vel_err) <= 0.05
    print(f"\nposition median {np.median(pos_err) * 1e3:.2f} mm, p95 "
          f"{np.percentile(pos_err, 95) * 1e3:.2f} mm, heading median "
          f"{math.degrees(np.median(head_err)):.2f} deg, forklift max {max(fork_err) * 1e3:.2f} "
          f"mm, velocity max err {max(vel_err):.3f} m/s")


def test_calibration_sets_aside_a_misplaced_marker_and_reports_it(lab, tmp_path, capsys):
    d, _rig = lab
    floor = {**FLOOR, 44: (1.9 + 0.12, 2.4)}  # surveyed 12 cm wrong
    (tmp_path / "floor.yaml").write_text(yaml.safe_dump(
        {"size_m": 0.16, "markers": {k: list(v) for k, v in floor.items()}}))
    code = main(["calibrate", str(d / "calib.png"), "--floor-markers", str(tmp_path / "floor.yaml"),
                 "--out", str(tmp_path / "c.yaml"), "--intrinsics", str(d / "intr.yaml")])
    out = capsys.readouterr().out
    assert code == 0 and "marker 44" in out and "REJECTED" in out


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("floor, culprit", [
    ({k: FLOOR[k] for k in (40, 41, 42)}, "need at least 4"),
    ({40: (0.45, 0.45), 41: (1.9, 0.4), 42: (3.35, 0.45), 99: (0.0, 0.0)}, "markers.99"),
    ({40: (0.45, 0.45), 41: (1.9, 0.46), 42: (3.35, 0.45), 43: (2.6, 0.44)}, "one line"),
])
def test_calibrate_refuses_too_few_collinear_or_invalid_markers_in_one_line(lab, tmp_path, capsys,
                                                                            floor, culprit):
    d, rig = lab
    image = tmp_path / "img.png"
    layout = {40: (0.45, 0.45), 41: (1.9, 0.46), 42: (3.35, 0.45), 43: (2.6, 0.44)} \
        if culprit == "one line" else {k: FLOOR[k] for k in (40, 41, 42)}
    cv2.imwrite(str(image), render(rig, 0.0, np.random.default_rng(1), robots=False,
                                   floor=layout))
    (tmp_path / "floor.yaml").write_text(yaml.safe_dump(
        {"size_m": 0.16, "markers": {k: list(v) for k, v in floor.items()}}))
    assert main(["calibrate", str(image), "--floor-markers", str(tmp_path / "floor.yaml"),
                 "--out", str(tmp_path / "c.yaml"), "--intrinsics", str(d / "intr.yaml")]) == 2
    assert culprit in _one_error_line(capsys)
    assert not (tmp_path / "c.yaml").exists()


@pytest.mark.parametrize("over, culprit", [
    ({"colour": 3}, "colour: unknown key"),
    ({"fps": -1}, "fps"),
    ({"markers": {"size_m": 0.1, "height_m": "high"}}, "markers.height_m"),
    ({"robots": {3: "r1", 5: "r1"}}, "robots.5"),
    ({"robots": {99: "r1"}}, "robots.99"),
    ({"obstacles": {1: {"name": "fork", "safe_distance": 0.4}}}, "obstacles.1"),
    ({"calibration": "nope.yaml"}, "calibration"),
    ({"zenoh": {"mode": "client"}}, "zenoh.connect"),
    ({"source": str(Path("/nonexistent") / "*.png")}, "source"),
])
def test_a_bad_camera_config_or_source_is_one_line_naming_it_and_exit_2(lab, capsys, over,
                                                                       culprit):
    d, _rig = lab
    cfg = write_config(d, free_tcp_port(), **over)
    assert main(["camera", str(cfg), "--frames", "1"]) == 2
    assert culprit in _one_error_line(capsys)


def test_a_calibration_file_with_a_bad_value_is_one_line_naming_it(tmp_path, capsys):
    (tmp_path / "calib.yaml").write_text(yaml.safe_dump(
        {"version": 1, "image_size": [640, 480], "floor_from_pixel": [[1, 0, 0], [0, 1, 0],
                                                                       [0, 0, 1]],
         "camera_position": [0, 0, -3]}))
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(
        {"source": "0", "calibration": "calib.yaml", "markers": {"size_m": 0.1},
         "robots": {1: "r1"}}))
    assert camera_main([str(tmp_path / "c.yaml")]) == 2
    assert "camera_position" in _one_error_line(capsys)


def test_the_config_loader_names_unknown_nested_keys(tmp_path):
    with pytest.raises(ConfigError, match=r"markers\.colour: unknown key"):
        config_from_dict({"source": 0, "calibration": "x", "markers": {"size_m": 0.1,
                                                                        "colour": 1}}, tmp_path)


# --- the process's robustness, in process, over a real Zenoh session ------------------------------


class _ListSource:
    """A finite list of (frame, stamp) items (a seam for the node; sources are tested above)."""

    def __init__(self, items):
        self.items = list(items)
        self.counts = {"reconnects": 0, "read_failures": 0, "undecodable": 0, "skipped": 0}

    def read(self):
        from camera_service.sources import EndOfSource

        if not self.items:
            raise EndOfSource
        return self.items.pop(0)

    def close(self):
        pass


@pytest.mark.integration
def test_bad_frames_duplicates_unknown_ids_and_empty_frames_are_counted_not_fatal(tmp_path):
    from camera_service.calibration import floor_to_pixel, save_calibration, synthetic_camera
    from camera_service.config import load_config
    from camera_service.node import CameraNode
    from camera_service.render import render_aruco_frame

    cal = synthetic_camera()
    save_calibration(cal, tmp_path / "calib.yaml")
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(
        {"source": "0", "calibration": "calib.yaml",
         "markers": {"size_m": 0.08, "height_m": 0.0}, "robots": {0: "a", 1: "b"},
         "zenoh": {"mode": "peer"}}))
    cfg = load_config(tmp_path / "c.yaml")
    good = render_aruco_frame({"a": (1.0, 1.0, 0.0), "b": (2.0, 1.5, 1.0)}, cal, {"a": 0, "b": 1})
    dup = good.copy()  # b's marker a second time, pasted at (3, 2)
    other = render_aruco_frame({"b": (3.0, 2.0, 0.0)}, cal, {"b": 1})
    (u0, v0), (u1, v1) = (np.round(floor_to_pixel(cal, p)).astype(int)
                          for p in ((2.9, 2.1), (3.1, 1.9)))
    dup[v0:v1, u0:u1] = other[v0:v1, u0:u1]
    unknown = render_aruco_frame({"a": (1.0, 1.0, 0.0), "x": (2.0, 2.0, 0.0)}, cal,
                                 {"a": 0, "x": 7})
    empty = render_aruco_frame({}, cal, {})
    items = [(good, 1.0), (good[:100], 2.0), (None, 3.0), (dup, 4.0), (unknown, 5.0),
             (empty, 6.0), (np.zeros((2, 2, 7), np.uint8), 7.0), (good, 8.0)]
    with zenoh.open(make_config("peer")) as session:
        node = CameraNode(cfg, session, _ListSource(items))
        stats = node.run(lambda: False)
        node.close()
    assert stats["frames"] == 7 and stats["bad_frames"] == 2 and stats["wrong_size"] == 1
    assert stats["duplicate_markers"] == 1 and stats["unknown_markers"] == 1
    assert stats["empty_frames"] == 1
    assert stats["detections"] == {"a": 4, "b": 2}  # b is ambiguous in the duplicate frame


def test_the_frame_payload_round_trips_and_garbage_is_a_decode_error():
    ok, png = cv2.imencode(".png", np.zeros((4, 4), np.uint8))
    frame = Frame(12.5, "png", png.tobytes())
    data = encode_frame(frame)
    assert decode_frame(data) == frame
    assert frame_key("lab") == "lab/camera/frame"
    for bad in (b"", data[:-1], data + b"x", b"\x02" + data[1:], data[:9] + b"\x03gif" + data[13:],
                data[:1] + struct.pack("<d", math.nan) + data[9:]):
        with pytest.raises(DecodeError):
            decode_frame(bad)
    rng = np.random.default_rng(0)
    for _ in range(300):
        raw = bytes(rng.integers(0, 256, rng.integers(0, 40), dtype=np.uint8))
        try:
            decode_frame(raw)
        except DecodeError:
            pass


def test_the_velocity_filter_follows_a_constant_velocity_through_noise():
    rng = np.random.default_rng(3)
    track = start_track(0.0, 0.0, 0.0)
    errs = []
    for k in range(1, 60):
        t = k / 15
        track = update_track(track, 0.3 * t + rng.normal(0, 0.002), -0.1 * t
                             + rng.normal(0, 0.002), t, hold_s=1.0)
        if k > 10:
            errs.append(math.hypot(track.vx - 0.3, track.vy + 0.1))
    assert max(errs) < 0.03  # a raw difference of the same positions: up to ~0.1 m/s


def test_an_unseen_obstacle_is_held_with_a_growing_safe_distance_then_dropped():
    tracker = ObstacleTracker({"fork": 0.4}, hold_s=0.5)
    for k in range(10):
        tracker.step({"fork": (0.2 * k / 10, 0.0)}, k / 10)
    held = [tracker.step({}, 0.9 + dt) for dt in (0.1, 0.3, 0.5, 0.7)]
    ds = [h[0].ds for h in held[:3]]
    assert ds[0] < ds[1] < ds[2] and ds[0] > 0.4
    assert abs(ds[2] - (0.4 + 0.2 * 0.5)) < 0.02  # last speed x age
    assert held[3] == [] and tracker.dropped == 1


# --- sources ---------------------------------------------------------------------------------------


class _FakeCapture:
    def __init__(self, script):
        self.script = script  # list of bools: read succeeds?
        self.opened = script is not None

    def isOpened(self):  # OpenCV's name
        return self.opened

    def read(self):
        if self.script:
            ok = self.script.pop(0)
            return ok, (np.zeros((4, 4, 3), np.uint8) if ok else None)
        return False, None

    def release(self):
        pass


def test_a_camera_that_drops_out_is_reopened_with_back_off_and_counted(monkeypatch):
    from camera_service import sources

    monkeypatch.setattr(sources, "BACKOFF_START_S", 0.01)
    monkeypatch.setattr(sources, "BACKOFF_MAX_S", 0.04)
    opens = [[True, True, False], None, None, [True]]  # works, fails, two failed reopens, works
    src = sources.CaptureSource(0, lambda: False, opener=lambda _t: _FakeCapture(opens.pop(0)))
    got = [src.read() for _ in range(6)]
    frames = [g for g in got if g is not None]
    assert len(frames) == 3 and all(f[0].shape == (4, 4, 3) for f in frames)
    assert src.counts["read_failures"] == 1 and src.counts["reconnects"] == 3
    assert src.backoff == 0.01  # reset by the frame after the reconnect


def test_a_camera_that_never_opens_is_a_source_error_naming_it():
    from camera_service.sources import CaptureSource, SourceError

    with pytest.raises(SourceError, match="source: cannot open 3"):
        CaptureSource(3, lambda: False, opener=lambda _t: _FakeCapture(None))


def test_an_image_glob_is_stamped_k_over_fps_and_skips_unreadable_files(tmp_path):
    from camera_service.sources import EndOfSource, GlobSource

    for k in range(3):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), np.full((8, 8, 3), k, np.uint8))
    (tmp_path / "f1.png").write_bytes(b"not a png")
    src = GlobSource(str(tmp_path / "*.png"), 50.0, lambda: False)
    items = [src.read() for _ in range(3)]
    with pytest.raises(EndOfSource):
        src.read()
    assert [i[0] is None for i in items] == [False, True, False]
    np.testing.assert_allclose([i[1] - items[0][1] for i in items], [0.0, 0.02, 0.04], atol=1e-6)
    assert src.counts["undecodable"] == 1


@pytest.mark.integration
def test_zenoh_frames_that_do_not_decode_are_counted_and_skipped():
    from camera_service.sources import ZenohSource

    ok, png = cv2.imencode(".png", np.full((6, 8, 3), 9, np.uint8))
    good = encode_frame(Frame(3.5, "png", png.tobytes()))
    broken = encode_frame(Frame(4.0, "png", png.tobytes()[:20]))  # a PNG cut short
    with zenoh.open(make_config("peer")) as session:
        src = ZenohSource(session, "t/camera/frame")
        pub = session.declare_publisher("t/camera/frame")
        got = []
        for payload in (b"\x07garbage", broken, good):
            pub.put(payload)
            for _ in range(20):
                item = src.read()
                if item is not None or src.counts["undecodable"] > len(got):
                    break
            got.append(item)
        src.close()
    assert got[0] is None and got[1] == (None, 4.0)
    assert got[2][0].shape == (6, 8) and got[2][1] == 3.5  # decoded grey
    assert src.counts["undecodable"] == 2


@pytest.mark.integration
def test_the_camera_process_stops_cleanly_on_sigterm_and_prints_its_counters(tmp_path):
    from camera_service.calibration import save_calibration, synthetic_camera

    save_calibration(synthetic_camera(), tmp_path / "calib.yaml")
    port = free_tcp_port()
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(
        {"source": "zenoh:t/camera/frame", "calibration": "calib.yaml",
         "markers": {"size_m": 0.08}, "robots": {0: "a"}, "prefix": "t",
         "zenoh": {"mode": "peer", "listen": [tcp_endpoint(port)]}}))
    proc = subprocess.Popen([sys.executable, "-m", "camera_service", str(tmp_path / "c.yaml")],
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with zenoh.open(make_config("peer", connect=[tcp_endpoint(port)],
                                    connect_timeout_s=20.0)) as session:
            deadline = time.monotonic() + 30
            live = None
            while live is None and time.monotonic() < deadline:
                for reply in session.get(stats_key("t"), timeout=1.0):
                    if reply.ok is not None:
                        live = json.loads(reply.ok.payload.to_string())
                time.sleep(0.1)
        assert live is not None and live["frames"] == 0
        proc.send_signal(15)
        stdout, stderr = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert json.loads(stdout.strip().splitlines()[-1])["camera"]["frames"] == 0


def test_a_video_file_plays_at_its_own_rate_and_then_ends(tmp_path):
    from camera_service.sources import EndOfSource, SourceError, VideoFileSource, make_source

    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 50.0, (64, 48))
    for k in range(3):
        writer.write(np.full((48, 64, 3), 40 * k, np.uint8))
    writer.release()
    src = make_source(str(path), 15.0, lambda: False)
    assert isinstance(src, VideoFileSource) and src.fps == 50.0
    items = [src.read() for _ in range(3)]
    with pytest.raises(EndOfSource):
        src.read()
    src.close()
    assert [i[0].shape for i in items] == [(48, 64, 3)] * 3
    np.testing.assert_allclose([i[1] - items[0][1] for i in items], [0.0, 0.02, 0.04], atol=1e-6)
    with pytest.raises(SourceError, match="no such file"):
        make_source(str(tmp_path / "missing.mp4"), 15.0, lambda: False)
    with pytest.raises(SourceError, match="exact key"):
        make_source("zenoh:lab/**", 15.0, lambda: False, session=object())


@settings(max_examples=200, deadline=None)
@given(cx=st.floats(-5, 5), cy=st.floats(-5, 5), cz=st.floats(1.0, 10.0),
       px=st.floats(-8, 8), py=st.floats(-8, 8), frac=st.floats(0.0, 0.9))
def test_parallax_correction_puts_a_raised_point_back_under_itself(cx, cy, cz, px, py, frac):
    from camera_service.calibration import correct_parallax

    h = frac * cz
    # where the ray from the camera through (px, py, h) meets the floor
    s = cz / (cz - h)
    floor = np.array([[cx + (px - cx) * s, cy + (py - cy) * s]])
    np.testing.assert_allclose(correct_parallax(floor, (cx, cy, cz), h)[0], [px, py], atol=1e-9)


def test_the_source_option_overrides_the_config_and_a_bad_one_is_named(lab, capsys):
    d, _rig = lab
    cfg = write_config(d, free_tcp_port())
    assert main(["camera", str(cfg), "--source", str(d / "nope.mp4")]) == 2
    assert "nope.mp4" in _one_error_line(capsys)
