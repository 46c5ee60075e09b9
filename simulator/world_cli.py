"""``python -m simulator.world_cli SCENARIO``: the simulated world of a multi-process run on
its own (:class:`simulator.world.World`), for agents started elsewhere; it prints its summary
(:func:`simulator.summary.world_summary`) and writes it with ``--summary FILE``."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from .summary import world_summary
from .world import CAMERAS, World, WorldOptions


def main(argv: Sequence[str] | None = None) -> int:
    from runtime.lifeline import watch_parent
    from scenario import ScenarioError, load_scenario
    from wire.zconf import add_zenoh_args, open_session, settings_from_args, use_zenoh_threads

    parser = argparse.ArgumentParser(prog="python -m simulator.world_cli",
                                     description="The simulated world of a multi-process run.")
    parser.add_argument("scenario")
    parser.add_argument("--realtime", action="store_true")
    parser.add_argument("--camera", default="truth", choices=CAMERAS)
    parser.add_argument("--summary", type=Path, default=None, help="write the result here (JSON)")
    parser.add_argument("--log-level", default="WARNING")
    add_zenoh_args(parser)
    ns = parser.parse_args(argv)
    logging.basicConfig(level=ns.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        scenario = load_scenario(ns.scenario)
        options = WorldOptions(realtime=ns.realtime, camera=ns.camera, prefix=ns.key_prefix)
        settings = settings_from_args(ns)
        settings.to_config()  # ValueError naming a setting zenoh rejects
    except (ScenarioError, ValueError) as exc:
        print(f"world: {exc}", file=sys.stderr)
        return 2
    watch_parent()  # started by a launcher: stop when it dies
    use_zenoh_threads("relay")
    try:
        session = open_session(settings, "world")  # says so when the credentials are refused
    except ConnectionError as exc:
        print(exc, file=sys.stderr)
        return 1
    with session:
        world = World(scenario, session, options)
        try:
            world.wait_for_agents()
            result = world.run()
        except (KeyboardInterrupt, TimeoutError) as exc:
            print(f"world: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 1
        finally:
            world.close()
    summary = world_summary(result)
    if ns.summary is not None:
        ns.summary.write_text(json.dumps(summary, default=float), encoding="utf-8")
    print(json.dumps({k: v for k, v in summary.items() if k not in ("traffic", "latency_ms")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
