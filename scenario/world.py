"""The scenario's ``world:`` section: what the simulated robots and camera are like.

``world: {profile: ideal}`` (the default, also when the section is missing) is the world every
result before it came from: a robot's velocity is its command at once and every pose is exact.
``world: {profile: turtlebot3-lab}`` is a lab of TurtleBot3 burgers under an overhead camera:
each robot a differential drive whose wheels have a speed limit, an acceleration limit and a
first-order lag, and a camera that sees every pose (and every moving obstacle) late, with noise,
at its own frame rate, dropping frames now and then. Any number of a profile may be overridden
in the same mapping (``world: {profile: turtlebot3-lab, drop_rate: 0.1}``); each is range-checked
here, and the whole section parses to one frozen :class:`WorldSpec`. docs/scenarios.md cites
where the profile's numbers come from; :mod:`simulator.lab` is the model that uses them.

Two more keys are allowed with either profile: ``odometry`` (each robot's wheel odometry errors,
:class:`Odometry`; exact in the ideal world unless given) and ``camera_blind`` (boxes of floor
where the camera sees no robot, :class:`BlindBox`). Neither changes what a run with
``controller.localisation: camera`` writes, except that a robot inside a blind box gets no pose.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .fields import within
from .limits import Range
from .reader import ScenarioError, excerpt

IDEAL = "ideal"
TURTLEBOT3_LAB = "turtlebot3-lab"
INF = math.inf
MAX_BLIND = 64  # camera_blind boxes a world may have


@dataclass(frozen=True)
class Odometry:
    """Each robot's wheel odometry errors: the bounds its own systematic errors are drawn from
    (uniformly in [-bound, bound], per robot, from the world's seed: :mod:`simulator.odometry`).

    ``scale_error``: the relative error of the distance each wheel reports (a tyre radius off by
    1 % is 0.01); ``heading_drift_rad_per_m``: the heading error gathered per metre driven (a
    wheel separation off, unequal tyres)."""

    scale_error: float = 0.0
    heading_drift_rad_per_m: float = 0.0

    @property
    def exact(self) -> bool:
        return self.scale_error == 0.0 and self.heading_drift_rad_per_m == 0.0


@dataclass(frozen=True)
class BlindBox:
    """A box of floor (centre, size along its own axes, yaw) where the camera sees no robot."""

    center: tuple[float, float]
    size: tuple[float, float]
    yaw: float = 0.0

    def contains(self, x: float, y: float) -> bool:
        """Whether the point (x, y) lies inside the box (edges included)."""
        dx, dy = x - self.center[0], y - self.center[1]
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        u, v = c * dx + s * dy, -s * dx + c * dy
        return abs(u) <= 0.5 * self.size[0] and abs(v) <= 0.5 * self.size[1]


#: camera faults a scenario may inject: every pose lost (``outage``), a robot's marker read as
#: another robot's pose (``misread``), a robot's pose forged ``offset`` metres off (``forged``)
CAMERA_FAULTS = ("outage", "misread", "forged")


@dataclass(frozen=True)
class CameraFault:
    """One camera fault of ``world.camera_faults`` from ``start`` for ``duration`` seconds."""

    kind: str
    start: float
    duration: float
    robot: str = ""  # misread, forged: the robot whose pose is wrong (outage: every robot)
    other: str = ""  # misread: the robot whose pose it gets instead
    offset: tuple[float, float] = (0.0, 0.0)  # forged: [m] added to the true position

    def active(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration


def blind_at(boxes: tuple[BlindBox, ...], x: float, y: float) -> bool:
    """Whether the point (x, y) lies in any of ``boxes`` (the camera sees no robot there)."""
    return any(b.contains(x, y) for b in boxes)


@dataclass(frozen=True)
class WorldSpec:
    """One world profile with its numbers (``inf``/0: that imperfection is absent)."""

    profile: str = IDEAL
    # actuators: a differential drive (every robot is one in a lab world)
    wheel_radius: float = 0.033  # [m]
    track: float = 0.160  # [m] distance between the wheels
    max_wheel_speed: float = INF  # [m/s] each wheel's rim speed limit
    max_wheel_accel: float = INF  # [m/s^2] each wheel's rim acceleration limit
    motor_lag: float = 0.0  # [s] first-order time constant from command to wheel speed
    # sensing: an overhead camera
    camera_fps: float = INF  # [1/s] frames per second (inf: a pose every tick)
    camera_latency: float = 0.0  # [s] capture to publication
    pose_noise: float = 0.0  # [m] standard deviation of each position coordinate
    heading_noise: float = 0.0  # [rad] standard deviation of the heading
    drop_rate: float = 0.0  # probability that a frame is lost
    seed: int = 0  # of the noise and the drops
    odometry: Odometry = Odometry()  # each robot's wheel odometry errors (exact: none)
    camera_blind: tuple[BlindBox, ...] = ()  # floor the camera does not see
    camera_faults: tuple[CameraFault, ...] = ()  # injected camera faults

    @property
    def ideal(self) -> bool:
        """True for the ideal world (the kinematic path of every simulator, unchanged)."""
        return self.profile == IDEAL

    @property
    def senses(self) -> bool:
        """True when the camera is anything but exact and instant."""
        return (math.isfinite(self.camera_fps) or self.camera_latency > 0 or self.pose_noise > 0
                or self.heading_noise > 0 or self.drop_rate > 0)

    def summary(self) -> dict[str, Any]:
        """The profile and its numbers, for summary.json (``inf`` written as None); odometry
        and blind boxes are the localisation's (summary.json's ``localisation`` block)."""
        return {f.name: (None if isinstance(v := getattr(self, f.name), float)
                         and math.isinf(v) else v)
                for f in dataclasses.fields(self) if f.name not in _LOCALISATION_KEYS}


PROFILES: dict[str, WorldSpec] = {
    IDEAL: WorldSpec(),
    # TurtleBot3 burger with XL430-W250 wheels under a 30 fps overhead camera (docs/scenarios.md)
    TURTLEBOT3_LAB: WorldSpec(
        profile=TURTLEBOT3_LAB,
        wheel_radius=0.033,
        track=0.160,
        max_wheel_speed=round(61.0 * 2.0 * math.pi / 60.0 * 0.033, 4),  # 61 rev/min at 12 V
        max_wheel_accel=2.5,
        motor_lag=0.1,
        camera_fps=30.0,
        camera_latency=0.05,
        pose_noise=0.002,
        heading_noise=0.01,
        drop_rate=0.02,
        # labelled estimates for a TurtleBot3's wheel odometry (docs/scenarios.md): its tyres'
        # radius is known to about 1 %, and its heading (integrated from its IMU's gyro by the
        # firmware) drifts about 0.005 rad per metre driven
        odometry=Odometry(scale_error=0.01, heading_drift_rad_per_m=0.005),
    ),
}

#: name -> the range an override must fall in (the ideal world's ``inf`` is no number to set)
RANGES: dict[str, Range] = {
    "wheel_radius": Range(0.0, 1.0, "m", lo_open=True),
    "track": Range(0.0, 5.0, "m", lo_open=True),
    "max_wheel_speed": Range(0.0, 100.0, "m/s", lo_open=True),
    "max_wheel_accel": Range(0.0, 1000.0, "m/s^2", lo_open=True),
    "motor_lag": Range(0.0, 10.0, "s"),
    "camera_fps": Range(0.0, 10000.0, "1/s", lo_open=True),
    "camera_latency": Range(0.0, 10.0, "s"),
    "pose_noise": Range(0.0, 1.0, "m"),
    "heading_noise": Range(0.0, math.pi, "rad"),
    "drop_rate": Range(0.0, 0.9, ""),
}
ODOMETRY_RANGES: dict[str, Range] = {
    "scale_error": Range(0.0, 0.2, ""),
    "heading_drift_rad_per_m": Range(0.0, 0.5, "rad/m"),
}
BLIND_SIZE = Range(0.0, 1000.0, "m", lo_open=True)
BLIND_CENTER = Range(-1e6, 1e6, "m")
BLIND_YAW = Range(-2.0 * math.pi, 2.0 * math.pi, "rad")
_LOCALISATION_KEYS = {"odometry", "camera_blind", "camera_faults"}
FAULT_TIME = Range(0.0, 1e6, "s")
FAULT_OFFSET = Range(-100.0, 100.0, "m")
_KEYS = {"profile", "seed", *RANGES, *_LOCALISATION_KEYS}
MAX_SEED = 2**63 - 1


def parse_world(raw: Any, where: str = "world") -> WorldSpec:
    """The ``world:`` section (a mapping, or None for the default) as a :class:`WorldSpec`."""
    if raw is None:
        return PROFILES[IDEAL]
    if not isinstance(raw, Mapping):
        raise ScenarioError(f"{where}: must be a mapping (profile: {' | '.join(PROFILES)}, ...)")
    unknown = sorted(str(k) for k in raw if k not in _KEYS)
    if unknown:
        raise ScenarioError(f"{where}: unknown key {excerpt(unknown[0])} "
                            f"(known: {', '.join(sorted(_KEYS))})")
    spec = profile(raw.get("profile", IDEAL), f"{where}.profile")
    changes: dict[str, Any] = {name: within(raw[name], f"{where}.{name}", rng)
                               for name, rng in RANGES.items() if name in raw}
    if "seed" in raw:
        changes["seed"] = _seed(raw["seed"], f"{where}.seed")
    if spec.ideal and any(k != "seed" for k in changes):
        raise ScenarioError(f"{where}: the ideal world has no {sorted(changes)[0]} "
                            f"(choose profile: {TURTLEBOT3_LAB} to set it)")
    if "odometry" in raw:
        changes["odometry"] = _odometry(raw["odometry"], f"{where}.odometry")
    if "camera_blind" in raw:
        changes["camera_blind"] = _blind(raw["camera_blind"], f"{where}.camera_blind")
    if "camera_faults" in raw:
        changes["camera_faults"] = _faults(raw["camera_faults"], f"{where}.camera_faults")
    return dataclasses.replace(spec, **changes)


def _faults(raw: Any, where: str) -> tuple[CameraFault, ...]:
    """``world.camera_faults``: a list of ``{kind, start, duration, robot, other, offset}``
    (robot names are checked against the formations by :func:`check_fault_robots`)."""
    if not isinstance(raw, list | tuple) or len(raw) > MAX_BLIND:
        raise ScenarioError(f"{where}: must be a list of at most {MAX_BLIND} faults")
    return tuple(_fault(item, f"{where}[{k}]") for k, item in enumerate(raw))


def _fault(raw: Any, where: str) -> CameraFault:
    known = ("kind", "start", "duration", "robot", "other", "offset")
    if not isinstance(raw, Mapping):
        raise ScenarioError(f"{where}: must be a mapping ({', '.join(known)})")
    unknown = sorted(str(k) for k in raw if k not in known)
    if unknown:
        raise ScenarioError(f"{where}: unknown key {excerpt(unknown[0])} (known: {', '.join(known)})")
    kind = raw.get("kind")
    if kind not in CAMERA_FAULTS:
        raise ScenarioError(f"{where}.kind: {excerpt(kind)} is not one of {CAMERA_FAULTS}")
    robot, other = raw.get("robot", ""), raw.get("other", "")
    if not isinstance(robot, str) or not isinstance(other, str):
        raise ScenarioError(f"{where}: robot and other must be robot names")
    if kind != "outage" and not robot:
        raise ScenarioError(f"{where}.robot: a {kind} fault names the robot it hits")
    if kind == "misread" and not other:
        raise ScenarioError(f"{where}.other: a misread fault names the robot whose pose it reads")
    offset = _pair(raw.get("offset", [0.0, 0.0]), f"{where}.offset", FAULT_OFFSET)
    return CameraFault(kind, within(raw.get("start"), f"{where}.start", FAULT_TIME),
                       within(raw.get("duration"), f"{where}.duration", FAULT_TIME),
                       robot, other, offset)


def check_fault_robots(spec: WorldSpec, robots: tuple[str, ...]) -> None:
    """Every robot a camera fault names is one of ``robots`` (ScenarioError naming it)."""
    for k, f in enumerate(spec.camera_faults):
        for key, name in (("robot", f.robot), ("other", f.other)):
            if name and name not in robots:
                raise ScenarioError(f"world.camera_faults[{k}].{key}: no robot {excerpt(name)}")


def _odometry(raw: Any, where: str) -> Odometry:
    """``world.odometry``: a mapping of the two bounds (a missing one is 0)."""
    if not isinstance(raw, Mapping):
        raise ScenarioError(f"{where}: must be a mapping (scale_error, heading_drift_rad_per_m)")
    unknown = sorted(str(k) for k in raw if k not in ODOMETRY_RANGES)
    if unknown:
        raise ScenarioError(f"{where}: unknown key {excerpt(unknown[0])} "
                            f"(known: {', '.join(ODOMETRY_RANGES)})")
    return Odometry(**{k: within(raw.get(k, 0.0), f"{where}.{k}", r)
                       for k, r in ODOMETRY_RANGES.items()})


def _blind(raw: Any, where: str) -> tuple[BlindBox, ...]:
    """``world.camera_blind``: a list of ``{box: {center: [x, y], size: [w, h], yaw}}``."""
    if not isinstance(raw, list | tuple):
        raise ScenarioError(f"{where}: must be a list of {{box: {{center, size, yaw}}}}")
    if len(raw) > MAX_BLIND:
        raise ScenarioError(f"{where}: {len(raw)} boxes, more than the {MAX_BLIND} allowed")
    return tuple(_box(item, f"{where}[{k}]") for k, item in enumerate(raw))


def _box(raw: Any, where: str) -> BlindBox:
    if not isinstance(raw, Mapping) or set(raw) != {"box"} or not isinstance(raw["box"], Mapping):
        raise ScenarioError(f"{where}: must be {{box: {{center: [x, y], size: [w, h], yaw}}}}, "
                            f"got {excerpt(raw)}")
    box = raw["box"]
    unknown = sorted(str(k) for k in box if k not in ("center", "size", "yaw"))
    if unknown:
        raise ScenarioError(f"{where}.box: unknown key {excerpt(unknown[0])} "
                            f"(known: center, size, yaw)")
    center = _pair(box.get("center"), f"{where}.box.center", BLIND_CENTER)
    size = _pair(box.get("size"), f"{where}.box.size", BLIND_SIZE)
    yaw = within(box.get("yaw", 0.0), f"{where}.box.yaw", BLIND_YAW)
    return BlindBox(center, size, yaw)


def _pair(raw: Any, where: str, allowed: Range) -> tuple[float, float]:
    if not isinstance(raw, list | tuple) or len(raw) != 2:
        raise ScenarioError(f"{where}: must be a list of 2 numbers, got {excerpt(raw)}")
    return (within(raw[0], f"{where}[0]", allowed), within(raw[1], f"{where}[1]", allowed))


def profile(name: Any, where: str = "--world") -> WorldSpec:
    """The named profile's numbers; a clear error naming ``where`` for an unknown name."""
    if not isinstance(name, str) or name not in PROFILES:
        raise ScenarioError(f"{where}: unknown world profile {excerpt(name)} "
                            f"(known: {', '.join(PROFILES)})")
    return PROFILES[name]


def with_profile(spec: WorldSpec, name: str) -> WorldSpec:
    """``--world NAME`` over a scenario's section: the named profile, keeping the section's
    own numbers where it chose the same profile (and its seed in any case)."""
    chosen = profile(name)
    if chosen.profile == spec.profile:
        return spec
    own = spec.odometry != PROFILES[spec.profile].odometry  # the section's own numbers
    return dataclasses.replace(chosen, seed=spec.seed, camera_blind=spec.camera_blind,
                               camera_faults=spec.camera_faults,
                               odometry=spec.odometry if own else chosen.odometry)


def _seed(raw: Any, where: str) -> int:
    if isinstance(raw, bool) or not isinstance(raw, int) or not 0 <= raw <= MAX_SEED:
        raise ScenarioError(f"{where}: must be an integer from 0 to 2^63-1, got {excerpt(raw)}")
    return raw


def describe() -> str:
    """The ranges as Markdown rows (docs/scenarios.md)."""
    return "\n".join(f"| world.{k} | {r.text()} |" for k, r in RANGES.items())
