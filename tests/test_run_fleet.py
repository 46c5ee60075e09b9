"""``formation run`` of a scenario with a fleet (lifelong operation): the launcher starts the
fleet manager, the world keeps the loads and the run writes the order files of ``formation sim``.
The agents here are formations of one that take no order (bidding and carrying are the agents'
part), so the order stays open and its load rests where it appeared."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import yaml

from formation.cli import main
from simulator.orders_out import LOAD_COLUMNS, ORDER_COLUMNS

ROOT = Path(__file__).resolve().parent.parent


def test_a_fleet_scenario_runs_lock_step_and_writes_the_order_files(tmp_path):
    data = yaml.safe_load((ROOT / "tests" / "scenarios" / "lifelong-one-pallet.yaml")
                          .read_text(encoding="utf-8"))
    data["duration"] = 1.0  # 20 ticks
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--quiet", "--no-plots"]) == 0
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["mode"] == "multiprocess" and summary["steps"] == 20
    assert summary["orders"]["posted"] == 1 and summary["orders"]["open"] == 1
    assert summary["all_reached"] is False and summary["collisions"] == 0
    assert summary["comm"]["classes"]["loads"]["put"]["messages"] == 20  # one a tick
    with (out / "orders.csv").open(encoding="utf-8") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == ORDER_COLUMNS and [r[0] for r in rows[1:]] == ["o1"]
    assert rows[1][ORDER_COLUMNS.index("state")] == "waiting"
    with (out / "loads.csv").open(encoding="utf-8") as f:
        loads = list(csv.reader(f))
    assert tuple(loads[0]) == LOAD_COLUMNS
    assert [(r[1], r[6], r[7]) for r in loads[1:]] == [("o1", "resting", "in-1")]
    assert (out / "orders.png").is_file()
    assert (out / "orders.journal").is_file()  # the fleet manager's book
