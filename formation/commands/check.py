"""``formation check SCENARIO``: validate a scenario file, nothing else.

Exit 2 with one line for an invalid file (a declared load overlapping something at the start
among the reasons, or under ``method: rigid`` a goal the footprint's plan finds no route to);
warnings, one line each on stderr, for what a valid file allows that the user should know (a
default load, the members' hull, overlapping something at the start).
"""

from __future__ import annotations

import argparse
import sys

from formation.commands.run import capacity_problem
from formation.exits import EXIT_OK
from scenario import Scenario, load_scenario
from scenario.load import scenario_warnings
from scenario.reader import ScenarioError
from scenario.routes import route_problem
from scenario.succession import formation_successor


def plural(n: int, noun: str) -> str:
    """``1 formation``, ``2 formations``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def lifelong_summary(s: Scenario) -> str:
    """``; fleet of 12 robots, 9 stations, 2 load types, 3 loads, 4 orders and a stream``, or
    nothing for a scenario without a lifelong part."""
    life = s.lifelong
    if life is None:
        return ""
    stream = " and a stream" if life.stream is not None else ""
    return (f"; fleet of {plural(len(life.fleet.robots), 'robot')}, "
            f"{plural(len(life.stations), 'station')}, {plural(len(life.load_types), 'load type')}, "
            f"{plural(len(life.loads), 'load')}, {plural(len(life.orders), 'order')}{stream}")


def cmd_check(ns: argparse.Namespace) -> int:
    s = load_scenario(ns.scenario)
    no_route = route_problem(s)
    if no_route is not None:  # the footprint's plan (method rigid) finds no way to a goal
        raise ScenarioError(f"{ns.scenario}: {no_route}")
    n = len(s.robot_ids)
    for w in scenario_warnings(s):
        print(f"{ns.scenario}: warning: {w}", file=sys.stderr)
    for f in s.formations:
        if formation_successor(f) is None:
            print(f"{ns.scenario}: warning: formation {f.name!r} has no member adjacent to every "
                  f"other member: if its leader {f.leader!r} dies, nobody takes over and the "
                  f"other formations stop avoiding it after the ellipse hold", file=sys.stderr)
    fit = capacity_problem(s)
    if fit is not None:  # a local run with one agent per process ('formation run' refuses it)
        print(f"{ns.scenario}: warning: {fit}", file=sys.stderr)
    print(f"{ns.scenario}: ok ({s.name}: {plural(len(s.formations), 'formation')}, "
          f"{plural(n, 'robot')}, {plural(len(s.obstacles), 'obstacle')}, "
          f"{len(s.shapes)} {'wall or shelf' if len(s.shapes) == 1 else 'walls and shelves'}, "
          f"{s.robot.model}{lifelong_summary(s)})")
    return EXIT_OK
