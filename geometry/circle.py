"""The distance barrier of a disk (thesis eq. 4.5; eq. 3.5 is the same form between robots)."""

from __future__ import annotations


def circle_h(px: float, py: float, cx: float, cy: float, radius: float) -> float:
    """h = |p - c|^2 - r^2 of eq. 4.5: negative inside the disk, zero on it, positive outside."""
    dx, dy = px - cx, py - cy
    return dx * dx + dy * dy - radius * radius
