"""The results page: ``docs/results.md`` rendered from the stored result files ``docs/results/*.json``.

    python -m experiments.results                 # render docs/results.md from the stored files
    python -m experiments.results --check         # exit 1 when docs/results.md is out of date
    python -m experiments.results --rerun demo    # run a result's commands again, store, render
    python -m experiments.results --take NAME OUT --command CMD --label L --machine M
                                                  # store a row run elsewhere (OUT: its output)

A result file holds one table. ``title`` and ``about`` say what it measures, ``columns`` name its
columns (label, key in a row's ``values``, optional format), and each row carries its own
provenance as data: the ``command`` that measured it, the ``commit`` of main it ran on, the
``machine`` and the ``date``. ``notes`` follow the table. The page is never edited by hand: a
new figure is a new or changed result file, and ``tests/test_results.py`` fails when the page
and the files disagree.

``kind`` says how ``--rerun`` reads a command's output back into its row:

* ``sim``: the ``summary.json`` that ``formation sim`` writes;
* ``montecarlo``: the ``montecarlo.json`` that ``formation montecarlo`` writes;
* ``scenario_bar``: the lines ``benchmarks/scenario_bar.py`` prints;
* ``engines``: the markdown rows ``python -m experiments.engines`` prints, one per scenario (rows
  that share a command run it once);
* ``table``: figures read off a benchmark's printed report (``formation bench``,
  ``experiments.engines``, ...); ``--rerun`` runs the commands and leaves the figures to be
  copied into the file from their output.

A re-run's row keeps its label values (a row's name, its world or model) and takes the new
figures, this checkout's commit, this machine and today's date.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RESULTS_DIR = ROOT / "docs" / "results"
PAGE = ROOT / "docs" / "results.md"
PROVENANCE = ("command", "commit", "machine", "date")
KINDS = ("sim", "montecarlo", "scenario_bar", "engines", "table")

HEADER = """# Results

The figures the project stands on, each with the command that measured it, the main it ran on,
the machine and the date. This page is rendered from the result files in
[results/](results/) by `python -m experiments.results`; do not edit it by hand. What each
benchmark measures: [performance.md](performance.md). How the figures moved:
[CHANGELOG.md](../CHANGELOG.md).
"""

Result = dict[str, Any]


def load_results(results_dir: Path = RESULTS_DIR) -> list[Result]:
    """Every result file of ``results_dir``, checked, in page order (``order``, then file name)."""
    results = []
    for path in sorted(results_dir.glob("*.json")):
        result = json.loads(path.read_text(encoding="utf-8"))
        check_result(result, path.name)
        result["name"] = path.stem
        results.append(result)
    return sorted(results, key=lambda r: (r["order"], r["name"]))


def check_result(result: Result, name: str) -> None:
    """Raise ValueError naming the file and the field when a result file lacks what the page needs."""
    for key in ("title", "order", "kind", "about", "columns", "rows"):
        if key not in result:
            raise ValueError(f"{name}: no {key!r}")
    if result["kind"] not in KINDS:
        raise ValueError(f"{name}: kind {result['kind']!r} is not one of {', '.join(KINDS)}")
    keys = {column[1] for column in result["columns"]}
    for i, row in enumerate(result["rows"]):
        for key in PROVENANCE:
            if not row.get(key):
                raise ValueError(f"{name}: row {i + 1} has no {key!r}")
        missing = keys - set(row.get("values", {}))
        if missing:
            raise ValueError(f"{name}: row {i + 1} has no value for {', '.join(sorted(missing))}")


def cell(value: Any, fmt: str | None = None) -> str:
    """One table cell: None as '-', booleans as yes/no, numbers through ``fmt`` when given."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if fmt and isinstance(value, (int, float)):
        return fmt.format(value)
    return str(value)


def render_table(result: Result) -> list[str]:
    """The markdown table of one result."""
    columns = result["columns"]
    lines = ["| " + " | ".join(c[0] for c in columns) + " |",
             "| " + " | ".join("---" for _ in columns) + " |"]
    for row in result["rows"]:
        values = row["values"]
        lines.append("| " + " | ".join(cell(values[c[1]], c[2] if len(c) > 2 else None)
                                       for c in columns) + " |")
    return lines


