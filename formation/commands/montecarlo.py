"""``formation montecarlo --n N --seed S [--draw circles|warehouse] [--model M]
[--jobs J | --scheduler ADDR] --out DIR``: see :mod:`experiments.montecarlo` and, for where the
runs execute, :mod:`experiments.cluster`."""

from __future__ import annotations

import argparse
import json

import yaml

from experiments.cluster import ClusterError, connect
from experiments.montecarlo import DT, Blind, run_montecarlo
from formation.exits import UsageError
from formation.outdir import begin_output
from formation.progress import Progress
from scenario.bounds import parse as parse_bounds
from scenario.world import IDEAL


def montecarlo_command(ns: argparse.Namespace) -> int:
    if ns.n <= 0:
        raise UsageError(f"--n: must be a positive number of runs, got {ns.n}")
    if ns.jobs <= 0:
        raise UsageError(f"--jobs: must be a positive number of processes, got {ns.jobs}")
    if not 0 <= ns.blind <= 16:
        raise UsageError(f"--blind: must be a number of patches from 0 to 16, got {ns.blind}")
    if ns.bounds is not None:
        parse_bounds(ns.bounds, DT)  # a bad --bounds: exit 2 before any run
    if ns.model == "double_integrator" and ns.world not in (None, IDEAL):
        raise UsageError(f"--model double_integrator: runs in the ideal world only, not with "
                         f"--world {ns.world}")
    if ns.scheduler is not None:
        check_scheduler(ns.scheduler)  # unreachable, no workers or another version: exit 2 now
    out = begin_output(ns)
    with Progress(f"montecarlo n={ns.n}", unit="runs") as progress:
        summary, results = run_montecarlo(ns.n, ns.seed, ns.jobs, progress=progress.update,
                                          world=ns.world, bounds=ns.bounds, draw=ns.draw,
                                          model=ns.model, scheduler=ns.scheduler,
                                          blind=Blind(ns.localisation, ns.blind))
    for r in results:
        if not r["all_reached"] or r["collisions"]:
            (out / f"failure-{r['seed']}.yaml").write_text(yaml.safe_dump(r["scenario"], sort_keys=False))
    (out / "montecarlo.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    with (out / "runs.jsonl").open("w", encoding="utf-8") as fh:
        for r in results:
            fh.write(json.dumps({k: v for k, v in r.items() if k != "scenario"}) + "\n")
    model = f", {ns.model} model" if ns.model else ""
    print(f"montecarlo: {summary['runs']} runs ({summary['draw']} draw, {summary['world']} world, "
          f"bounds {summary['bounds']}{model}), "
          f"reached {100 * summary['reached_rate']:.1f}%, "
          f"collisions {summary['collisions']} (in {summary['runs_with_collision']} runs), "
          f"deadlocks {summary['deadlocks']}, worst formation error "
          f"{summary['worst_formation_error_m']:.3f} m")
    print(f"wrote {out / 'montecarlo.json'}"
          + (f"; failed scenarios as {out}/failure-SEED.yaml" if summary["failures"] else ""))
    return 0


def check_scheduler(address: str) -> None:
    """Exit 2 with one line unless the Dask scheduler at ``address`` can run the sweep."""
    try:
        client = connect(address)
    except ClusterError as exc:
        raise UsageError(str(exc)) from None
    workers = client.scheduler_info().get("workers", {})
    threads = sum(w.get("nthreads", 0) for w in workers.values())
    client.close()
    print(f"montecarlo: on the Dask cluster at {address} ({len(workers)} workers, "
          f"{threads} threads)")
