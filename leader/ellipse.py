"""The formation ellipse: its formulas live in :mod:`geometry.ellipse` (re-exported here)."""

from geometry.ellipse import (  # noqa: F401
    Ellipse,
    Point,
    ReferenceShape,
    centroid,
    derive_axes,
    ellipse_terms,
    ellipse_value,
    estimate,
    reference_shape,
    wrap_angle,
)