def render_provenance(rows: Iterable[Result]) -> list[str]:
    """One line per (commit, machine, date), with the commands run there, in the rows' order."""
    groups: dict[tuple[str, str, str], list[str]] = {}
    for row in rows:
        commands = groups.setdefault((row["commit"], row["machine"], row["date"]), [])
        if row["command"] not in commands:
            commands.append(row["command"])
    return [f"- main {commit}, {machine}, {date}: " + "; ".join(f"`{c}`" for c in commands)
            for (commit, machine, date), commands in groups.items()]


def render_result(result: Result) -> list[str]:
    """One section of the page: title, what it measures, the table, notes, provenance."""
    lines = [f"## {result['title']}", "", result["about"].strip(), "", *render_table(result), ""]
    if result.get("notes"):
        lines += [result["notes"].strip(), ""]
    lines += [f"Provenance (`docs/results/{result['name']}.json`, kind `{result['kind']}`):", ""]
    lines += [*render_provenance(result["rows"]), ""]
    return lines


def render(results: Sequence[Result]) -> str:
    """The whole of docs/results.md."""
    lines = [HEADER.strip(), ""]
    lines += ["| section | what |", "| --- | --- |"]
    lines += [f"| [{r['title']}](#{anchor(r['title'])}) | {r.get('summary', '')} |" for r in results]
    lines.append("")
    for result in results:
        lines += render_result(result)
    return "\n".join(lines).rstrip() + "\n"


def anchor(title: str) -> str:
    """GitHub's anchor of a heading: lower case, spaces to '-', punctuation dropped."""
    kept = "".join(ch for ch in title.lower() if ch.isalnum() or ch in " -_")
    return kept.replace(" ", "-")


# --- re-runs: a command's output back into its row --------------------------------------------


def scaled(value: float | None, factor: float, digits: int) -> float | None:
    """``value * factor`` rounded to ``digits``; None (a figure the run has not) stays None."""
    return None if value is None else round(value * factor, digits)


def from_summary(summary: dict, epsilon: float) -> dict[str, Any]:
    """A ``sim`` row's figures from ``summary.json`` (epsilon: the scenario's band)."""
    clearance, error = summary["min_clearance_m"], summary["formation_error_max_m"]
    return {
        "reached": summary["all_reached"],
        "time_to_goal_s": summary["time_to_goal_s"],
        "collisions": summary["collisions"],
        "error_mm": scaled(error, 1000, 1),
        "eps": scaled(error, 1 / epsilon, 3),
        "obstacle_mm": scaled(clearance["obstacle"], 1000, 1),
        "robot_mm": scaled(clearance["robot"], 1000, 1),
        "reversals": summary["motion"]["reversals_total"],
        "unmet": summary["qp"]["hard_row_unmet_ticks"],
    }


def from_montecarlo(report: dict) -> dict[str, Any]:
    """A ``montecarlo`` row's figures from ``montecarlo.json`` (a lifelong draw's: its orders'
    too, :func:`orders_figures`)."""
    figures = {
        "runs": report["runs"],
        "reached": round(report["reached_rate"] * report["runs"]),
        "collisions": f"{report['collisions']} ({report['runs_with_collision']})",
        "deadlocks": report["deadlocks"],
        "worst_eps": scaled(report["worst_formation_error_over_epsilon"], 1, 2),
        "over_band": report["runs_over_1_5_epsilon"],
        "fallback_ticks": report["fallback_ticks"],
        "clearance_mm": scaled(report["min_obstacle_clearance_m"], 1000, 1),
    }
    if "orders" in report:
        figures.update(orders_figures(report["orders"]))
    return figures


def orders_figures(orders: dict) -> dict[str, Any]:
    """A lifelong draw's order figures from ``montecarlo.json``'s ``orders``: delivered of
    posted, failed, still open at the end, stuck (and in how many runs), and the contacts of
    carried loads with anything and of robots with resting loads."""
    return {
        "delivered": f"{orders['delivered']} of {orders['posted']}",
        "failed": orders["failed"],
        "open": orders["open"],
        "stuck": f"{orders['stuck']} ({orders['runs_with_stuck_order']})",
        "load_contacts": orders["load_contacts"] + orders["intrusions"],
    }


