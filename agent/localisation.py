"""A robot's own estimate of its pose: an extended Kalman filter over its wheel odometry and the
ceiling camera's poses (``controller.localisation: fused``). numpy only: it runs on the robot.

The state is the body pose (x, y, theta) with its covariance P (3 x 3).

* **Prediction** (:func:`predict`): each odometry increment (dx, dy, dtheta in the body frame
  at the start of the increment, as the wheels measured it) moves the pose; P grows through the
  motion's Jacobian and by a process noise that grows with the distance driven
  (:func:`process_noise`). The odometry's errors are systematic (a tyre's radius, the wheel
  separation): their effect grows with the distance, not with its square root, so the noise per
  metre is sized for a stretch of :attr:`FilterTuning.stretch` metres: over that stretch the
  95 % radius of each error alone equals the bound's whole error (shorter stretches are
  covered more than that, longer ones less: past it the physical bound of the gate still holds).
* **Camera poses** arrive late: each is fused at its capture stamp (:meth:`Localiser.camera`).
  The filter keeps the last :attr:`FilterTuning.history` odometry steps with the pose and
  covariance after each; a camera pose updates the step it was captured in
  (:func:`update`, Joseph form: P stays symmetric positive semi-definite) and the later
  increments are applied again on top of it.
* **Outlier gate** (:func:`accept`): a pose is fused only if its Mahalanobis distance is within
  the chi-square bound for 3 degrees of freedom (:data:`GATE_CHI2`) AND its position lies within
  the physical bound of what the odometry can have gathered since the last fused pose
  (:attr:`Localiser.drift_bound`): after a long blind stretch P is large and the chi-square
  gate alone would let a forged pose 0.5 m off pull the estimate; the physical bound does not.
  A rejected pose is counted.
* **Disputed** (:attr:`Localiser.disputed`, counted): once the gate has refused every pose for
  :attr:`FilterTuning.hold_after` seconds, the estimate and the camera disagree (a forger, or
  odometry worse than assumed). The robot drives on its odometry meanwhile, as when blind, its
  radius growing with the distance. It takes a pose again when the last
  :attr:`FilterTuning.agree` refused poses were off the estimate by the same offset (within
  :attr:`FilterTuning.agree_m`) and this one lies within :attr:`FilterTuning.lost_factor` times
  the physical bound (odometry up to that much worse than assumed); the covariance grows by the
  jump first, so the estimate follows (counted, ``relocalised``). A pose beyond even that stays
  refused: the radius keeps growing until the robot stops at the margins' limit.
* **No jump** when the camera returns: the filter's own state takes each update whole, but the
  pose it hands the controller moves towards it at most :attr:`FilterTuning.max_correction`
  metres (and :attr:`FilterTuning.max_turn_correction` radians) per second; the remaining
  offset is added to the confidence radius the margins use (:meth:`Localiser.estimate`).
* A robot that starts unseen has no estimate (:meth:`Localiser.estimate` is None) until its
  first camera pose: it waits.

References: the EKF and the Joseph form: Thrun, Burgard and Fox, "Probabilistic Robotics"
(2005), ch. 3.3 and 7.4; delayed measurements fused by re-applying the stored inputs: Larsen,
Andersen, Ravn and Poulsen, "Incorporation of time delayed measurements in a discrete-time
Kalman filter", IEEE CDC 1998; the gate: Bar-Shalom, Li and Kirubarajan, "Estimation with
Applications to Tracking and Navigation" (2001), section 5.4 (validation gate).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

Pose = tuple[float, float, float]
Increment = tuple[float, float, float]  # dx, dy [m] in the body frame, dtheta [rad]

#: chi-square quantile, 3 degrees of freedom, 0.999: a true pose is rejected once in 1,000
GATE_CHI2 = 16.27
#: chi-square quantile, 2 degrees of freedom, 0.95: the 95 % confidence ellipse
CONF95_CHI2 = 5.991


@dataclass(frozen=True)
class FilterTuning:
    """The filter's numbers: what the robot assumes of its odometry and camera.

    The odometry bounds are labelled estimates for a TurtleBot3 (the lab profile's,
    :data:`scenario.world.PROFILES`); the camera's are a few times the lab camera's noise."""

    scale_error: float = 0.01  # relative error of the distance driven (bound)
    heading_drift: float = 0.005  # [rad/m] heading error per metre driven (bound)
    stretch: float = 4.0  # [m] the blind stretch the noise per metre is sized for
    floor: float = 1e-10  # [m^2, rad^2] process noise per step even at rest
    camera_sigma: float = 0.005  # [m] standard deviation of a camera position coordinate
    camera_heading_sigma: float = 0.02  # [rad]
    initial_sigma: float = 0.01  # [m] of the first fused pose (and its heading, x 2 rad/m)
    error_floor: float = 0.05  # [m] physical bound's floor (camera noise, latency, a slip)
    max_correction: float = 0.05  # [m/s] the handed pose's correction rate
    max_turn_correction: float = 0.2  # [rad/s]
    history: int = 200  # odometry steps kept for late camera poses
    hold_after: float = 0.25  # [s] of refused poses before the filter counts itself disputed
    agree: int = 5  # refused poses whose offsets must agree before one is taken while disputed
    agree_m: float = 0.05  # [m] how closely their offsets agree
    lost_factor: float = 3.0  # the physical bound's factor a disputed robot accepts within


TUNING = FilterTuning()


def wrap(a: float) -> float:
    """An angle in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


