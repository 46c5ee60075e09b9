"""Moving obstacles tracked from their markers: an alpha-beta filter per obstacle (pure).

Velocity is estimated over frames, not as a raw difference of two positions: an alpha-beta
filter (the steady-state Kalman filter of a constant-velocity model) predicts each obstacle to
the new frame's capture stamp and corrects position and velocity by fixed gains,

    x_pred = x + v dt,   r = z - x_pred,   x = x_pred + ALPHA r,   v = v + (BETA / dt) r.

``BETA`` follows from ``ALPHA`` by Kalata's relation for a constant-velocity target,
``beta = 2 (2 - alpha) - 4 sqrt(1 - alpha)``. With ``ALPHA = 0.5`` (``BETA = 0.172``) the
velocity noise is about ``0.2 sigma / dt``: 2 mm of position noise at 15 fps gives about
6 mm/s (a raw difference: 42 mm/s), and a constant velocity is followed with no steady lag.

An obstacle not seen in a frame stays in the output for up to ``hold_s`` seconds after it was
last seen, at its last position, with its last velocity, and its safe distance grown by its last
speed times the age (every place it could have reached); after that it is dropped and counted.
A track whose frames are more than ``hold_s`` apart restarts (velocity zero).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

ALPHA = 0.5  # position gain of the alpha-beta filter
BETA = 2.0 * (2.0 - ALPHA) - 4.0 * math.sqrt(1.0 - ALPHA)  # velocity gain (Kalata)


@dataclass(frozen=True)
class Track:
    """The filter state of one obstacle."""

    x: float  # [m] filtered position at ``stamp``
    y: float  # [m]
    vx: float  # [m/s]
    vy: float  # [m/s]
    stamp: float  # [s] capture stamp of the last frame it was seen in
    frames: int = 1  # frames it was seen in since the track (re)started

    @property
    def speed(self) -> float:
        return math.hypot(self.vx, self.vy)


def start_track(x: float, y: float, stamp: float) -> Track:
    """A new track at a first sighting (velocity unknown: zero)."""
    return Track(x, y, 0.0, 0.0, stamp)


def update_track(track: Track, x: float, y: float, stamp: float, hold_s: float,
                 alpha: float = ALPHA, beta: float = BETA) -> Track:
    """``track`` corrected by a sighting at ``(x, y)`` at ``stamp``. A sighting no later than
    the track's stamp, or more than ``hold_s`` after it, restarts the track."""
    dt = stamp - track.stamp
    if not (0.0 < dt <= hold_s):
        return start_track(x, y, stamp)
    if track.frames == 1:  # second sighting: the difference is the only estimate there is
        return Track(x, y, (x - track.x) / dt, (y - track.y) / dt, stamp, 2)
    px, py = track.x + track.vx * dt, track.y + track.vy * dt
    rx, ry = x - px, y - py
    return Track(px + alpha * rx, py + alpha * ry, track.vx + beta / dt * rx,
                 track.vy + beta / dt * ry, stamp, track.frames + 1)


def held_safe_distance(track: Track, safe_distance: float, now: float) -> float:
    """The safe distance [m] of an obstacle last seen at ``track.stamp``, at ``now``: grown by
    its last speed times the age."""
    return safe_distance + track.speed * max(0.0, now - track.stamp)


@dataclass(frozen=True)
class TrackedObstacle:
    """One obstacle as published: ``(name, x, y, vx, vy, ds)`` and its age [s]."""

    name: str
    x: float
    y: float
    vx: float
    vy: float
    ds: float
    age: float


class ObstacleTracker:
    """Tracks of every configured moving obstacle across frames."""

    def __init__(self, safe_distances: dict[str, float], hold_s: float) -> None:
        if not (math.isfinite(hold_s) and hold_s >= 0.0):
            raise ValueError(f"hold_s: must be >= 0 seconds, got {hold_s!r}")
        self.safe_distances = dict(safe_distances)
        self.hold_s = hold_s
        self.tracks: dict[str, Track] = {}
        self.dropped = 0  # tracks dropped after hold_s unseen
        self.held = 0  # obstacle-frames published from a held track

    def step(self, seen: dict[str, tuple[float, float]], stamp: float) -> list[TrackedObstacle]:
        """Update with the obstacles ``seen`` (name -> floor x, y) in the frame captured at
        ``stamp``; returns every obstacle to publish for that frame."""
        for name, (x, y) in seen.items():
            if name not in self.safe_distances:
                continue
            old = self.tracks.get(name)
            self.tracks[name] = (start_track(x, y, stamp) if old is None
                                 else update_track(old, x, y, stamp, self.hold_s))
        out = []
        for name in list(self.tracks):
            track = self.tracks[name]
            age = stamp - track.stamp
            if name not in seen and age > self.hold_s:
                del self.tracks[name]
                self.dropped += 1
                continue
            ds = self.safe_distances[name]
            if name not in seen:
                self.held += 1
                ds = held_safe_distance(track, ds, stamp)
            out.append(TrackedObstacle(name, track.x, track.y, track.vx, track.vy, ds,
                                       max(0.0, age)))
        return out
