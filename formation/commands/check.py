"""``formation check SCENARIO``: validate a scenario file, nothing else."""

from __future__ import annotations

import argparse

from formation.exits import EXIT_OK


def cmd_check(ns: argparse.Namespace) -> int:
    from scenario import load_scenario

    s = load_scenario(ns.scenario)
    n = len(s.robot_ids)
    print(f"{ns.scenario}: ok ({s.name}: {len(s.formations)} formations, {n} robots, "
          f"{len(s.obstacles)} obstacles, {len(s.shapes)} walls and shelves, {s.robot.model})")
    return EXIT_OK
