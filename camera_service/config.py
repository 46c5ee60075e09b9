"""The camera service's ``CONFIG.yaml`` and the calibration's ``FLOOR.yaml`` (docs/camera.md).

Both are strict, like the scenario file: an unknown key, a missing one or a bad value raises
:class:`ConfigError` (a ``ValueError``) naming it by its path (``markers.height_m``,
``robots.3``, ...). Paths inside the file (``calibration``, ``static_obstacles``) are relative to
the file's folder. Loading also reads the calibration and the static obstacles' scenario, so a
config that loads is one the service can run.

``CONFIG.yaml``::

    source: 0            # camera index, video file, rtsp:// or http:// URL, glob of images, zenoh:KEY
    fps: 15              # stamps of sources without timestamps (image globs): frame k at k/fps
    calibration: calib.yaml
    markers: {dictionary: DICT_4X4_50, size_m: 0.10, height_m: 0.19}
    robots: {3: r1, 5: r2}                                  # marker id -> robot id
    obstacles: {30: {name: forklift, safe_distance: 0.45}}  # marker id -> moving obstacle
    static_obstacles: warehouse.yaml                        # optional
    prefix: warehouse
    zenoh: {mode: client, connect: ["tcp/192.168.1.10:7447"]}
    obstacle_hold_s: 1.0   # optional: how long an unseen moving obstacle is kept [s]

An obstacle may give its own marker's ``size_m`` and ``height_m`` (a forklift's marker is
neither the robots' size nor at their height).

``zenoh`` takes ``mode``, ``connect``, ``listen``, ``user``, ``password`` and ``config_file``
(a Zenoh JSON5 file to start from, e.g. for TLS).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from camera_service.calibration import Calibration, load_calibration
from camera_service.markers import aruco_dictionary, dictionary_size
from geometry.shapes import Shape
from scenario import ScenarioError, load_scenario
from wire import keys
from wire.zconf import MODES, UsrPwdAuth, ZenohSettings

CONFIG_KEYS = {"source", "fps", "calibration", "markers", "robots", "obstacles",
               "static_obstacles", "prefix", "zenoh", "obstacle_hold_s"}
MARKER_KEYS = {"dictionary", "size_m", "height_m"}
OBSTACLE_KEYS = {"name", "safe_distance", "size_m", "height_m"}
ZENOH_KEYS = {"mode", "connect", "listen", "user", "password", "config_file"}
FLOOR_KEYS = {"dictionary", "size_m", "markers"}
DEFAULT_FPS = 15.0  # [1/s]
DEFAULT_HOLD_S = 1.0  # [s] an unseen moving obstacle stays this long
MAX_MARKER_HEIGHT = 2.0  # [m] a robot's marker higher than this is a typo


class ConfigError(ValueError):
    """An invalid configuration; the message names the culprit."""


@dataclass(frozen=True)
class MovingObstacle:
    """A moving obstacle tracked from its marker."""

    name: str
    safe_distance: float  # [m]
    size_m: float | None = None  # [m] its marker's printed side (None: markers.size_m)
    height_m: float | None = None  # [m] its marker above the floor (None: markers.height_m)


@dataclass(frozen=True)
class StaticObstacle:
    """A circle that does not move (from the scenario named by ``static_obstacles``)."""

    name: str
    x: float  # [m]
    y: float  # [m]
    safe_distance: float  # [m]


@dataclass(frozen=True)
class ServiceConfig:
    """A loaded, checked ``CONFIG.yaml``."""

    source: str
    calibration: Calibration
    robots: Mapping[int, str]  # marker id -> robot id
    obstacles: Mapping[int, MovingObstacle]  # marker id -> obstacle
    static_obstacles: tuple[StaticObstacle, ...] = ()
    static_shapes: tuple[Shape, ...] = ()  # the scenario's walls and shelves
    fps: float = DEFAULT_FPS
    dictionary: str = "DICT_4X4_50"
    marker_size: float = 0.10  # [m]
    marker_height: float = 0.0  # [m] above the floor
    prefix: str = keys.DEFAULT_PREFIX
    zenoh: ZenohSettings = ZenohSettings(mode="peer")
    obstacle_hold_s: float = DEFAULT_HOLD_S
    path: str = "<config>"


@dataclass(frozen=True)
class FloorMarkers:
    """A loaded ``FLOOR.yaml``: floor markers' dictionary, printed side and surveyed centres."""

    dictionary: str
    size_m: float
    markers: Mapping[int, tuple[float, float]]  # id -> floor x, y of the centre [m]


