"""The numbers and the input of one robot's control step (:mod:`agent.control`): its parameters
(:class:`ControlParams`), what every member knows of its own formation (:class:`FormationView`,
:class:`Stall`) and everything one tick reads (:class:`StepInput`).

A module of its own so that each robot model's row builder (:func:`agent.control.build_rows`,
:func:`agent.double_integrator.hocbf_rows`) can name them without importing the controller.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import NamedTuple

from geometry.ellipse import Ellipse
from geometry.limits import BURGER_MAX_SPEED, BURGER_MAX_TURN_RATE, BURGER_RADIUS
from geometry.shapes import Shape
from scenario import limits as ranges
from scenario.model import METHODS, Bounds

from . import margins, unicycle
from .barriers import Neighbour, Obstacle, Partner
from .body import Footprint


@dataclass(frozen=True, slots=True)
class RowTuning:
    """The velocity rows' tuning (:func:`agent.control.build_rows`)."""

    sep_margin: float = 0.0  # [m] bodies kept this far beyond touching: more is a wider berth, slower passing
    narrow_cap: float = 0.5  # unicycle band narrowing cap / eps: more room for turns, a narrower band
    heading_from: float = 0.05  # [m] farther from its goal the speed polygon faces it, nearer the nominal
    pair_clearance: float = 0.25  # [m] default all-to-all D_Af beyond two radii: more is safer, less room


ROW_TUNING = RowTuning()


#: The range of each number of :class:`ControlParams`: the scenario's (:mod:`scenario.limits`);
#: ``period`` may be a camera's pose period, in the same range as a control period.
PARAM_RANGES: dict[str, ranges.Range] = {
    "kp": ranges.GAIN,
    "gamma_formation": ranges.GAMMA,
    "gamma_obstacle": ranges.GAMMA,
    "gamma_formations": ranges.GAMMA,
    "epsilon": ranges.EPSILON,
    "max_speed": ranges.MAX_SPEED,
    "lookahead": ranges.LOOKAHEAD,
    "max_turn_rate": ranges.MAX_TURN_RATE,
    "d_af": ranges.DISTANCE,
    "period": ranges.DT,
    "radius": ranges.RADIUS,
    "max_accel": ranges.MAX_ACCEL,
}


