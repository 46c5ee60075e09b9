"""``formation commcost --formations 2,4,8 --out DIR``: see :mod:`experiments.commcost`."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from experiments.commcost import outcome, paired, parse_formations, ratio, run_commcost, write_outputs
from formation.exits import EXIT_OK, UsageError
from formation.progress import Progress
from scenario import Scenario


def commcost_command(ns: argparse.Namespace) -> int:
    """``formation commcost --formations 2,4,8 --out DIR``; returns the exit status."""
    try:
        formations = parse_formations(ns.formations)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = Path(ns.out)
    label = {"text": "commcost"}

    def on_run(index: int, total: int, topology: str, scenario: Scenario) -> None:
        label["text"] = f"[{index}/{total}] {topology:10s} {scenario.name}"
        print(f"[{index}/{total}] {topology}: {len(scenario.formations)} formations, "
              f"{len(scenario.robot_ids)} agent processes", flush=True)

    def on_done(r: dict[str, Any]) -> None:
        print(f"      {r['messages_per_robot_per_s']:.1f} msgs/robot/s "
              f"(analytic {r['analytic_messages_per_robot_per_s']:.1f}), "
              f"{r['bytes_per_robot_per_s']:.0f} B/robot/s; {outcome(r)}; "
              f"{r['steps']} ticks in {r['wall_s']:.1f} s", flush=True)

    rows = run_commcost(formations, out, on_run=on_run, on_done=on_done,
                        progress_factory=lambda: Progress(label["text"]))
    write_outputs(rows, out)
    for red, a2a in paired(rows):
        print(f"{red['formations']} formations ({red['robots']} robots): reduced / all-to-all = "
              f"{ratio(red['messages_per_robot_per_s'], a2a['messages_per_robot_per_s']):.3f} "
              f"in messages, {ratio(red['bytes_per_robot_per_s'], a2a['bytes_per_robot_per_s']):.3f}"
              " in bytes")
    print(f"wrote {out / 'commcost.csv'}, {out / 'commcost.md'}, {out / 'commcost.png'}")
    return EXIT_OK
