"""A uniform grid over the plane for the validator's neighbour queries (linear work in robots)."""

from __future__ import annotations

import math
from collections.abc import Iterator


class Grid:
    """Integer items at points, bucketed in square cells of side ``cell`` [m]."""

    def __init__(self, cell: float) -> None:
        if not (cell > 0.0 and math.isfinite(cell)):
            raise ValueError(f"cell: must be a positive number, got {cell!r}")
        self.cell = cell
        self.cells: dict[tuple[int, int], list[int]] = {}

    def _key(self, x: float, y: float) -> tuple[int, int]:
        return math.floor(x / self.cell), math.floor(y / self.cell)

    def add(self, item: int, x: float, y: float) -> None:
        self.cells.setdefault(self._key(x, y), []).append(item)

    def near(self, x: float, y: float) -> Iterator[int]:
        """Items of the 3 x 3 cells around (x, y): every item closer than ``cell`` is among them."""
        cx, cy = self._key(x, y)
        for i in (cx - 1, cx, cx + 1):
            for j in (cy - 1, cy, cy + 1):
                yield from self.cells.get((i, j), ())

    def in_box(self, x0: float, y0: float, x1: float, y1: float) -> Iterator[int]:
        """Items of every cell that meets the box [x0, x1] x [y0, y1] (a superset of the items
        inside it). Visits the fewer of the box's cells and the occupied cells."""
        i0, j0 = self._key(x0, y0)
        i1, j1 = self._key(x1, y1)
        if (i1 - i0 + 1) * (j1 - j0 + 1) <= len(self.cells):
            for i in range(i0, i1 + 1):
                for j in range(j0, j1 + 1):
                    yield from self.cells.get((i, j), ())
        else:
            for (i, j), items in self.cells.items():
                if i0 <= i <= i1 and j0 <= j <= j1:
                    yield from items
