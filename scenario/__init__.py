"""Scenario files: the typed model and the validating loader."""

from .load import ScenarioError, formation_axes, load_scenario, parse_scenario, start_ellipse
from .model import (
    SINGLE_INTEGRATOR,
    UNICYCLE,
    Bounds,
    ControllerSpec,
    Edge,
    FormationSpec,
    Gammas,
    ObstacleSpec,
    RobotModel,
    RobotSpec,
    Scenario,
)

__all__ = [
    "SINGLE_INTEGRATOR", "UNICYCLE", "Bounds", "ControllerSpec", "Edge", "FormationSpec", "Gammas",
    "ObstacleSpec", "RobotModel", "RobotSpec", "Scenario", "ScenarioError", "formation_axes",
    "load_scenario", "parse_scenario", "start_ellipse",
]
