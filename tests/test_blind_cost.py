"""What the margins cost (experiments.blind.time_cost): each fused draw's time to its goals
against the same draw's camera-only run, paired by seed and layout; a bad folder is refused."""

from __future__ import annotations

import json

from experiments.blind import main, spread, time_cost


def run(seed: int, ttg: float | None, layout: int | None = None) -> dict:
    return {"seed": seed, "layout_seed": seed * 1000 if layout is None else layout,
            "time_to_goal_s": ttg}


def test_runs_are_paired_by_seed_and_layout_and_the_unreached_counted_apart():
    fused = [run(1, 30.0), run(2, 44.0), run(3, None), run(4, 20.0), run(5, 50.0, layout=7)]
    camera = [run(1, 20.0), run(2, 40.0), run(3, 35.0), run(5, 50.0)]
    got = time_cost(fused, camera)
    assert (got["pairs"], got["unreached"], got["unpaired"]) == (2, 1, 2)
    assert got["ratio"] == {"median": 1.1, "p95": 1.5, "worst": 1.5}
    assert got["extra_s"] == {"median": 4.0, "p95": 10.0, "worst": 10.0}
    assert got["ratio_best"] == 1.1 and got["extra_s_best"] == 4.0


def test_the_spread_is_nearest_rank_and_empty_without_values():
    assert spread([float(v) for v in range(20, 0, -1)]) == {"median": 10.0, "p95": 19.0,
                                                            "worst": 20.0}
    assert spread([]) == {"median": None, "p95": None, "worst": None}


def test_the_command_prints_the_comparison_and_refuses_a_missing_folder(tmp_path, capsys):
    for name, rows in (("f", [run(1, 33.0)]), ("c", [run(1, 30.0)])):
        (tmp_path / name).mkdir()
        (tmp_path / name / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert main([str(tmp_path / "f"), str(tmp_path / "c")]) == 0
    assert json.loads(capsys.readouterr().out)["ratio"]["median"] == 1.1
    assert main([str(tmp_path / "f"), str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert "nowhere" in err and "Traceback" not in err
