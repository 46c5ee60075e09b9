"""Shared pure geometry: no clock, no network, no I/O.

* :mod:`geometry.shapes` - walls (segments) and shelves (boxes): distance, gradient, barrier
  value of eq. 4.5 generalised to a shape.
* :mod:`geometry.route` - a formation's route around the walls and boxes (visibility graph)
  and the waypoint tracking rule.
"""