@dataclass(frozen=True)
class ControlParams:
    """The controller's parameters; every number is checked against :data:`PARAM_RANGES` and
    every switch must be a bool (ValueError naming the field) when one is built. The numbers
    derived from them alone (offset, margins, separation) are computed once, on first use."""

    kp: float = 2.0  # eq. 4.2
    gamma_formation: float = 1.0
    gamma_obstacle: float = 1.0
    gamma_formations: float = 1.0
    epsilon: float = 0.05  # [m]
    max_speed: float = BURGER_MAX_SPEED  # [m/s]
    unicycle: bool = False
    lookahead: float = 0.05  # [m]
    max_turn_rate: float = BURGER_MAX_TURN_RATE  # [rad/s]
    tiebreak: bool = True
    safety: bool = True  # False: the nominal command, no barriers (to show what happens)
    d_af: float = 0.5  # [m] pairwise distance for the all-to-all baseline (eq. 3.5)
    period: float = 0.05  # [s] control period (sizes the unicycle's discretisation margin)
    radius: float = BURGER_RADIUS  # [m] body radius: separation rows keep bodies 2 r + sep_margin apart
    method: str = "rigid"  # scenario.model.METHODS: rigid (agent.body) or thesis (eq. 4.2 alone)
    double_integrator: bool = False  # input acceleration (agent.double_integrator)
    max_accel: float | None = None  # [m/s^2] None: no acceleration limit
    bounds: Bounds = Bounds()  # declared sensing and motor bounds: margins (agent.margins)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            allowed = PARAM_RANGES.get(f.name)
            if f.name == "max_accel" and value is None:
                continue
            if allowed is not None:
                ranges.check(value, f.name, allowed)
            elif f.name == "method":
                if value not in METHODS:
                    raise ValueError(f"method: must be one of {', '.join(METHODS)}, got {value!r}")
            elif f.name == "bounds":
                if not isinstance(value, Bounds):
                    raise ValueError(f"bounds: must be a Bounds, got {value!r}")
            elif not isinstance(value, bool):
                raise ValueError(f"{f.name}: must be true or false, got {value!r}")

    @classmethod
    def from_scenario(cls, scenario, safety: bool = True) -> ControlParams:
        r, c = scenario.robot, scenario.controller
        return cls(
            kp=c.kp,
            gamma_formation=c.gamma.formation,
            gamma_obstacle=c.gamma.obstacle,
            gamma_formations=c.gamma.formations,
            epsilon=c.epsilon,
            max_speed=r.max_speed,
            unicycle=r.is_unicycle,
            lookahead=r.lookahead,
            max_turn_rate=r.max_turn_rate,
            tiebreak=c.tiebreak == "keep_right",
            safety=safety,
            d_af=c.d_af if c.d_af is not None else 2.0 * r.radius + ROW_TUNING.pair_clearance,
            period=scenario.dt,
            radius=r.radius,
            method=c.method,
            double_integrator=r.is_double_integrator,
            max_accel=r.max_accel,
            bounds=c.bounds,
        )

    @functools.cached_property
    def declared(self) -> bool:
        """Whether any sensing or motor bound is declared (:attr:`scenario.model.Bounds.declared`)."""
        return self.bounds.declared

    @functools.cached_property
    def offset(self) -> float:
        """Control point offset from the body centre [m]."""
        return self.lookahead if self.unicycle else 0.0

    @functools.cached_property
    def separation(self) -> float:
        """[m] distance the separation rows keep between two body centres: two radii (for
        unicycles the pair barrier adds l HEADING_SMOOTH, 1 cm for a TurtleBot, which covers
        the look-ahead points' second-order sampling error: :func:`agent.barriers.separation_terms`);
        each pair adds its margin for the declared bounds (:meth:`pair_margin`)."""
        return 2.0 * self.radius + ROW_TUNING.sep_margin

    @functools.cached_property
    def margin(self) -> float:
        """[m] this robot's margin for its declared bounds (:func:`agent.margins.robot_margin`;
        0.0 without bounds): obstacles, walls and shelves keep it beyond Ds."""
        return margins.robot_margin(self.bounds, self.max_speed, self.offset)

    def pair_margin(self, u: tuple[float, float], v: tuple[float, float]) -> float:
        """[m] the margin for the declared bounds between this robot (last velocity ``u``)
        and a robot or formation moving at ``v`` (:func:`agent.margins.pair_margin`; 0.0
        without bounds): its fixed part and its part per unit of relative speed, each worked
        out once (the same numbers: the fixed part plus 0 (latency + motor_lag), and
        :func:`agent.margins.travel` at 1 m/s is 1 (latency + motor_lag))."""
        return self._pair_fixed + math.hypot(u[0] - v[0], u[1] - v[1]) * self._pair_rate

    @functools.cached_property
    def _pair_fixed(self) -> float:
        """[m] :meth:`pair_margin` of a pair moving together."""
        return margins.pair_margin(self.bounds, 0.0, self.offset)

    @functools.cached_property
    def _pair_rate(self) -> float:
        """[s] :meth:`pair_margin`'s growth per m/s of relative speed (latency + motor_lag)."""
        return margins.travel(self.bounds, 1.0)

    @functools.cached_property
    def sampling_margin(self) -> float:
        """[m] extra obstacle clearance for a unicycle's look-ahead point under sampled control.

        Over one period the look-ahead point of a unicycle turning at omega moves off the
        straight line u dt by up to l (omega dt)^2 / 2; the barrier, which assumed s' = u, then
        settles that far divided by gamma dt inside its boundary. Ds grows by that bound at the
        largest turn rate, or by :data:`agent.unicycle.NEAR_MARGIN` where that is less and the
        turn rate is capped near things (:attr:`turn_capped`), so the body still keeps Ds
        (single integrators move exactly: 0)."""
        if not self.unicycle:
            return 0.0
        return unicycle.sampling_margin(self.lookahead, self.max_turn_rate, self.period,
                                        self.gamma_obstacle)

    @functools.cached_property
    def turn_capped(self) -> bool:
        """Whether this unicycle's turn rate is capped near things
        (:func:`agent.unicycle.near_turn_cap`): where the full turn rate's sampling margin is
        more than :data:`agent.unicycle.NEAR_MARGIN`."""
        return self.unicycle and unicycle.full_sampling_margin(
            self.lookahead, self.max_turn_rate, self.period, self.gamma_obstacle) > self.sampling_margin

    @functools.cached_property
    def load_sampling_margin(self) -> float:
        """[m] the load rows' clearance for sampled control beyond LOAD_CLEAR: the
        :attr:`sampling_margin`, and where the turn rate is capped near things, what the load's
        rows need (:func:`agent.unicycle.load_sampling_margin`)."""
        if not self.turn_capped:
            return self.sampling_margin
        return unicycle.load_sampling_margin(self.max_speed, self.max_turn_rate, self.period,
                                             self.gamma_obstacle)