def motion(x: np.ndarray, inc: Increment) -> tuple[np.ndarray, np.ndarray]:
    """The pose after the body-frame increment ``inc`` and the motion's Jacobian F = df/dx."""
    c, s = math.cos(x[2]), math.sin(x[2])
    dx, dy, dth = inc
    out = np.array([x[0] + c * dx - s * dy, x[1] + s * dx + c * dy, wrap(x[2] + dth)])
    f = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
    return out, f


def process_noise(theta: float, inc: Increment, t: FilterTuning = TUNING) -> np.ndarray:
    """The covariance one odometry increment adds (world frame): along the motion
    scale_error^2 stretch d / c, across it the same, on the heading heading_drift^2 stretch d / c
    plus (scale_error dtheta)^2 for a turn, with d the distance driven, c = CONF95_CHI2 (a
    random walk's 95 % radius over ``stretch`` is then the bound's error over it) and a small
    floor."""
    dx, dy, dth = inc
    d = math.hypot(dx, dy)
    q_pos = t.scale_error ** 2 * t.stretch * d / CONF95_CHI2 + t.floor
    q_th = (t.heading_drift ** 2 * t.stretch * d / CONF95_CHI2 + (t.scale_error * dth) ** 2
            + t.floor)
    c, s = math.cos(theta), math.sin(theta)
    rot = np.array([[c, -s], [s, c]])
    q = np.zeros((3, 3))
    q[:2, :2] = rot @ np.diag([q_pos, q_pos]) @ rot.T
    q[2, 2] = q_th
    return q


def predict(x: np.ndarray, p: np.ndarray, inc: Increment, t: FilterTuning = TUNING
            ) -> tuple[np.ndarray, np.ndarray]:
    """EKF prediction over one odometry increment: (x', F P F^T + Q)."""
    out, f = motion(x, inc)
    q = process_noise(float(x[2]), inc, t)
    pn = f @ p @ f.T + q
    return out, 0.5 * (pn + pn.T)


def camera_noise(t: FilterTuning = TUNING) -> np.ndarray:
    """R: the camera pose's covariance."""
    return np.diag([t.camera_sigma ** 2, t.camera_sigma ** 2, t.camera_heading_sigma ** 2])


def innovation(x: np.ndarray, p: np.ndarray, z: Pose, r: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, float]:
    """The innovation y = z - x (heading wrapped), its covariance S = P + R (H = I) and the
    squared Mahalanobis distance y^T S^-1 y."""
    y = np.array([z[0] - x[0], z[1] - x[1], wrap(z[2] - x[2])])
    s = p + r
    return y, s, float(y @ np.linalg.solve(s, y))


