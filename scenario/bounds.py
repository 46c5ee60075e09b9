"""``--bounds SPEC``: the controller's declared bounds (``controller.bounds``) from the command line.

A robot's controller keeps margins for the bounds its own config declares
(:class:`scenario.model.Bounds`, :mod:`agent.margins`); it never reads the world. For
experiments, ``formation sim``, ``run`` and ``montecarlo`` take ``--bounds SPEC`` in place of
the file's ``controller.bounds``:

* a world profile's name (``turtlebot3-lab``, ``ideal``): the bounds that match that profile
  (:func:`matching`): what a scenario's author would write for a robot in that lab;
* ``key=value,...`` (``pose_noise=0.001,latency=0.02``): those bounds, the others 0, e.g. bounds
  smaller than what the world does, to see what breaks.
"""

from __future__ import annotations

import dataclasses
import math

from . import limits
from .model import Bounds, Scenario
from .reader import ScenarioError, excerpt
from .world import PROFILES, WorldSpec

#: Frames a matching latency counts beyond the camera's latency: the newest frame is up to one
#: frame period older than the camera's latency, and one more when a frame was lost.
FRAMES_BEHIND = 2


def matching(spec: WorldSpec, dt: float) -> Bounds:
    """The bounds that match the world ``spec`` for a control period ``dt``: its noise as it
    is, its motor lag, and a latency of the camera's latency plus FRAMES_BEHIND frame periods
    (a frame every ``dt`` when the camera's rate is unbounded). The ideal world: all 0."""
    if spec.ideal:
        return Bounds()
    period = 1.0 / spec.camera_fps if math.isfinite(spec.camera_fps) else dt
    latency = spec.camera_latency + FRAMES_BEHIND * period if spec.senses else 0.0
    return Bounds(pose_noise=spec.pose_noise, heading_noise=spec.heading_noise,
                  latency=min(latency, limits.BOUNDS["latency"].hi), motor_lag=spec.motor_lag)


def parse(text: str, dt: float) -> Bounds:
    """``--bounds SPEC`` (module docstring) as bounds; ScenarioError naming the culprit."""
    if text in PROFILES:
        return matching(PROFILES[text], dt)
    values: dict[str, float] = {}
    for item in text.split(","):
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or key not in limits.BOUNDS:
            raise ScenarioError(
                f"--bounds: {excerpt(item)} is neither a world profile ({', '.join(PROFILES)}) "
                f"nor NAME=VALUE with NAME one of {', '.join(limits.BOUNDS)}")
        values[key] = _number(raw, key)
    return Bounds(**values)


def _number(raw: str, key: str) -> float:
    try:
        number = float(raw)
    except ValueError:
        raise ScenarioError(f"--bounds {key}: must be a number, got {excerpt(raw)}") from None
    try:
        return limits.check(number, f"--bounds {key}", limits.BOUNDS[key])
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None


def with_bounds(scenario: Scenario, text: str | None) -> Scenario:
    """``scenario`` with the bounds ``--bounds TEXT`` declares (None: as its file says)."""
    if text is None:
        return scenario
    bounds = parse(text, scenario.dt)
    return dataclasses.replace(scenario,
                               controller=dataclasses.replace(scenario.controller, bounds=bounds))
