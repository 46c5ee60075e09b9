"""The agents carry loads in ``formation run`` (lock-step): each fleet robot's agent bids, walks
to its slot, lifts with its team, carries the load as the team's formation, sets it down and
parks (agent.lifepart), the world only moving the load with the team it reports.

Run ``--insecure``: the fleet's access rows do not give a robot the formation keys of a team it
joins at run time, so under access control a team's leader could not put its ``others``."""

from __future__ import annotations

import csv
import hashlib
import json
import math
from pathlib import Path

import pytest

from formation.cli import main

ROOT = Path(__file__).resolve().parent.parent
LIFE = ROOT / "tests" / "scenarios" / "lifelong"


def run(tmp_path: Path, stem: str, name: str) -> Path:
    out = tmp_path / name
    assert main(["run", str(LIFE / f"{stem}.yaml"), "--out", str(out), "--quiet", "--no-plots",
                 "--insecure"]) == 0
    return out


def orders(out: Path) -> list[dict[str, str]]:
    with (out / "orders.csv").open(encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_four_agents_carry_a_pallet_to_its_rack_lock_step(tmp_path: Path) -> None:
    out = run(tmp_path, "one-pallet-si", "a")
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    [o1] = orders(out)
    assert o1["state"] == "delivered" and o1["robots"] == "r4;r2;r1;r3"
    assert float(o1["t_assigned"]) < float(o1["t_gathered"]) < float(o1["t_lifted"]) \
        < float(o1["t_delivered"])
    assert summary["collisions"] == 0 and summary["orders"]["stuck"] == 0
    checks = summary["orders"]["checks"]
    assert checks["set_down_m"] <= 0.05 and checks["set_down_deg"] <= 3.0
    assert checks["intrusions"] == 0 and checks["load_contacts"] == 0
    # every input came: no tick waited out its timeout or commanded zero for a missing one
    assert summary["agents"]["lockstep_timeouts"] == 0 and summary["agents"]["stale"] == 0
    with (out / "loads.csv").open(encoding="utf-8") as f:
        last = list(csv.DictReader(f))[-1]
    assert last["state"] == "resting" and last["station"] == "rack"
    assert math.hypot(float(last["x"]) - 2.5, float(last["y"]) - 2.0) <= 0.05


@pytest.mark.slow
def test_a_lock_step_lifelong_run_is_the_same_twice(tmp_path: Path) -> None:
    a, b = run(tmp_path, "one-beam-unicycle", "a"), run(tmp_path, "one-beam-unicycle", "b")
    assert orders(a) == orders(b) and orders(a)[0]["state"] == "delivered"
    digest = [hashlib.sha256((d / "robots.csv").read_bytes()).hexdigest() for d in (a, b)]
    assert digest[0] == digest[1]
