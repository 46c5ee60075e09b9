"""The margins a robot keeps for its declared sensing and motor bounds (``controller.bounds``).

Pure formulas, one copy each; :mod:`agent.control` grows its safe distances by them and
:mod:`agent.node` carries its pose forward by its measured age. The agent never reads the
world's profile: ``bounds`` (:class:`scenario.model.Bounds`) are what the robot's own config
declares, right or wrong (a run with bounds below what the world does shows what breaks:
README, "Promises on a real robot"). With every bound 0 each margin is exactly 0.0 and every
row is the one it always was.

What a barrier row of eq. 4.12 assumes, and what a lab robot does instead:

* the position p is the robot's true position. A camera measures it with noise (standard
  deviation ``pose_noise`` on each coordinate, ``heading_noise`` on the heading) and hands it
  over up to ``latency`` seconds after it was taken, while the robot moved on;
* p' = u, the certified command. A motor with a first-order lag of time constant
  ``motor_lag`` reaches a new command only gradually, so the robot overshoots where the row
  meant it to stop.

Each of these moves the true position a bounded distance from the one the row holds
(:func:`robot_margin`); a row that keeps the measured position that much further away keeps
the true one where the thesis's row would. A pair of robots, each measured with its own error,
keeps both ends' noise and their relative travel (:func:`pair_margin`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from scenario.model import Bounds

#: Noise is Gaussian (unbounded): the margin covers NOISE_SIGMAS standard deviations. A 2-D
#: Gaussian position error of sigma per coordinate lies within 3 sigma sqrt(2) of the truth
#: with probability 1 - exp(-9) = 0.99988 (its radius is Rayleigh distributed: [1]).
NOISE_SIGMAS = 3.0


def position_noise(b: Bounds) -> float:
    """[m] The radius a measured position lies within: NOISE_SIGMAS sqrt(2) pose_noise.

    [1] The distance of a 2-D Gaussian point (sigma on each axis, independent) from its mean
    is Rayleigh distributed (the chi distribution with two degrees of freedom):
    P(r > k sigma) = exp(-k^2 / 2); with k = NOISE_SIGMAS sqrt(2), exp(-9)."""
    return NOISE_SIGMAS * math.sqrt(2.0) * b.pose_noise


def heading_shift(b: Bounds, lookahead: float) -> float:
    """[m] How far a heading error moves a unicycle's look-ahead point s = b + l e(theta)
    (thesis eq. 6.2): |l (e(theta + d) - e(theta))| = 2 l sin(|d| / 2) <= l |d|, with
    |d| <= NOISE_SIGMAS heading_noise. Single integrators (l = 0): 0."""
    return lookahead * NOISE_SIGMAS * b.heading_noise


def travel(b: Bounds, vmax: float) -> float:
    """[m] How far the true position can be from the one a row acts on, beyond the noise:
    vmax (latency + motor_lag).

    * latency: a pose ``latency`` seconds old was taken that long before the robot acts; at
      speed at most vmax it has moved at most vmax latency since (the part the agent carries
      forward by the measured age, :func:`carried_age`, is still counted: a camera that stamps
      on publication, as the simulated lab's does, hides the age, and the command it is carried
      under is not the motion the motor made);
    * motor_lag: a first-order lag v' = (u - v) / tau trails a command step from v0 to u by
      (v0 - u) tau of distance in all (the integral of (v0 - u) exp(-t / tau)); the overshoot
      towards a hazard the row meant to stop at is at most v0 tau <= vmax tau (a command
      reversing to -vmax stops the motion towards it sooner, not later)."""
    return vmax * (b.latency + b.motor_lag)


def robot_margin(b: Bounds, vmax: float, lookahead: float) -> float:
    """[m] The distance between a robot's true control point and the one its rows act on, at
    most: :func:`position_noise` + :func:`heading_shift` + :func:`travel` (the sum of the
    bounds of the three independent errors, by the triangle inequality). An obstacle's or a
    shelf's safe distance grows by this much (the map's obstacles are exact)."""
    return position_noise(b) + heading_shift(b, lookahead) + travel(b, vmax)


def pair_margin(b: Bounds, rel_speed: float, lookahead: float) -> float:
    """[m] Two robots with the same bounds, each measured with its own error, moving at
    ``rel_speed`` relative to each other: 2 (position_noise + heading_shift) +
    rel_speed (latency + motor_lag).

    The noise is each end's own (triangle inequality on both ends). Both are seen in the same
    camera frame, so the latency and the lag shift the pair's distance only by their RELATIVE
    motion over that time; ``rel_speed`` is |u_i - u_j| of the two last certified velocities
    (the ones the separation row itself splits its slack by, the same numbers on both robots,
    so both keep the same distance). Members moving together keep little more than the noise;
    a pair closing at 2 vmax keeps 2 vmax (latency + motor_lag) more. A change of command
    within one tick is what the row's own class-K term covers, as in the ideal world. Separation
    rows, another formation's ellipse (estimated from its members' states, with its velocity)
    and the all-to-all pairwise rows grow by this much; a formation edge's band narrows by it
    (at most half of epsilon in all: :mod:`agent.control`)."""
    return 2.0 * (position_noise(b) + heading_shift(b, lookahead)) \
        + rel_speed * (b.latency + b.motor_lag)


def moving_obstacle_margin(b: Bounds, speed: float) -> float:
    """[m] What a moving obstacle seen through the same camera adds: its position noise and
    its travel during the latency, position_noise + speed latency. A static one (speed 0) is
    the map's: 0."""
    if speed <= 0.0:
        return 0.0
    return position_noise(b) + speed * b.latency


