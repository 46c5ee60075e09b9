"""``formation bench --out DIR [--quick]``: see :mod:`experiments.bench`."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from experiments.bench import (
    DEFAULT_SCENARIO,
    format_fleets,
    format_table,
    parse_fleets,
    run_bench,
    run_fleets,
)
from experiments.inprocess_bench import (
    INPROCESS_DURATION,
    bench_inprocess_curve,
    format_curve,
    parse_sizes,
)
from experiments.localisation_bench import bench_localisation, format_localisation
from experiments.method_bench import bench_methods, format_methods, parse_methods
from formation.exits import UsageError
from formation.outdir import begin_output


def bench_command(ns: argparse.Namespace) -> int:
    """``formation bench --out DIR [--quick]``, or ``--fleets N@HZ,... [--agents-per-process K]
    [--session-per-agent] [--repeat R] [--duration S]``: only those agent fleets, or
    ``--method M,... [--quick]``: only the per-member step under those methods, or
    ``--inprocess N,... [--quick]``: only ``formation sim``'s speed on N-robot warehouses, or
    ``--localisation [--quick]``: only the agent's own filter's CPU per tick."""
    only = _only(ns)
    if only is not None:
        return only
    fleets_arg = getattr(ns, "fleets", None)
    per_process = getattr(ns, "agents_per_process", 1)
    repeat = getattr(ns, "repeat", 1)
    duration = getattr(ns, "duration", None)
    try:
        fleets = None if fleets_arg is None else parse_fleets(fleets_arg)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    slots = getattr(ns, "pose_slots", 1)
    if per_process < 1 or repeat < 1 or slots < 1:
        raise UsageError("--agents-per-process, --repeat and --pose-slots: need integers >= 1")
    if duration is not None and not duration > 0:
        raise UsageError(f"--duration: need seconds > 0, got {duration}")
    own = getattr(ns, "session_per_agent", False)
    zones_arg = getattr(ns, "pose_zones", "0")
    try:
        zones = [int(z) for z in zones_arg.split(",")]
    except ValueError:
        zones = [-1]
    if not zones or any(z < 0 for z in zones):
        raise UsageError(f"--pose-zones: {zones_arg!r} is not a list of integers >= 0 (e.g. 0,4)")
    if fleets is None and (per_process != 1 or repeat != 1 or duration is not None or slots != 1
                           or own or zones != [0]):
        raise UsageError("--agents-per-process, --session-per-agent, --repeat, --duration, "
                         "--pose-slots and --pose-zones go with --fleets")
    stalls = getattr(ns, "stalls", False)
    if stalls and (fleets is None or per_process < 2):
        raise UsageError("--stalls goes with --fleets and --agents-per-process K > 1")
    out = begin_output(ns)
    if fleets is not None:
        result = run_fleets(fleets, per_process, per_process > 1 and not own, repeat,
                            pose_slots=slots, pose_zones=zones, stalls=stalls,
                            **({} if duration is None else {"duration": duration}))
        _write(out, result, format_fleets(result))
    else:
        result = run_bench(quick=ns.quick)
        _write(out, result, format_table(result))
    return 0


def _only(ns: argparse.Namespace) -> int | None:
    """The exit status of a one-benchmark mode (``--method``, ``--localisation``,
    ``--inprocess``); None when none is asked for."""
    method_arg = getattr(ns, "method", None)
    if method_arg is not None:
        return _methods(ns, method_arg)
    if getattr(ns, "localisation", False):
        return _localisation(ns)
    inprocess_arg = getattr(ns, "inprocess", None)
    if inprocess_arg is not None:
        return _inprocess(ns, inprocess_arg)
    return None


def _methods(ns: argparse.Namespace, text: str) -> int:
    """``--method M,...``: :mod:`experiments.method_bench` on the warehouse (``--quick``: 20 s)."""
    try:
        methods = parse_methods(text)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if getattr(ns, "fleets", None) is not None:
        raise UsageError("--method and --fleets: one at a time")
    out = begin_output(ns)
    result = bench_methods(DEFAULT_SCENARIO, methods, 20.0 if ns.quick else None)
    _write(out, result, format_methods(result))
    return 0


def _inprocess(ns: argparse.Namespace, text: str) -> int:
    """``--inprocess N,...``: :mod:`experiments.inprocess_bench` (``--quick``: 5 s a fleet)."""
    try:
        sizes = parse_sizes(text)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if getattr(ns, "fleets", None) is not None:
        raise UsageError("--inprocess and --fleets: one at a time")
    out = begin_output(ns)
    result = bench_inprocess_curve(sizes, 5.0 if ns.quick else INPROCESS_DURATION)
    _write(out, result, format_curve(result))
    return 0


def _localisation(ns: argparse.Namespace) -> int:
    """``--localisation``: :mod:`experiments.localisation_bench` (``--quick``: fewer ticks)."""
    if getattr(ns, "fleets", None) is not None:
        raise UsageError("--localisation and --fleets: one at a time")
    out = begin_output(ns)
    result = bench_localisation(ns.quick)
    _write(out, result, format_localisation(result))
    return 0


def _write(out: Path, result: dict, table: str) -> None:
    """``bench.json`` and ``bench.txt`` (the table, also printed)."""
    (out / "bench.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    (out / "bench.txt").write_text(table + "\n", encoding="utf-8")
    print(table)
    print(f"wrote {out / 'bench.json'}")
    sys.stdout.flush()
