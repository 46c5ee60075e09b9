"""Monte Carlo's blind patches (experiments.blind): seeded, across a formation's way, never on
a robot's start or goal; and the command's bad --blind is refused with exit 2."""

from __future__ import annotations

import copy

from experiments.blind import covers, draw_patches
from experiments.montecarlo import Blind, draw_layout, with_blind
from formation.cli import main
from scenario.load import scenario_from_dict


def test_patches_are_seeded_and_leave_every_start_and_goal_seen():
    d = draw_layout(7)
    a, b = draw_patches(d, 2, 7), draw_patches(d, 2, 7)
    assert a == b and len(a) == 2 and draw_patches(d, 2, 8) != a
    for seed in range(7, 47):
        d = draw_layout(seed)
        ends = [r[k] for f in d["formations"] for r in f["robots"].values() for k in ("start", "goal")]
        for p in draw_patches(d, 2, seed):
            box = p["box"]
            assert not any(covers(tuple(box["center"]), box["yaw"], s[0], s[1]) for s in ends)


def test_a_drawn_layout_with_patches_is_a_valid_fused_scenario():
    d = with_blind(copy.deepcopy(draw_layout(3)), Blind("fused", 2), 3)
    sc = scenario_from_dict(d)
    assert sc.controller.localisation == "fused" and len(sc.world.camera_blind) == 2


def test_a_bad_blind_count_is_refused(tmp_path, capsys):
    assert main(["montecarlo", "--blind", "-1", "--n", "1", "--out", str(tmp_path / "o")]) == 2
    assert "--blind" in capsys.readouterr().err


def test_the_error_quantiles_are_nearest_rank():
    from experiments.montecarlo import localisation_totals

    runs = [{"localisation": {"max_error_m": float(e), "max_sigma_m": 0.0, "rejected": 1,
                              "over_limit_ticks": 0, "blind_s": 1.0}} for e in range(20, 0, -1)]
    got = localisation_totals(runs, Blind("fused", 2))
    assert got["max_error_m"] == {"median": 10.0, "p95": 19.0, "worst": 20.0}
    assert got["rejected"] == 20
