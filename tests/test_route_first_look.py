"""Which circles a formation's leader plans round at once: those standing still when it first
looks (:func:`leader.route_driver.still_circles`), kept by its route driver for the formation's
life, so that the agent's leader and the in-process simulator, both driving a
:class:`leader.route_driver.RouteDriver`, take one rule; a formation that comes into being later
looks first then."""

from __future__ import annotations

from geometry.footprint_plan import Body
from leader.navigation import Follower
from leader.route_driver import RouteDriver, still_circles
from leader.routing import Replanner, Thing

LINE = Body(tuple((-0.6 + 0.3 * k, 0.0) for k in range(5)), radius=0.1, margin=0.0)


def driver() -> RouteDriver:
    return RouteDriver(Replanner(LINE, 0.0, (5.0, 0.0, 0.0), [], start=(-5.0, 0.0)), 0.0, 0.1)


def look_and_tick(d: RouteDriver, t: float, circles: list[tuple[str, float, float]]
                  ) -> frozenset[str]:
    """One tick of a leader at the origin that sees ``circles`` (name, vx, vy) 3 m ahead."""
    static = d.look(circles)
    seen = [Thing(f"obstacle/{n}", 3.0, 0.0, abs(vx) + abs(vy), 0.5, n in static, vx, vy)
            for n, vx, vy in circles]
    follower = Follower("a", (5.0, 0.0), (5.0, 0.0), ((-5.0, 0.0), (5.0, 0.0)))
    d.tick(t, (-5.0, 0.0, 0.0), follower, seen, {})
    return static


def test_the_still_circles_are_those_with_no_velocity():
    circles = [("post", 0.0, 0.0), ("forklift", 0.0, 0.23), ("cart", -0.1, 0.0)]
    assert still_circles(circles) == frozenset({"post"})
    assert still_circles([]) == frozenset()


def test_a_leader_keeps_what_it_saw_still_at_its_first_look():
    d = driver()
    assert look_and_tick(d, 0.0, [("post", 0.0, 0.0), ("forklift", 0.0, 0.23)]) == {"post"}
    # the forklift parks later: still, but not static (it counts still after Stillness.still_s)
    assert look_and_tick(d, 10.0, [("post", 0.0, 0.0), ("forklift", 0.0, 0.0)]) == {"post"}


def test_a_formation_that_comes_into_being_after_a_forklift_parked_takes_it_as_static():
    early, late = driver(), driver()
    look_and_tick(early, 0.0, [("forklift", 0.0, 0.23)])
    parked = [("forklift", 0.0, 0.0)]
    assert look_and_tick(early, 30.0, parked) == frozenset()
    assert look_and_tick(late, 30.0, parked) == {"forklift"}
