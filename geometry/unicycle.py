"""The control point of the near-identity diffeomorphism (thesis section 6.2, Fig. 6.2)."""

from __future__ import annotations

import math


def control_point(x: float, y: float, theta: float, lookahead: float) -> tuple[float, float]:
    """s(p, theta) = p + l (cos theta, sin theta) of Fig. 6.2 / eq. 6.2."""
    return (x + lookahead * math.cos(theta), y + lookahead * math.sin(theta))