def _mapping(raw: Any, where: str, allowed: set[str]) -> dict[str, Any]:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(raw).__name__}")
    for key in raw:
        if str(key) not in allowed:
            raise ConfigError(f"{where + '.' if where else ''}{key}: unknown key")
    return raw


def _number(raw: Any, where: str, low: float = -math.inf, high: float = math.inf,
            low_open: bool = False) -> float:
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        raise ConfigError(f"{where}: expected a number, got {raw!r}")
    value = float(raw)
    if not math.isfinite(value) or value < low or value > high or (low_open and value == low):
        bound = f"> {low}" if low_open else f">= {low}"
        raise ConfigError(f"{where}: must be a finite number {bound}"
                          + (f" and <= {high}" if math.isfinite(high) else "") + f", got {raw!r}")
    return value


def _marker_id(raw: Any, where: str, size: int) -> int:
    if isinstance(raw, bool) or not isinstance(raw, int):
        raise ConfigError(f"{where}: marker id {raw!r} must be an integer")
    if not 0 <= raw < size:
        raise ConfigError(f"{where}: marker id {raw} is outside the dictionary (0..{size - 1})")
    return raw


def _dictionary(raw: Any, where: str) -> str:
    try:
        aruco_dictionary(raw)
    except ValueError:
        raise ConfigError(f"{where}: unknown ArUco dictionary {raw!r}") from None
    return raw


def _path(raw: Any, where: str, base: Path) -> Path:
    if not isinstance(raw, str) or not raw:
        raise ConfigError(f"{where}: expected a file path, got {raw!r}")
    path = Path(raw).expanduser()
    path = path if path.is_absolute() else base / path
    if not path.is_file():
        raise ConfigError(f"{where}: no such file {str(path)!r}")
    return path


def _source(raw: Any) -> str:
    if isinstance(raw, bool) or not isinstance(raw, int | str) or raw == "":
        raise ConfigError(f"source: expected a camera index, path, URL, glob or zenoh:KEY, "
                          f"got {raw!r}")
    if isinstance(raw, int) and raw < 0:
        raise ConfigError(f"source: camera index must be >= 0, got {raw}")
    return str(raw)


def _read_yaml(path: str | Path, what: str) -> Any:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise ConfigError(f"{path}: not valid YAML{where}") from None


def _zenoh(raw: Any, base: Path) -> ZenohSettings:
    m = _mapping(raw, "zenoh", ZENOH_KEYS)
    mode = m.get("mode", "client")
    if mode not in MODES:
        raise ConfigError(f"zenoh.mode: must be one of {MODES}, got {mode!r}")
    connect, listen = _endpoints(m, "connect"), _endpoints(m, "listen")
    if mode == "client" and not connect:
        raise ConfigError("zenoh.connect: a client needs at least one endpoint (the router)")
    auth = _auth(m.get("user"), m.get("password"))
    config_file = None
    if "config_file" in m:
        config_file = str(_path(m["config_file"], "zenoh.config_file", base))
    try:
        return ZenohSettings(mode=mode, connect=connect, listen=listen,
                             connect_timeout_s=10.0 if mode == "client" else None,
                             config_file=config_file, auth=auth)
    except ValueError as exc:
        raise ConfigError(f"zenoh: {exc}") from None


def _endpoints(m: dict[str, Any], name: str) -> tuple[str, ...]:
    """``zenoh.connect`` or ``zenoh.listen``: one endpoint or a list of them."""
    value = m.get(name, [])
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(e, str) and "/" in e for e in value):
        raise ConfigError(f"zenoh.{name}: expected a list of endpoints such as "
                          f"'tcp/192.168.1.10:7447', got {value!r}")
    return tuple(value)


def _auth(user: Any, password: Any) -> UsrPwdAuth | None:
    """``zenoh.user`` and ``zenoh.password``: both or neither, non-empty strings."""
    if (user is None) != (password is None):
        raise ConfigError(f"zenoh.{'password' if password is None else 'user'}: "
                          "user and password go together")
    if user is None:
        return None
    if not isinstance(user, str) or not user or not isinstance(password, str) or not password:
        raise ConfigError("zenoh.user: user and password must be non-empty strings")
    return UsrPwdAuth(user, password)


