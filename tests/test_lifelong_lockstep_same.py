"""A lock-step ``formation run`` of a lifelong scenario writes the same ``orders.csv`` and
``robots.csv`` as ``formation sim`` of it, byte for byte: the simulator runs the agents' own
timeline (a roster committed a tick after its round closes, a formation the tick after next,
the team's speaker judging on the tick before), so the agents, bidding, walking, lifting,
carrying and parking over Zenoh, move every robot exactly as the in-process fleet does.

The files: a two-robot beam of unicycles, a pallet of four double integrators, chained orders
(the second order's load is the first's, a busy source, a later urgent order) whose teams
dissolve and form again among robots parking between orders, a forklift parked in a
cross-aisle before the team exists (static to every leader that first looks after it stopped),
and a ten-minute stream of pallets and beams for a fleet of eight (leaders that see only the
formations in view, loads lifted and set down in the robots' view a tick late, robots that walk
home a tick late when they repeat their last status), and a pallet whose last member's route
goes round its teammates' ellipses, not between them (each leader's plan as the simulator's)."""

from __future__ import annotations

from pathlib import Path

import pytest

from formation.cli import main
from tests.same_files import assert_same

SCENARIOS = Path(__file__).resolve().parent / "scenarios"
SAME = ("lifelong/one-beam-unicycle", "lifelong/one-pallet-di", "lifelong/chain-busy-si",
        "lifelong-forklift-cross-aisle", "lifelong/stream-mixed-si",
        "lifelong/mc-gather-standstill-unicycle")


@pytest.mark.slow
@pytest.mark.parametrize("stem", SAME)
def test_a_lock_step_run_writes_what_the_simulator_writes(tmp_path: Path, stem: str) -> None:
    path = str(SCENARIOS / f"{stem}.yaml")
    sim, run = tmp_path / "sim", tmp_path / "run"
    assert main(["sim", path, "--out", str(sim), "--no-plots", "--quiet"]) == 0
    assert main(["run", path, "--out", str(run), "--no-plots", "--quiet"]) == 0
    for name in ("orders.csv", "robots.csv"):
        assert_same(sim / name, run / name, f"{stem} {name}")
    rows = (sim / "orders.csv").read_text(encoding="utf-8").splitlines()[1:]
    assert rows and all(",delivered," in row for row in rows)
