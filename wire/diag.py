"""The per-robot diagnostics key ``{prefix}/robot/{id}/diag``: agent -> viewers, at a low rate.

What a viewer of a real fleet needs beyond poses, states and ellipses: the robot's formation,
its last QP status and slack, its smallest barrier value of each kind, its goal and its
counters. It is for people, not for control: no agent subscribes to it, it is published at most
every :data:`DIAG_PERIOD_S` (wall clock), outside the traffic counters (the publisher is not a
:class:`wire.traffic.CountingPublisher`), so the communication-cost figures stay those of the
control traffic. :func:`wire.keys.key_class` files the key under ``other``.

Payload (``zenoh.ext.z_serialize`` layout, as :mod:`wire.payloads`)::

    u8 version, formation:str, status:str,
    f64 stamp, slack, h_formation, h_obstacle, h_formations, goal_x, goal_y,
    f64 ticks, stale, relaxed, fallback, dropped          (counts since the agent started)

The ``h_*`` and ``slack`` values may be non-finite (``inf``: no row of that kind this tick; NaN:
no QP ran), the others must be finite. Decoding is defensive like :mod:`wire.payloads`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import zenoh
from zenoh.ext import UInt8, z_serialize

from wire import keys
from wire.reader import WIRE_VERSION, DecodeError, Reader, as_bytes

DIAG = "diag"
DIAG_PERIOD_S = 0.25  # [s] at most 4 diagnostics a second per robot
MAX_DIAG_BYTES = 512
_MAY_BE_NONFINITE = frozenset(("slack", "h_formation", "h_obstacle", "h_formations"))


def diag_key(prefix: str, robot_id: str) -> str:
    """``{prefix}/robot/{robot_id}/diag``."""
    return f"{keys.validate_prefix(prefix)}/robot/{keys.validate_id(robot_id, 'robot_id')}/{DIAG}"


def all_diag_key(prefix: str) -> str:
    """``{prefix}/robot/*/diag``: every robot's diagnostics (viewers only)."""
    return f"{keys.validate_prefix(prefix)}/robot/*/{DIAG}"


@dataclass(frozen=True, slots=True)
class Diag:
    formation: str
    status: str
    stamp: float
    slack: float
    h_formation: float
    h_obstacle: float
    h_formations: float
    goal_x: float
    goal_y: float
    ticks: float
    stale: float
    relaxed: float
    fallback: float
    dropped: float

    def __post_init__(self) -> None:
        keys.validate_id(self.formation, "formation")
        if keys.id_problem(self.status) is not None:
            raise ValueError(f"status {self.status!r} is not a plain word")
        for name in FLOAT_FIELDS:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"{name} must be a number, got {type(v).__name__}")
            object.__setattr__(self, name, float(v))
            if name not in _MAY_BE_NONFINITE and not math.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v!r}")


FLOAT_FIELDS = ("stamp", "slack", "h_formation", "h_obstacle", "h_formations", "goal_x", "goal_y",
                "ticks", "stale", "relaxed", "fallback", "dropped")


def encode_diag(d: Diag) -> bytes:
    return z_serialize((UInt8(WIRE_VERSION), d.formation, d.status,
                        *(getattr(d, f) for f in FLOAT_FIELDS))).to_bytes()


def decode_diag(payload: object) -> Diag:
    """The :class:`Diag` in ``payload``; :class:`DecodeError` for anything else."""
    try:
        data = as_bytes(payload)
    except (TypeError, ValueError) as exc:
        raise DecodeError(f"diag: {exc}") from None
    if not data or len(data) > MAX_DIAG_BYTES:
        raise DecodeError(f"diag: payload of {len(data)} bytes")
    if data[0] != WIRE_VERSION:
        raise DecodeError(f"diag: unsupported version {data[0]}")
    r = Reader(data, 1)
    formation = r.string("diag.formation")
    status = r.string("diag.status")
    values = r.floats(4, "diag") + r.floats(4, "diag") + r.floats(4, "diag")
    r.end()
    try:
        return Diag(formation, status, *values)
    except ValueError as exc:
        raise DecodeError(f"diag: invalid message ({exc})") from None


class DiagPublisher:
    """An agent's diagnostics: :meth:`tick` after every control tick, a put at most every
    ``period`` seconds of wall time (uncounted: see the module docstring)."""

    def __init__(self, session: zenoh.Session, prefix: str, robot_id: str,
                 period: float = DIAG_PERIOD_S) -> None:
        self._pub = session.declare_publisher(diag_key(prefix, robot_id))
        self.period = period
        self._next = 0.0
        self.sent = 0

    def tick(self, node: Any, res: Any) -> None:
        """``node``: the agent (its counters, and its configuration ``cfg``, whose formation and
        goal each put names: a fleet robot's change with every regroup); ``res``: the tick's
        ``StepResult`` or ``None`` (a zero command: stale inputs, or no pose yet)."""
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + self.period
        nan = math.nan
        if res is None:
            status = "stale" if node.stale else "waiting"
            slack = hf = ho = he = nan
        else:
            status, slack = res.status, res.slack
            hf, ho, he = res.h_formation, res.h_obstacle, res.h_formations
        counts = node.status_counts
        dropped = node.dropped_malformed
        cfg = node.cfg
        goal_x, goal_y = cfg.goal
        d = Diag(cfg.formation, status or "ok", node.last_stamp, slack, hf, ho, he,
                 goal_x, goal_y, node.ticks, node.stale,
                 counts.get("relaxed", 0), counts.get("fallback", 0), dropped)
        self._pub.put(encode_diag(d))
        self.sent += 1

    def undeclare(self) -> None:
        self._pub.undeclare()
