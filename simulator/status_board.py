"""The newest ``status`` of every formation's leader, heard by the launcher during a run
(``formations_status`` of ``summary.json``)."""

from __future__ import annotations

import logging
import threading

import zenoh

from wire.navigation import decode_status
from wire.payloads import DecodeError

logger = logging.getLogger(__name__)


class StatusBoard:
    """The newest ``status`` of every formation's leader, heard on the launcher's session."""

    def __init__(self, session: zenoh.Session, prefix: str) -> None:
        self._lock = threading.Lock()
        self._latest: dict[str, dict] = {}
        self._goals: dict[str, dict] = {}  # formation -> the goal its leader follows
        self._sub = session.declare_subscriber(f"{prefix}/formation/*/status", self._on_status)

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            s = decode_status(sample.payload.to_bytes())
        except DecodeError:
            return
        with self._lock:
            self._latest[s.formation] = {
                "state": s.state, "goal": [s.gx, s.gy], "heading": s.heading,
                "distance_m": s.distance, "waypoint": s.waypoint, "waypoints": s.waypoints,
                "leader": s.leader, "stamp": s.stamp}
            self._goals[s.formation] = {"goal": [s.gx, s.gy], "heading": s.heading,
                                        "goal_stamp": s.goal_stamp}

    def latest(self) -> dict[str, dict]:
        with self._lock:
            return {k: dict(v) for k, v in sorted(self._latest.items())}

    def goals(self) -> dict[str, dict]:
        """The goal each formation's leader follows: ``goal`` centroid, ``heading`` and
        ``goal_stamp`` (0 for the scenario's), as :func:`simulator.goals.goals_sent` takes them."""
        with self._lock:
            return {k: dict(v) for k, v in sorted(self._goals.items())}

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # the session may be closing
            logger.debug("status board undeclare failed", exc_info=True)