def update(x: np.ndarray, p: np.ndarray, z: Pose, r: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """EKF update with a full-pose measurement (H = I): K = P S^-1, x + K y, and the Joseph
    form (I - K) P (I - K)^T + K R K^T, symmetric positive semi-definite by construction."""
    y, s, _d2 = innovation(x, p, z, r)
    k = np.linalg.solve(s.T, p.T).T  # P S^-1 (S symmetric)
    out = x + k @ y
    out[2] = wrap(float(out[2]))
    i_k = np.eye(3) - k
    pn = i_k @ p @ i_k.T + k @ r @ k.T
    return out, 0.5 * (pn + pn.T)


def confidence_radius(p: np.ndarray) -> float:
    """[m] The radius of a circle holding the position with 95 % probability, at least:
    sqrt(chi2_2(0.95) lambda_max) of the position block (the 95 % ellipse's major semi-axis)."""
    lam = float(np.linalg.eigvalsh(p[:2, :2])[-1])
    return math.sqrt(CONF95_CHI2 * max(lam, 0.0))


def accept(d2: float, jump: float, bound: float) -> bool:
    """Whether a camera pose is fused: within the chi-square gate (``d2`` <= GATE_CHI2) AND its
    position ``jump`` from the estimate within the physical ``bound``."""
    return d2 <= GATE_CHI2 and jump <= bound


def step_towards(value: float, target: float, most: float) -> float:
    """``value`` moved towards ``target`` by at most ``most``."""
    return value + max(-most, min(most, target - value))


@dataclass
class Entry:
    """One odometry step as the filter keeps it: the stamp it ends at, the increment, and the
    pose and covariance after it."""

    stamp: float
    inc: Increment
    x: np.ndarray
    p: np.ndarray


class Localiser:
    """One robot's filter (see the module docstring). Feed it :meth:`odometry` every step and
    :meth:`camera` whenever a pose arrives; :meth:`estimate` is what the controller uses."""

    def __init__(self, tuning: FilterTuning = TUNING) -> None:
        self.t = tuning
        self.x: np.ndarray | None = None
        self.p = np.zeros((3, 3))
        self.history: deque[Entry] = deque(maxlen=tuning.history)
        self.handed: np.ndarray | None = None  # the pose handed to the controller
        self.travel = 0.0  # [m] driven since the last fused pose
        self.drift_bound = tuning.error_floor  # [m] the odometry's error since then, at most
        self.rejected = 0  # camera poses the gate refused
        self.fused = 0
        self.relocalised = 0  # disputed poses taken (see the module docstring)
        # the refused poses' offsets from the estimate (x, y), in a row
        self.refused: deque[tuple[float, float]] = deque(maxlen=tuning.agree)
        self.refused_since: float | None = None  # [s] the first of them's stamp
        self.last_refused = -math.inf  # [s] the latest one's stamp

    # --- inputs -------------------------------------------------------------------------

    def odometry(self, stamp: float, inc: Increment, dt: float) -> None:
        """One odometry increment ending at ``stamp``, measured over ``dt`` seconds."""
        if self.x is None:
            return
        self.x, self.p = predict(self.x, self.p, inc, self.t)
        self.history.append(Entry(stamp, inc, self.x.copy(), self.p.copy()))
        d = math.hypot(inc[0], inc[1])
        self.travel += d
        # the error a distance d adds at most: its scale error, and the heading error gathered
        # so far swinging it sideways (scale_error + heading_drift travel) d
        self.drift_bound += (self.t.scale_error + self.t.heading_drift * self.travel) * d
        self._hand_on(dt)

    def camera(self, stamp: float, z: Pose) -> bool:
        """A camera pose captured at ``stamp``: fused there (True), or refused by the gate and
        counted (False). The first one starts the filter."""
        if self.x is None:
            self._start(z)
            return True
        at = self._index_at(stamp)
        x, p = (self.history[at].x, self.history[at].p) if at >= 0 else (self.x, self.p)
        r = camera_noise(self.t)
        _y, _s, d2 = innovation(x, p, z, r)
        jump = math.hypot(z[0] - x[0], z[1] - x[1])
        offset = (z[0] - float(x[0]), z[1] - float(x[1]))
        if not accept(d2, jump, self.drift_bound):
            if not self._take_disputed(offset, jump):
                self._refuse(stamp, offset)
                return False
            p = p + np.diag([jump ** 2, jump ** 2, 0.0])  # the estimate follows the camera
            self.relocalised += 1
        self.refused.clear()
        self.refused_since = None
        x, p = update(x, p, z, r)
        self._replay(at, x, p)
        self.fused += 1
        self.travel = 0.0
        self.drift_bound = self.t.error_floor
        return True

    @property
    def disputed(self) -> bool:
        """Whether the gate has refused every pose for ``hold_after`` seconds (see the module
        docstring)."""
        since = self.refused_since
        return since is not None and self.last_refused - since >= self.t.hold_after

    # --- outputs ------------------------------------------------------------------------

    def estimate(self) -> tuple[Pose, float] | None:
        """The pose handed to the controller and its confidence radius [m] (the filter's 95 %
        radius plus the correction still to be made); None before the first camera pose."""
        if self.x is None or self.handed is None:
            return None
        offset = math.hypot(float(self.handed[0] - self.x[0]), float(self.handed[1] - self.x[1]))
        h = self.handed
        return (float(h[0]), float(h[1]), float(h[2])), confidence_radius(self.p) + offset

    # --- internals ----------------------------------------------------------------------

    def _start(self, z: Pose) -> None:
        sig = self.t.initial_sigma
        self.x = np.array([z[0], z[1], wrap(z[2])])
        self.p = np.diag([sig ** 2, sig ** 2, (2.0 * sig) ** 2])
        self.handed = self.x.copy()
        self.fused += 1

    def _refuse(self, stamp: float, offset: tuple[float, float]) -> None:
        self.rejected += 1
        self.refused.append(offset)
        self.last_refused = stamp
        if self.refused_since is None:
            self.refused_since = stamp

    def _take_disputed(self, offset: tuple[float, float], jump: float) -> bool:
        """While disputed: whether a pose ``offset`` off the estimate is taken (the refused
        poses were off by the same, and it lies within lost_factor times the physical bound)."""
        if not self.disputed or len(self.refused) < self.t.agree:
            return False
        if jump > self.t.lost_factor * self.drift_bound:
            return False
        return all(math.hypot(q[0] - offset[0], q[1] - offset[1]) <= self.t.agree_m
                   for q in self.refused)

    def _index_at(self, stamp: float) -> int:
        """The newest kept step that ended by ``stamp`` (-1: none; the pose is then fused on
        the present estimate, as when it is newer than every step)."""
        for k in range(len(self.history) - 1, -1, -1):
            if self.history[k].stamp <= stamp + 1e-9:
                return k
        return -1

    def _replay(self, at: int, x: np.ndarray, p: np.ndarray) -> None:
        """Step ``at`` updated to (x, p): every later increment applied again on top."""
        if at < 0 or at == len(self.history) - 1:
            if at >= 0:
                self.history[at].x, self.history[at].p = x.copy(), p.copy()
            self.x, self.p = x, p
            return
        self.history[at].x, self.history[at].p = x.copy(), p.copy()
        for k in range(at + 1, len(self.history)):
            e = self.history[k]
            x, p = predict(x, p, e.inc, self.t)
            e.x, e.p = x.copy(), p.copy()
        self.x, self.p = x, p

    def _hand_on(self, dt: float) -> None:
        """The handed pose follows the filter's with a bounded correction: it moves with the
        latest increment, and towards the filter's estimate by at most the correction rates."""
        assert self.x is not None
        if self.handed is None:
            self.handed = self.x.copy()
            return
        last = self.history[-1]
        moved, _f = motion(self.handed, last.inc)
        most, turn = self.t.max_correction * dt, self.t.max_turn_correction * dt
        out = np.array([step_towards(float(moved[0]), float(self.x[0]), most),
                        step_towards(float(moved[1]), float(self.x[1]), most),
                        0.0])
        dth = wrap(float(self.x[2]) - float(moved[2]))
        out[2] = wrap(float(moved[2]) + max(-turn, min(turn, dth)))
        self.handed = out
