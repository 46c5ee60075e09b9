"""Walls and shelves between :class:`geometry.shapes.Shape` and the wire's :class:`ShapeMsg`."""

from __future__ import annotations

from geometry.shapes import BOX, SEGMENT, Shape

from .payloads import SHAPE_BOX, SHAPE_SEGMENT, ShapeMsg

_KIND_TO_WIRE = {SEGMENT: SHAPE_SEGMENT, BOX: SHAPE_BOX}
_WIRE_TO_KIND = {v: k for k, v in _KIND_TO_WIRE.items()}


def shape_to_msg(sh: Shape) -> ShapeMsg:
    return ShapeMsg(sh.name, _KIND_TO_WIRE[sh.kind], float(sh.cx), float(sh.cy), float(sh.hx),
                    float(sh.hy), float(sh.yaw), float(sh.ds))


def msg_to_shape(m: ShapeMsg) -> Shape:
    return Shape(m.id, _WIRE_TO_KIND[m.kind], m.cx, m.cy, m.hx, m.hy, m.yaw, m.ds)
