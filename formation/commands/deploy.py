"""``formation deploy INVENTORY SCENARIO [--dry-run|--start|--stop|--status]``.

Without an option: build the wheel once, install it and each robot's files on every robot
(concurrently), one line per robot (installed / updated / unchanged / FAILED with the reason).
``--dry-run`` checks the inventory (each robot's SSH key must exist) and prints the plan,
touching nothing; ``--start``, ``--stop`` and ``--status``
control the agent through each robot's ``run-agent.sh``.

Exit status: 2 for an invalid inventory or scenario (one line naming the culprit); 1 if any
robot failed (after a summary line naming them: the others were still served) or the wheel
could not be built; 0 when every robot succeeded.
"""

from __future__ import annotations

import argparse
import logging

from deploy import deployer, rmw_status
from deploy.inventory import (
    Inventory,
    InventoryError,
    check_against_scenario,
    check_keys,
    load_inventory,
)
from formation.exits import EXIT_ERROR, EXIT_OK, UsageError
from scenario import load_scenario

logger = logging.getLogger(__name__)


def deploy_command(ns: argparse.Namespace) -> int:
    inventory, plan = load_plan(ns)
    if getattr(ns, "dry_run", False):
        for line in deployer.describe(plan):
            print(line)
        print(f"dry run: {len(plan.robots)} robots planned, nothing touched")
        return EXIT_OK
    action = next((a for a in deployer.ACTIONS if getattr(ns, a, False)), None)
    if action is None:
        try:
            outcome = deployer.deploy(plan)
        except deployer.BuildError as exc:
            print(f"formation deploy: {exc}")
            return EXIT_ERROR
    else:
        outcome = deployer.control(plan, action)
    report(inventory, outcome, action)
    return EXIT_ERROR if outcome.failed else EXIT_OK


def load_plan(ns: argparse.Namespace) -> tuple[Inventory, deployer.Plan]:
    """The inventory and the plan of ``ns``, checked against the scenario (exit 2 naming the
    culprit, before any SSH)."""
    scenario = load_scenario(ns.scenario)  # ScenarioError -> exit 2
    try:
        inventory = load_inventory(ns.inventory)
        check_against_scenario(inventory, scenario.robot_ids)
        plan = deployer.make_plan(inventory, scenario,
                                  write_secrets=not getattr(ns, "dry_run", False))
        check_keys(inventory)  # before a dry run says all is well, and before any SSH
    except InventoryError as exc:
        raise UsageError(str(exc)) from None
    return inventory, plan


def report(inventory: Inventory, outcome: deployer.Outcome, action: str | None) -> None:
    """What a deploy (``action`` None) or an action on every robot did, one line per robot,
    then the summary line."""
    for note in outcome.notes:
        print(note)
    if inventory.zenoh.access_control and action is None:
        print(f"access control: one Zenoh user per robot; the router's files and the camera, "
              f"manager and viewer credentials are in {inventory.zenoh.secrets}/ "
              f"(python -m runtime.router --listen {inventory.zenoh.router} --config "
              f"{inventory.zenoh.secrets / 'router.json5'})")
    for robot in outcome.reports:
        print(deployer.format_report(robot))
    if action == "status":
        for line in rmw_status.status_lines(inventory, rmw_status.viewer_file(inventory)):
            print(line)
    print(deployer.summary_line(outcome, action or "deploy"))
