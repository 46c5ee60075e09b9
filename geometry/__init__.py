"""Shared geometry and formulas of the thesis: one copy each, no clock, no network, no I/O.

The bottom layer of the project: :mod:`agent`, :mod:`leader`, :mod:`scenario` and
:mod:`simulator` import from here, and this package imports none of them.

* :mod:`geometry.unicycle` - the control point s(p, theta) of the near-identity
  diffeomorphism (thesis section 6.2, Fig. 6.2).
* :mod:`geometry.ellipse` - the formation ellipse: reference shape, semi-axes, the estimate
  of eq. 4.7 and the ellipse barrier h of eq. 4.6 with its derivatives.
* :mod:`geometry.circle` - the distance barrier of a disk (eq. 4.5, also eq. 3.5).
* :mod:`geometry.angles` - the angle wraps: to [-pi, pi), the left-biased one for turns of
  nearly half a turn, and the nearest of forwards and backwards.
* :mod:`geometry.speed_polygon` - the speed disk as the regular polygon inscribed in it.
* :mod:`geometry.slack` - the smallest common slack that makes a QP's rows feasible (bisection).
* :mod:`geometry.limits` - the TurtleBot3 burger's speed and turn-rate limits.
* :mod:`geometry.shapes` - walls (segments) and shelves (boxes): distance, gradient, barrier
  value of eq. 4.5 generalised to a shape.
* :mod:`geometry.route` - a formation's route around the walls and boxes (visibility graph)
  and the waypoint tracking rule.
"""
