"""``formation check SCENARIO``: validate a scenario file, nothing else."""

from __future__ import annotations

import argparse
import sys

from formation.exits import EXIT_OK


def cmd_check(ns: argparse.Namespace) -> int:
    from scenario import load_scenario
    from scenario.load import scenario_warnings

    s = load_scenario(ns.scenario)
    n = len(s.robot_ids)
    for w in scenario_warnings(s):
        print(f"{ns.scenario}: warning: {w}", file=sys.stderr)
    print(f"{ns.scenario}: ok ({s.name}: {len(s.formations)} formations, {n} robots, "
          f"{len(s.obstacles)} obstacles, {len(s.shapes)} walls and shelves, {s.robot.model})")
    return EXIT_OK