def grown_axes(a: float, b: float, margin: float) -> tuple[float, float]:
    """The semi-axes of an ellipse that contains every point within ``margin`` of the ellipse
    with semi-axes (a, b): both scaled by (m + margin) / m, m = min(a, b).

    A convex set contains another iff its support function is at least the other's in every
    direction. The margin's set (the Minkowski sum with a disc) has support h(n) + margin; the
    ellipse's support h(n) = sqrt(a^2 n_x^2 + b^2 n_y^2) is at least m, so the scaled ellipse's
    k h(n) = h(n) + (k - 1) h(n) >= h(n) + margin for k = 1 + margin / m. (Adding the margin to
    both axes falls short where a != b: its support is below h + margin off the axes.)"""
    if margin <= 0.0:
        return a, b
    k = 1.0 + margin / min(a, b)
    return a * k, b * k


def carried_age(age: float, latency: float) -> float:
    """[s] How far a pose is carried forward: its measured age (the agent's clock minus the
    pose's stamp) within [0, latency]. A negative age (a clock ahead of the agent's) carries
    nothing; an age beyond the declared latency is not trusted beyond it."""
    return min(max(age, 0.0), latency)


# --- localisation: margins from the agent's own estimate (controller.localisation: fused) ---

#: [m] past this confidence radius (the 95 % radius of :func:`agent.localisation.confidence_radius`
#: plus the correction still to come) a robot stops and counts it, as with stale data
RADIUS_LIMIT = 0.25
#: [m] margins from the estimate are rounded up to this step (one controller per step)
RADIUS_STEP = 0.005


def estimate_margin(own: float, other: float) -> float:
    """[m] How far a barrier on estimates keeps the estimated positions beyond the true ones'
    need: for a pair, the sum of the two robots' confidence radii (own + other); for a map's
    obstacle, the robot's own.

    A pair barrier h(p_i, p_j) >= 0 holds for the true positions with the chosen confidence
    when it holds for the estimates with the distance grown by both ends' confidence radii
    (triangle inequality: each true position lies within its radius of its estimate): the
    chance-constrained barrier turned into a deterministic one on the estimates, as in Luo, Sun
    and Kapoor, "Multi-robot collision avoidance under uncertainty with probabilistic safety
    barrier certificates", NeurIPS 2020 (arXiv:1912.09957), for localisation errors of bounded
    support. ``other`` is the largest radius among the robots this one hears (their ``state``)."""
    return own + other


def heard_radius(own: float, members: Iterable[float | None],
                 formations: Iterable[float | None]) -> float:
    """[m] The ``other`` radius of :func:`estimate_margin` for a robot of radius ``own``: the
    largest of its own, its formation's members' (the ``sigma`` of the states it hears) and
    the formations' (the ``sigma`` on each ellipse of its ``others`` view this tick: its own
    formation's and those of the other formations in view, :data:`leader.role.VIEW_RANGE`; a
    formation farther away is in no row). None: a sender on the camera's poses. One rule for the
    agent (:mod:`agent.odom_in`) and the in-process simulator (:mod:`simulator.fused`), which
    computes the same radii from the same view."""
    out = own
    for r in (*members, *formations):
        if r is not None and r > out:
            out = r
    return out


def margin_steps(own: float, other: float) -> int:
    """The pose-noise growth of :func:`localisation_bounds` in RADIUS_STEPs: (own + max(own,
    other)) / 2 rounded up. Bounds with the same steps are the same bounds (a cache of
    controllers is keyed by it)."""
    half = 0.5 * (own + max(own, other))
    return max(0, math.ceil(half / RADIUS_STEP - 1e-9))


def localisation_bounds(b: Bounds, own: float, other: float) -> Bounds:
    """The declared bounds ``b`` with the pose noise grown so that every margin the controller
    keeps (:func:`robot_margin`, :func:`pair_margin`) holds the estimate's too: position_noise
    grows by m = (own + max(own, other)) / 2, rounded up to RADIUS_STEP (:func:`margin_steps`).
    A pair then keeps 2 m >= :func:`estimate_margin` more (both ends' radii), an obstacle
    m >= own, and a formation edge's band narrows by the pair's (its cap applies:
    :mod:`agent.control`)."""
    m = margin_steps(own, other) * RADIUS_STEP
    if m <= 0.0:
        return b
    return Bounds(pose_noise=b.pose_noise + m / (NOISE_SIGMAS * math.sqrt(2.0)),
                  heading_noise=b.heading_noise, latency=b.latency, motor_lag=b.motor_lag)
