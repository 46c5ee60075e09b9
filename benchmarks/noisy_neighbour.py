"""A seeded "noisy neighbour" for fleet benchmarks on a shared machine (docs/performance.md,
round 8): one process, busy for 10-60 ms, then idle for 10-60 ms, for DURATION seconds.

    python3 benchmarks/noisy_neighbour.py SEED DURATION &

Two of them beside ``formation bench --fleets 128@20 ...`` took 60-69 % of a core together on
the 2-core machine (the bench's ``other %`` column): bursts that take a core for tens of
milliseconds at a time, as other people's processes do. It stops by itself.
"""

from __future__ import annotations

import random
import sys
import time


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python3 benchmarks/noisy_neighbour.py SEED DURATION", file=sys.stderr)
        return 2
    rng = random.Random(int(argv[0]))
    end = time.monotonic() + float(argv[1])
    while time.monotonic() < end:
        busy_until = time.monotonic() + rng.uniform(0.01, 0.06)
        while time.monotonic() < busy_until:
            pass
        time.sleep(rng.uniform(0.01, 0.06))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
