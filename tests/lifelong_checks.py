"""The acceptance checks of a lifelong run, applied to what the run measured and wrote: every
order delivered where asked (5 cm, 3 degrees), the team under its load when it lifts, no carried
load touching anything, no robot through a resting load, no bodies overlapping, no collision and
no stuck order."""

from __future__ import annotations

import math

from agent.errand import SET_DOWN_M, SET_DOWN_RAD
from leader.orders import DELIVERED
from simulator.lifelong import LifelongResult

CONTACT = 1e-3  # [m] a clearance below minus this is a contact


def delivered_where_asked(result: LifelongResult) -> list[str]:
    """The orders delivered: each one's load row at its delivery names the destination and
    rests within the set-down tolerance of it (loads.csv's rows)."""
    life = result.run.life
    done = []
    for order in result.run.orders.values():
        if order.state != DELIVERED:
            continue
        rows = [r for r in result.run.load_rows
                if r[1] == order.load and r[0] == order.t_delivered and r[6] == "resting"]
        assert rows, f"{order.oid}: no resting row of {order.load} at its delivery"
        t, _name, _kind, x, y, yaw, _state, station, _order = rows[-1]
        assert station == order.dst, f"{order.oid}: rests at {station!r}, not {order.dst!r}"
        sx, sy, syaw = life.station(order.dst).pose
        assert math.hypot(x - sx, y - sy) <= SET_DOWN_M, f"{order.oid}: set down off its station"
        turn = abs(math.remainder(yaw - syaw, 2 * math.pi))
        assert turn <= SET_DOWN_RAD, f"{order.oid}: set down turned {math.degrees(turn):.1f} deg"
        done.append(order.oid)
    return done


def check_safe(result: LifelongResult) -> None:
    """Bodies, loads and teams as the acceptance asks, for any run (faults included)."""
    s = result.summary
    checks = s["orders"]["checks"]
    assert s["collisions"] == 0, s["collision_log"]
    assert s["min_clearance_m"]["robot"] is None or s["min_clearance_m"]["robot"] >= -CONTACT
    assert checks["lift_error_m"] <= result.scenario.goal_tolerance + 1e-9
    assert checks["load_contacts"] == 0
    clear = checks["carried_min_clearance_m"]
    assert clear is None or clear >= -CONTACT
    assert checks["intrusions"] == 0
    assert s["orders"]["stuck"] == 0, checks["stuck_orders"]


def check_all_delivered(result: LifelongResult) -> None:
    """:func:`check_safe`, and every order posted delivered where asked."""
    check_safe(result)
    orders = result.run.orders
    assert orders and all(o.state == DELIVERED for o in orders.values()), \
        {o.oid: o.state for o in orders.values()}
    assert sorted(delivered_where_asked(result)) == sorted(orders)