def from_scenario_bar(lines: Iterable[str]) -> dict[str, Any]:
    """A ``scenario_bar`` row's figures from the lines benchmarks/scenario_bar.py printed."""
    met, failing = 0, []
    for line in lines:
        if line.startswith("ok "):
            met += 1
        elif line.startswith("FAIL "):
            failing.append(json.loads(line[5:])["name"])
    return {"met": met, "files": met + len(failing), "failing": ", ".join(failing) or "none"}


def from_engines(lines: Iterable[str]) -> dict[str, dict[str, Any]]:
    """Each scenario's figures from the markdown rows ``python -m experiments.engines`` prints."""
    figures = {}
    for line in lines:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 8 or cells[0] in ("scenario", "---"):
            continue
        name, reached, collisions, contacts, eps, _time, sides, bar = cells
        pairs, _, flipped = sides.partition(": ")
        if flipped != "same":
            flipped = f"{flipped.split(' ')[0]} of {pairs} pairs flipped"
        figures[name] = {"reached": reached, "collisions": collisions, "contacts": int(contacts),
                         "eps": eps, "sides": flipped, "bar": bar.lower()}
    return figures


def argv_of(command: str) -> list[str]:
    """The argv that runs a stored command with this interpreter (``formation``, ``python``)."""
    args = shlex.split(command)
    if args[0] == "formation":
        return [sys.executable, "-m", "formation", *args[1:]]
    if args[0] in ("python", "python3"):
        return [sys.executable, *args[1:]]
    raise ValueError(f"command: {command!r} starts with neither formation nor python")


def with_out(args: list[str], out: Path) -> list[str]:
    """``args`` writing into ``out``: the value after ``--out`` replaced (or added)."""
    if "--out" in args:
        i = args.index("--out")
        return [*args[:i + 1], str(out), *args[i + 2:]]
    return [*args, "--out", str(out)]


def this_machine() -> dict[str, str]:
    """Provenance of a re-run here: the checkout's commit, the machine and today's date."""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short=7", "HEAD"], cwd=ROOT, text=True,
                                capture_output=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    machine = f"{os.cpu_count()} cores, {platform.system()}, Python {platform.python_version()}"
    return {"commit": commit, "machine": machine, "date": datetime.date.today().isoformat()}


def run_command(command: str, out: Path) -> subprocess.CompletedProcess:
    """Run a stored command from the project root, writing into ``out``; raise when it fails."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    args = argv_of(command)
    if args[1] != "benchmarks/scenario_bar.py":
        args = with_out(args, out)
    if args[1:3] == ["-m", "experiments.engines"]:  # exits 1 when a scenario misses the bar
        return subprocess.run(args, cwd=ROOT, env=env, text=True, capture_output=True)
    return subprocess.run(args, cwd=ROOT, env=env, text=True, capture_output=True, check=True)


@functools.lru_cache(maxsize=8)
def engines_figures(command: str) -> dict[str, dict[str, Any]]:
    """Every scenario's figures from one run of an ``experiments.engines`` command."""
    with tempfile.TemporaryDirectory() as tmp:
        return from_engines(run_command(command, Path(tmp) / "out").stdout.splitlines())


def rerun_row(kind: str, row: Result) -> dict[str, Any]:
    """Run one row's command again and return its new figures (kinds with a reader only)."""
    if kind == "engines":
        figures = engines_figures(row["command"])
        if row["values"]["label"] not in figures:
            raise ValueError(f"{row['command']}: printed no row for {row['values']['label']}")
        return figures[row["values"]["label"]]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        done = run_command(row["command"], out)
        return read_back(kind, row["command"], out, done.stdout)


def read_back(kind: str, command: str, out: Path, stdout: str = "") -> dict[str, Any]:
    """A row's figures from what its ``command`` wrote into ``out`` and printed (``stdout``)."""
    if kind == "sim":
        from scenario import load_scenario

        epsilon = load_scenario(ROOT / shlex.split(command)[2]).controller.epsilon
        return from_summary(json.loads((out / "summary.json").read_text(encoding="utf-8")), epsilon)
    if kind == "montecarlo":
        return from_montecarlo(json.loads((out / "montecarlo.json").read_text(encoding="utf-8")))
    return from_scenario_bar(stdout.splitlines())