def load_static_obstacles(path: Path) -> tuple[tuple[StaticObstacle, ...], tuple[Shape, ...]]:
    """The scenario's obstacles that do not move: its circles without a velocity, and its walls
    and shelves (published as they are, :mod:`geometry.shapes`)."""
    try:
        scenario = load_scenario(path)
    except ScenarioError as exc:
        raise ConfigError(f"static_obstacles: {exc}") from None
    out = []
    for o in scenario.obstacles:
        centre = getattr(o, "center", None)
        if centre is None or tuple(getattr(o, "velocity", (0.0, 0.0))) != (0.0, 0.0):
            continue  # a moving obstacle of a simulation, or a shape that is not a circle
        out.append(StaticObstacle(o.name, float(centre[0]), float(centre[1]),
                                  float(o.safe_distance)))
    return tuple(out), tuple(scenario.shapes)


def config_from_dict(data: Any, base: Path, path: str = "<config>") -> ServiceConfig:
    """A :class:`ServiceConfig` from parsed YAML; relative paths resolve against ``base``.

    The sections are checked in this order (the first problem is the one reported): required
    keys, source, fps, obstacle_hold_s, markers, robots, obstacles, static_obstacles and the
    obstacles' names, prefix, zenoh, calibration."""
    m = _mapping(data, "", CONFIG_KEYS)
    for key in ("source", "calibration", "markers"):
        if key not in m:
            raise ConfigError(f"{key}: missing")
    source = _source(m["source"])
    fps = _number(m.get("fps", DEFAULT_FPS), "fps", 0.0, 1000.0, low_open=True)
    hold = _number(m.get("obstacle_hold_s", DEFAULT_HOLD_S), "obstacle_hold_s", 0.0, 60.0)
    dictionary, size_m, height = _markers(m["markers"])
    n_ids = dictionary_size(dictionary)
    robots = _robots(m.get("robots", {}) or {}, n_ids)
    obstacles = _moving_obstacles(m.get("obstacles", {}) or {}, n_ids, robots)
    if not robots and not obstacles:
        raise ConfigError("robots: no robot and no obstacle marker to look for")
    statics: tuple[StaticObstacle, ...] = ()
    shapes: tuple[Shape, ...] = ()
    if m.get("static_obstacles") is not None:
        statics, shapes = load_static_obstacles(_path(m["static_obstacles"], "static_obstacles", base))
    _check_unique_names([o.name for o in obstacles.values()] + [o.name for o in statics]
                        + [s.name for s in shapes])
    prefix = _prefix(m.get("prefix", keys.DEFAULT_PREFIX))
    zenoh = _zenoh(m.get("zenoh", {"mode": "peer"}), base)
    top = max([height, *(o.height_m or 0.0 for o in obstacles.values())])
    calibration = _calibration(_path(m["calibration"], "calibration", base), top)
    return ServiceConfig(
        source=source, calibration=calibration, robots=robots, obstacles=obstacles,
        static_obstacles=statics, static_shapes=shapes, fps=fps, dictionary=dictionary, marker_size=size_m,
        marker_height=height, prefix=prefix, zenoh=zenoh, obstacle_hold_s=hold, path=path)


def _markers(raw: Any) -> tuple[str, float, float]:
    """``markers``: the dictionary, the printed side [m] and the height above the floor [m]."""
    mk = _mapping(raw, "markers", MARKER_KEYS)
    dictionary = _dictionary(mk.get("dictionary", "DICT_4X4_50"), "markers.dictionary")
    if "size_m" not in mk:
        raise ConfigError("markers.size_m: missing")
    size_m = _number(mk["size_m"], "markers.size_m", 0.0, 2.0, low_open=True)
    height = _number(mk.get("height_m", 0.0), "markers.height_m", 0.0, MAX_MARKER_HEIGHT)
    return dictionary, size_m, height


def _robots(raw: Any, n_ids: int) -> dict[int, str]:
    """``robots``: marker id -> robot id, one marker per robot."""
    if not isinstance(raw, dict):
        raise ConfigError(f"robots: expected a mapping marker id -> robot id, got {raw!r}")
    robots: dict[int, str] = {}
    for mid, rid in raw.items():
        where = f"robots.{mid}"
        _marker_id(mid, where, n_ids)
        problem = keys.id_problem(rid)
        if problem is not None:
            raise ConfigError(f"{where}: robot id {rid!r} {problem}")
        if rid in robots.values():
            raise ConfigError(f"{where}: robot {rid!r} has two markers")
        robots[mid] = rid
    return robots


