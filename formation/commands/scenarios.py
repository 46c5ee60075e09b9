"""``formation scenarios``: the names of the shipped scenarios and where their files are."""

from __future__ import annotations

import argparse

from scenario.shipped import SHIPPED_DIR, shipped_names


def scenarios_command(ns: argparse.Namespace) -> int:
    for name in shipped_names():
        print(name)
    print(f"(files in {SHIPPED_DIR}; copy one out to change it)")
    return 0