class FormationView(NamedTuple):
    """What every member knows of its own formation, for the tie-break."""

    own: Ellipse  # the formation's ellipse, as its leader estimates it
    goal_x: float  # [m] goal centroid
    goal_y: float
    name: str = ""  # this formation's name (priority: names sort first-come-first)
    other_names: tuple[str, ...] = ()  # names of ``others``, in the same order
    yielding: float = 0.0  # [s] the stall clock says jammed, yield this long still (update_stall)
    goal_heading: float | None = None  # [rad] the current waypoint's heading (the goal shape's turn)
    arriving: bool = True  # the target is where the member settles (not a waypoint passed)
    # the other formations in view parked at their goals (their ellipses' ``parked``): they
    # hold where they are and cannot give way, so no jam is broken by yielding to them
    parked: frozenset[str] = frozenset()


class Stall(NamedTuple):
    """How long the formation has been nearly still away from its goal, and how long it still
    yields (every member keeps an identical copy; the leader reports ``stalled`` from it)."""

    still: float = 0.0  # [s]
    yielding: float = 0.0  # [s] left


class StepInput(NamedTuple):
    """Everything one robot's tick reads (:meth:`agent.control.Controller.step`), as the agent and the
    in-process simulator assemble it (:func:`agent.inputs.step_inputs`, then the pose, goal,
    obstacles, shapes, last command and footprint)."""

    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the body (x, y, theta)
    goal: tuple[float, float] = (0.0, 0.0)  # [m] its target (goal or waypoint slot)
    # graph neighbours: their control points and last velocities, with Df
    neighbours: Sequence[Neighbour] = ()
    # circles with Ds for the body (a unicycle's look-ahead offset is added in the rows)
    obstacles: Sequence[Obstacle] = ()
    others: Sequence[Ellipse] = ()  # other formations' ellipses: barrier rows
    view: FormationView | None = None  # own formation, for the formation rules; None: no ellipse
    # all-to-all baseline: robots of other formations (eq. 3.5 rows instead of ellipses)
    pairwise: Sequence[Neighbour] = ()
    # the robots it could touch: a hard separation row each (every other member of its
    # formation, and in all-to-all every foreign robot)
    partners: Sequence[Partner] = ()
    # [m/s] its own last certified velocity, as its ``state`` told the partners (a double
    # integrator's velocity now: agent.double_integrator)
    last_u: tuple[float, float] = (0.0, 0.0)
    # the other formations' ellipses for the formation's motion only (its QP and the rules;
    # None: ``others``), so all-to-all keeps them without ellipse rows
    hazards: Sequence[Ellipse] | None = None
    shapes: Sequence[Shape] = ()  # static walls and shelves (Ds from the shape)
    # this member's slot in its formation's body, which ``method: rigid`` needs
    # (agent.control.rigid_nominal); ``method: thesis`` is eq. 4.2 and the rows alone
    footprint: Footprint | None = None
    stall: Stall = Stall()  # the jam rule's memory after this tick (the controller reads none)
