"""A fleet robot killed while its team carries, in a lock-step ``formation run``: the team sets
the beam down where it stands at once (its token gone is positive knowledge), the order fails
``member lost`` as in the in-process simulator, the dead robot stands under the beam as a body
for every other formation (the camera's pose of it, not its ellipse from before the lift grown
by the whole carry), and the other team delivers with nobody stopping or pressed into a body."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from formation.cli import main
from scenario import load_scenario
from simulator.lifelong import LifelongOptions, simulate_lifelong

SCENARIO = Path(__file__).resolve().parent / "scenarios" / "lifelong" / "beam-kill-carry-si.yaml"


def test_a_member_killed_while_carrying_stands_under_the_beam_and_the_others_deliver(
        tmp_path: Path) -> None:
    out = tmp_path / "kill"
    main(["run", str(SCENARIO), "--out", str(out), "--no-plots", "--quiet", "--kill", "r1@19"])
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    with (out / "orders.csv").open(encoding="utf-8") as f:
        rows = {r["id"]: r for r in csv.DictReader(f)}
    sim = simulate_lifelong(load_scenario(SCENARIO),
                            life_options=LifelongOptions(kills=(("r1", 19.0),))).run.orders
    for oid in ("o1", "o2"):
        assert (rows[oid]["state"], rows[oid]["reason"]) == (sim[oid].state, sim[oid].reason)
    assert (rows["o1"]["state"], rows["o1"]["reason"]) == ("failed", "member lost: r1")
    assert float(rows["o1"]["t_lifted"]) < 19.0 and rows["o2"]["state"] == "delivered"
    with (out / "loads.csv").open(encoding="utf-8") as f:
        beam = [r for r in csv.DictReader(f) if r["load"] == "o1"][-1]
    assert beam["state"] == "resting" and beam["station"] == ""  # where the team stood
    assert summary["collisions"] == 0 and summary["orders"]["checks"]["intrusions"] == 0
    assert summary["orders"]["stuck"] == 0
    faults = summary["faults"]
    # the dead robot was a standing body after the team dissolved, as small as the camera saw
    # it: nobody stopped for a stale input, and no robot started inside a grown body
    assert faults["standing_body_ticks"] > 0
    assert faults["stale_ticks_by_input"] == {}
    assert summary["hard_row_unmet_ticks"] == 0
