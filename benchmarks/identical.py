"""Fingerprints of what runs write, to show that a refactor changes no float.

    python benchmarks/identical.py --out prints.json [--tree DIR] [--jobs 2] [--run NAME ...]
    python benchmarks/identical.py --compare a.json b.json

Runs ``formation sim`` on every shipped and test scenario (the code of ``--tree``, default this
checkout) and records the SHA-256 of each ``robots.csv``; each ``--run`` NAME (a file stem, or
``shipped`` for every shipped scenario) is also run as a lock-step ``formation run``. ``--compare``
prints the files run in both whose fingerprints differ and exits 1 if any does.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def fingerprint(job: tuple[Path, Path, str]) -> tuple[str, str]:
    tree, path, command = job
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        env = dict(os.environ, PYTHONPATH=str(tree))
        argv = [sys.executable, "-m", "formation", command, str(path), "--out", str(out),
                "--no-plots", "--quiet"]
        done = subprocess.run(argv, cwd=tree, env=env, capture_output=True, text=True)
        csv = out / "robots.csv"
        if not csv.exists():
            tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or [""]
            return f"{command}:{path.stem}", f"no robots.csv (exit {done.returncode}: {tail[0]})"
        return f"{command}:{path.stem}", hashlib.sha256(csv.read_bytes()).hexdigest()


def compare(a: Path, b: Path) -> int:
    left, right = json.loads(a.read_text()), json.loads(b.read_text())
    both = left.keys() & right.keys()
    differ = sorted(k for k in both if left[k] != right[k])
    for key in differ:
        print(f"differs: {key}  {left[key]}  {right[key]}")
    alone = sorted(left.keys() ^ right.keys())
    print(f"{len(both) - len(differ)} of {len(both)} run in both identical; {len(alone)} run in one only")
    return 1 if differ else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path)
    ap.add_argument("--tree", type=Path, default=ROOT)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--run", nargs="*", default=[], help="file stems (or 'shipped') to run lock-step too")
    ap.add_argument("--only", nargs="*", default=None, help="file stems to run in process (default: all)")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"))
    ns = ap.parse_args()
    if ns.compare:
        return compare(*ns.compare)
    if ns.out is None:
        ap.error("--out is required")
    tree = ns.tree.resolve()
    shipped = sorted((tree / "scenarios").glob("*.yaml"))
    paths = shipped + sorted((tree / "tests" / "scenarios").glob("*.yaml"))
    jobs = [(tree, p, "sim") for p in paths if ns.only is None or p.stem in ns.only]
    run = set(ns.run)
    jobs += [(tree, p, "run") for p in paths
             if p.stem in run or ("shipped" in run and p in shipped)]
    prints: dict[str, str] = {}
    with ThreadPoolExecutor(ns.jobs) as pool:
        for i, (key, value) in enumerate(pool.map(fingerprint, jobs), 1):
            prints[key] = value
            print(f"[{i}/{len(jobs)}] {key} {value[:16]}", flush=True)
    ns.out.write_text(json.dumps(dict(sorted(prints.items())), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
