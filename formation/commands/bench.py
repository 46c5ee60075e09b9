"""``formation bench --out DIR [--quick]``: see :mod:`experiments.bench`."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from experiments.bench import format_table, run_bench


def bench_command(ns: argparse.Namespace) -> int:
    """``formation bench --out DIR [--quick]``."""
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    result = run_bench(quick=ns.quick)
    (out / "bench.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    table = format_table(result)
    (out / "bench.txt").write_text(table + "\n", encoding="utf-8")
    print(table)
    print(f"wrote {out / 'bench.json'}")
    sys.stdout.flush()
    return 0
