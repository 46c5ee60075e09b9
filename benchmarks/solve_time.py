"""Solve-time benchmark: the exact 2-variable QP against qpsolvers backends on the QPs a
warehouse run really poses, side by side in one process. Same as `formation bench`.

    python benchmarks/solve_time.py [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from formation.commands.bench import bench_command

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", default="runs/bench")
    sys.exit(bench_command(parser.parse_args()))
