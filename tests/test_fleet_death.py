"""A fleet robot killed in a lock-step ``formation run`` stands where it died for the other
leaders (its token gone: a standing body, leader.succession) and the rest of the fleet goes on,
as in the in-process simulator: the order waits again and the other two deliver it."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from formation.cli import main
from scenario import load_scenario
from simulator.lifelong import LifelongOptions, simulate_lifelong

SCENARIO = Path(__file__).resolve().parent / "scenarios" / "lifelong" / "beam-spare-si.yaml"


def test_a_killed_fleet_robot_stands_and_the_others_deliver_as_in_the_simulator(tmp_path) -> None:
    out = tmp_path / "kill"
    assert main(["run", str(SCENARIO), "--out", str(out), "--no-plots", "--quiet",
                 "--kill", "r1@3"]) == 0
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    with (out / "orders.csv").open(encoding="utf-8") as f:
        [o1] = list(csv.DictReader(f))
    sim = simulate_lifelong(load_scenario(SCENARIO),
                            life_options=LifelongOptions(kills=(("r1", 3.0),))).run.orders["o1"]
    assert o1["state"] == sim.state == "delivered"
    assert sorted(o1["robots"].split(";")) == sorted(sim.robots) == ["r2", "r3"]
    assert float(o1["t_assigned"]) >= 3.0  # assigned again after the loss
    assert summary["collisions"] == 0 and summary["orders"]["stuck"] == 0
    faults = summary["faults"]
    # nobody stopped for the dead robot's stale ellipse: it was a standing body instead
    assert faults["stale_ticks_by_input"].get("ellipse", 0) == 0
    assert faults["standing_body_ticks"] > 0