def _moving_obstacles(raw: Any, n_ids: int, robots: Mapping[int, str]) -> dict[int, MovingObstacle]:
    """``obstacles``: marker id -> moving obstacle, on markers no robot carries."""
    if not isinstance(raw, dict):
        raise ConfigError(f"obstacles: expected a mapping marker id -> obstacle, got {raw!r}")
    obstacles: dict[int, MovingObstacle] = {}
    for mid, spec in raw.items():
        where = f"obstacles.{mid}"
        _marker_id(mid, where, n_ids)
        if mid in robots:
            raise ConfigError(f"{where}: marker id {mid} is also robot {robots[mid]!r}'s")
        obstacles[mid] = _moving_obstacle(spec, where)
    return obstacles


def _moving_obstacle(spec: Any, where: str) -> MovingObstacle:
    s = _mapping(spec, where, OBSTACLE_KEYS)
    for key in ("name", "safe_distance"):
        if key not in s:
            raise ConfigError(f"{where}.{key}: missing")
    problem = keys.id_problem(s["name"])
    if problem is not None:
        raise ConfigError(f"{where}.name: {s['name']!r} {problem}")
    ds = _number(s["safe_distance"], f"{where}.safe_distance", 0.0, 100.0, low_open=True)
    osize = ohigh = None
    if "size_m" in s:
        osize = _number(s["size_m"], f"{where}.size_m", 0.0, 2.0, low_open=True)
    if "height_m" in s:
        ohigh = _number(s["height_m"], f"{where}.height_m", 0.0, MAX_MARKER_HEIGHT)
    return MovingObstacle(s["name"], ds, osize, ohigh)


def _check_unique_names(names: list[str]) -> None:
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"obstacles: name {dup[0]!r} is used twice")


def _prefix(prefix: Any) -> str:
    try:
        keys.validate_prefix(prefix)
    except ValueError as exc:
        raise ConfigError(f"prefix: {exc}") from None
    return prefix


def _calibration(cal_path: Path, top: float) -> Calibration:
    """The calibration file, with a camera above ``top``, the highest marker [m] (if above 0)."""
    try:
        calibration = load_calibration(cal_path)
    except ValueError as exc:
        raise ConfigError(f"calibration: {cal_path}: {exc}") from None
    if top > 0.0 and calibration.camera_position is None:
        raise ConfigError(f"calibration: {cal_path} has no camera_position, which "
                          "markers.height_m needs (run formation calibrate again)")
    if calibration.camera_position is not None and top >= calibration.camera_position[2]:
        raise ConfigError(f"markers.height_m: {top} m is not below the camera "
                          f"({calibration.camera_position[2]:.3f} m)")
    return calibration


def load_config(path: str | Path) -> ServiceConfig:
    """Read and check ``CONFIG.yaml`` (:class:`ConfigError` naming the culprit)."""
    data = _read_yaml(path, "the camera config")
    return config_from_dict(data, Path(path).resolve().parent, str(path))


def floor_from_dict(data: Any) -> FloorMarkers:
    """A :class:`FloorMarkers` from parsed ``FLOOR.yaml``."""
    m = _mapping(data, "", FLOOR_KEYS)
    for key in ("size_m", "markers"):
        if key not in m:
            raise ConfigError(f"{key}: missing")
    dictionary = _dictionary(m.get("dictionary", "DICT_4X4_50"), "dictionary")
    size = _number(m["size_m"], "size_m", 0.0, 5.0, low_open=True)
    raw = m["markers"]
    if not isinstance(raw, dict) or not raw:
        raise ConfigError("markers: expected a mapping id -> [x, y]")
    n_ids = dictionary_size(dictionary)
    markers: dict[int, tuple[float, float]] = {}
    for mid, xy in raw.items():
        where = f"markers.{mid}"
        _marker_id(mid, where, n_ids)
        if not isinstance(xy, list | tuple) or len(xy) != 2:
            raise ConfigError(f"{where}: expected [x, y] in metres, got {xy!r}")
        markers[mid] = (_number(xy[0], f"{where}[0]"), _number(xy[1], f"{where}[1]"))
    return FloorMarkers(dictionary, size, markers)


def load_floor(path: str | Path) -> FloorMarkers:
    """Read and check ``FLOOR.yaml``."""
    return floor_from_dict(_read_yaml(path, "the floor markers"))
