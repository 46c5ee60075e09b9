"""The leader's part of a formation, pure (no clock, no network): its ellipse and others
(:mod:`leader.role`), whom it listens to (:mod:`leader.listen`), its successor
(:mod:`leader.succession`), and a route's life: the goal and the route handed to the members
(:mod:`leader.navigation`), when and why it is planned again (:mod:`leader.routing`, whose
docstring tells the whole life) and the one driver of that policy (:mod:`leader.route_driver`)."""