def take(name: str, out: Path, row: Result, results_dir: Path = RESULTS_DIR) -> Result:
    """Store a row of result ``name`` measured elsewhere (a machine this one hands a command to):
    ``row`` names its ``command``, its ``values``' ``label`` and its ``machine``; its figures are
    read from the command's output folder ``out`` as a re-run reads its own, its commit and date
    are this checkout's and today's. It replaces the row of the same label (keeping the values
    the output has not), or comes last."""
    path = results_dir / f"{name}.json"
    result = json.loads(path.read_text(encoding="utf-8"))
    if result["kind"] not in ("sim", "montecarlo"):
        raise ValueError(f"{name}: a {result['kind']} result; --take reads the output folder of "
                         f"a sim or montecarlo command")
    rows = result["rows"]
    at = [k for k, r in enumerate(rows) if r["values"].get("label") == row["values"]["label"]]
    kept = rows[at[0]]["values"] if at else {}
    new = {**this_machine(), **row, "values": {
        **kept, **row["values"], **read_back(result["kind"], row["command"], out)}}
    if at:
        rows[at[0]] = new
    else:
        rows.append(new)
    check_result(result, path.name)
    path.write_text(json.dumps(result, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    return result


def rerun(name: str, results_dir: Path = RESULTS_DIR,
          run: Callable[[str, Result], dict[str, Any]] = rerun_row) -> Result:
    """Re-run every row of result ``name``, store the figures and provenance, and return it."""
    path = results_dir / f"{name}.json"
    result = json.loads(path.read_text(encoding="utf-8"))
    if result["kind"] == "table":
        commands = "\n  ".join(row["command"] for row in result["rows"])
        raise ValueError(f"{name}: a table result; run its commands and copy the figures into "
                         f"{path.name}:\n  {commands}")
    here = this_machine()
    for row in result["rows"]:
        row["values"].update(run(result["kind"], row))
        row.update(here)
    check_result(result, path.name)
    path.write_text(json.dumps(result, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    return result


def take_from(ns: argparse.Namespace) -> None:
    """``--take NAME OUT --command CMD --label L --machine M``: :func:`take`."""
    missing = [f"--{k}" for k in ("command", "label", "machine") if getattr(ns, k) is None]
    if missing:
        raise ValueError(f"--take needs {', '.join(missing)}")
    name, out = ns.take
    take(name, Path(out), {"command": ns.command, "machine": ns.machine,
                           "values": {"label": ns.label}}, ns.dir)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when the page is out of date")
    ap.add_argument("--rerun", nargs="+", default=[], metavar="NAME",
                    help="run these results' commands again (file stems of docs/results/)")
    ap.add_argument("--take", nargs=2, default=None, metavar=("NAME", "OUT"),
                    help="store a row of result NAME from OUT, the output folder of --command "
                         "run on another machine (with --label and --machine)")
    ap.add_argument("--command", default=None, help="--take: the command that wrote OUT")
    ap.add_argument("--label", default=None, help="--take: the row's label (a row of the same "
                    "label is replaced)")
    ap.add_argument("--machine", default=None, help="--take: the machine it ran on")
    ap.add_argument("--dir", type=Path, default=RESULTS_DIR, help="the result files")
    ap.add_argument("--page", type=Path, default=PAGE, help="the page to write")
    ns = ap.parse_args(argv)
    try:
        for name in ns.rerun:
            rerun(name, ns.dir)
        if ns.take is not None:
            take_from(ns)
        text = render(load_results(ns.dir))
    except (ValueError, OSError, subprocess.CalledProcessError) as exc:
        print(f"results: {exc}", file=sys.stderr)
        return 2
    if ns.check:
        if not ns.page.is_file() or ns.page.read_text(encoding="utf-8") != text:
            print(f"{ns.page} is out of date: run python -m experiments.results", file=sys.stderr)
            return 1
        return 0
    ns.page.write_text(text, encoding="utf-8")
    print(f"wrote {ns.page} from {len(list(ns.dir.glob('*.json')))} result files")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
