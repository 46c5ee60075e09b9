"""A fleet robot's own check of a posted order (agent.lifepart.LifePart.resolve with
agent.order_check): what its warehouse cannot serve is never bid for, and counted; what it can
serve becomes an open order at the load's slots. No Zenoh: the part is not opened."""

from __future__ import annotations

from pathlib import Path

import pytest

from agent.config import build_agent_configs
from agent.lifepart import LifePart
from leader.team import slot_points
from scenario import load_scenario
from wire.orders import OrderMsg

PALLET = Path(__file__).resolve().parent / "scenarios" / "lifelong" / "one-pallet-si.yaml"


@pytest.fixture
def part() -> LifePart:
    cfg = build_agent_configs(load_scenario(PALLET))["r1"]
    return LifePart(cfg, regroup=lambda _m: None, static=lambda: ())


@pytest.mark.parametrize("msg", [
    OrderMsg("m1", "new", type="crate", source="dock", to="rack", stamp=1.0),
    OrderMsg("m2", "new", type="pallet", source="rack", to="rack", stamp=1.0),
    OrderMsg("m3", "new", type="pallet", source="dock", to="nowhere", stamp=1.0),
    OrderMsg("m4", "load", load="p9", to="rack", stamp=1.0),
], ids=["unknown type", "source not a source", "unknown destination", "unknown load"])
def test_an_order_the_warehouse_cannot_serve_is_refused_and_counted(part: LifePart,
                                                                     msg: OrderMsg) -> None:
    assert part.resolve(msg) is None
    assert part.refused == 1 and part.stats()["orders_refused"] == 1
    assert msg.oid not in part.orders


def test_a_servable_order_opens_at_its_loads_slots_and_its_load_may_then_be_moved(
        part: LifePart) -> None:
    life = part.life
    new = part.resolve(OrderMsg("m1", "new", type="pallet", source="dock", to="rack", stamp=1.0))
    assert new is not None and part.refused == 0
    assert new.slots == slot_points(life.station("dock").pose, life.load_type("pallet").slots)
    # the new load m1 may be named by a later order: not refused (it opens once the world
    # lists where m1 rests), while a load nobody brought is
    assert part.resolve(OrderMsg("m2", "load", load="m1", to="rack", stamp=2.0)) is None
    assert part.refused == 0
    assert part.resolve(OrderMsg("m3", "load", load="m9", to="rack", stamp=2.0)) is None
    assert part.refused == 1
