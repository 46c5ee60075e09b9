"""A lifelong run's loads and orders in the viewer: the orders' states as they changed, the loads
resting among the obstacles or carried, in the frames, in ``run.mcap`` (the ``/orders`` channel,
read back) and on the page (a headless browser)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from browser import Browser, chromium_path, hex_rgb
from system import require
from test_viewer_recording import assert_renderable, read_mcap

from leader import orders as lo
from scenario import load_scenario
from scenario.lifelong import outline_at
from simulator.lifelong import solo
from simulator.series import Series
from viewer.frame import frames_from_series
from viewer.orders import FINAL, RECENT_S, OrderBoard, OrderTimeline
from viewer.record import FLEET_TOPIC, ORDERS_TOPIC, SCENE_TOPIC, write_recording
from viewer.server import Hub, PageServer
from wire.orders import ORDER_STATES

ONE_PALLET = Path(__file__).parent / "scenarios" / "lifelong-one-pallet.yaml"
TEAM = ("f1", "f2", "f3", "f4")
# (t, event) of order o1 (in-1 -> rack-2) and of o2, whose member is lost before its lift
O1 = ((0.0, lo.Event(lo.POST, 0.0)), (1.0, lo.Event(lo.ASSIGN, 1.0, TEAM)),
      (1.0, lo.Event(lo.JOIN, 1.0)), (5.0, lo.Event(lo.GATHERED, 5.0)),
      (6.0, lo.Event(lo.LIFTED, 6.0)), (10.0, lo.Event(lo.ARRIVED, 10.0)),
      (11.0, lo.Event(lo.SET_DOWN, 11.0)))
O2 = ((2.0, lo.Event(lo.POST, 2.0)), (3.0, lo.Event(lo.ASSIGN, 3.0, ("f5", "f6"))),
      (3.0, lo.Event(lo.JOIN, 3.0)), (4.0, lo.Event(lo.LOST, 4.0, who="f6")))


def lifelong():
    return load_scenario(ONE_PALLET)


def timeline(dt: float = 0.5, until: float = 12.0) -> OrderTimeline:
    """The timeline looked at every ``dt`` after the events up to then, as a run looks."""
    orders: dict[str, lo.Order] = {}
    pending = [("o1", t, e) for t, e in O1] + [("o2", t, e) for t, e in O2]
    tl = OrderTimeline()
    k = 0
    while k * dt <= until:
        now = k * dt
        for oid, t, e in [p for p in pending if p[1] <= now]:
            base = orders.get(oid) or lo.Order(oid, "pallet", oid, "in-1" if oid == "o1" else "in-2",
                                                "rack-2" if oid == "o1" else "rack-3", fresh=True)
            orders[oid] = lo.step(base, e)
            pending.remove((oid, t, e))
        tl.look(now, orders)
        k += 1
    return tl


def load_rows() -> list[tuple]:
    life = lifelong().lifelong
    src, dst = life.station("in-1").pose, life.station("rack-2").pose
    mid = (0.5 * (src[0] + dst[0]), 0.5 * (src[1] + dst[1]), 0.0)
    return [(0.0, "o1", "pallet", *src, "resting", "in-1", ""),
            (6.0, "o1", "pallet", *src, "carried", "", "o1"),
            (8.0, "o1", "pallet", *mid, "carried", "", "o1"),
            (11.0, "o1", "pallet", *dst, "resting", "rack-2", "")]


def test_the_viewers_states_are_the_contracts():
    assert FINAL == lo.FINAL
    assert ORDER_STATES == tuple(s for s in lo.STATES if s not in lo.REPORTED)


def test_the_timeline_notes_each_reported_state_when_the_order_entered_it():
    got = [(c.oid, c.state, c.t, c.robots) for c in timeline().changes]
    assert got == [("o1", "waiting", 0.0, ()), ("o1", "gathering", 1.0, TEAM),
                   ("o2", "waiting", 2.0, ()), ("o2", "gathering", 3.0, ("f5", "f6")),
                   ("o2", "waiting", 4.0, ()),  # a member lost before the lift: back in the queue
                   ("o1", "carrying", 6.0, TEAM), ("o1", "delivered", 11.0, TEAM)]
    # looked at less often, each change keeps the order's own time of it
    assert [(c.state, c.t) for c in timeline(2.5, 12.5).changes if c.oid == "o1"] == [
        ("waiting", 0.0), ("gathering", 1.0), ("carrying", 6.0), ("delivered", 11.0)]


def test_the_board_places_each_load_and_lists_the_orders_at_each_instant():
    life = lifelong().lifelong
    board = OrderBoard(life, load_rows(), timeline())
    at = {t: board.fields(t) for t in (0.5, 3.5, 7.0, 9.0, 11.0, 11.0 + RECENT_S + 1.0)}
    (resting,) = at[0.5]["cargo"]
    assert resting["state"] == "resting" and resting["station"] == "in-1"
    assert resting["outline"] == [list(p) for p in outline_at(life.load_type("pallet"),
                                                              life.station("in-1").pose)]
    assert [(o["id"], o["state"]) for o in at[3.5]["orders"]] == [("o1", "gathering"),
                                                                 ("o2", "gathering")]
    assert at[7.0]["cargo"][0]["state"] == "carried" and at[7.0]["cargo"][0]["order"] == "o1"
    assert at[9.0]["cargo"][0]["outline"] != at[7.0]["cargo"][0]["outline"]  # it moved
    assert list(at[11.0]["order_counts"].items()) == [("waiting", 1), ("delivered", 1)]
    done = at[11.0 + RECENT_S + 1.0]
    assert [o["id"] for o in done["orders"]] == ["o2"]  # o1 ended long ago: counted, not listed
    assert done["order_counts"]["delivered"] == 1
    assert done["cargo"][0]["station"] == "rack-2"


def base_and_series(ticks: int = 30, dt: float = 0.5):
    """The run's scenario of formations of one (as a lifelong run records it) and its series."""
    s = lifelong()
    starts = s.lifelong.fleet.starts
    base = dataclasses.replace(s, formations=tuple(solo(r, starts[r], starts[r][:2])
                                                   for r in s.lifelong.fleet.robot_ids))
    series = Series()
    for k in range(ticks):
        for r in s.lifelong.fleet.robot_ids:
            x, y = starts[r][0], starts[r][1]
            series.robots.append((k * dt, r, "o1" if k * dt >= 6.0 else r, x, y, 0.0, x, y,
                                  0.0, 0.0, 0.0, 0.0, "ok", 0.0, 0.1, 0.5, 0.5))
    return base, series


def test_the_recording_logs_the_orders_on_their_channel_at_each_change(tmp_path):
    base, series = base_and_series()
    board = OrderBoard(base.lifelong, load_rows(), timeline())
    messages = read_mcap(write_recording({}, series, base, tmp_path, board=board))
    assert_renderable(messages)
    logged = [json.loads(m[4]) for m in messages[ORDERS_TOPIC]]
    assert [[(o["id"], o["state"]) for o in m["orders"]] for m in logged] == [
        [("o1", "waiting")], [("o1", "gathering")], [("o1", "gathering"), ("o2", "waiting")],
        [("o1", "gathering"), ("o2", "gathering")], [("o1", "gathering"), ("o2", "waiting")],
        [("o1", "carrying"), ("o2", "waiting")], [("o1", "delivered"), ("o2", "waiting")]]
    assert [m[0] for m in messages[ORDERS_TOPIC]] == [round(t * 1e9) for t in
                                                     (0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 11.0)]
    fleet = [json.loads(m[4]) for m in messages[FLEET_TOPIC]]
    assert all({"cargo", "orders", "order_counts"} <= set(f) for f in fleet)
    # the formations of each tick: the robots alone, then the team
    assert [fm["name"] for fm in fleet[-1]["formations"]] == ["o1"]
    assert all(b"cargo/o1" in m[4] for m in messages[SCENE_TOPIC])


@pytest.mark.integration
def test_the_page_lists_the_orders_and_draws_resting_loads_brown_and_carried_ones_in_colour():
    require(chromium_path() is not None, "chromium", "chromium")
    base, series = base_and_series()
    rows = load_rows()
    life = base.lifelong
    # a second load resting at rack-3, so one rests while o1 is carried
    rows.insert(1, (0.0, "p9", "pallet", *life.station("rack-3").pose, "resting", "rack-3", ""))
    frames = list(frames_from_series(series, base, board=OrderBoard(life, rows, timeline())))
    frame = next(f for f in frames if f["t"] == 9.0)
    hub = Hub(mode="live")
    hub.publish(frame)
    page = PageServer(hub)
    try:
        browser = Browser(page.url)
        try:
            browser.wait_for("window.viewer.seq >= 1 && window.viewer.cargo.length == 2")
            browser.evaluate("window.viewerFreeze = true")
            browser.painted()
            shown = browser.evaluate("window.viewer")
            table = browser.evaluate("Array.from(document.querySelectorAll('#orders tr.order'))"
                                     ".map(r => Array.from(r.cells).map(c => c.textContent))")
            counts = browser.evaluate("document.getElementById('order-counts').textContent")
            _png, rgb = browser.screenshot()
        finally:
            browser.close()
    finally:
        page.close()
    assert [(r[0], r[1], r[3], r[4]) for r in table] == [("o1", "carrying", "in-1", "rack-2"),
                                                         ("o2", "waiting", "in-2", "rack-3")]
    assert table[0][5] == " ".join(TEAM)
    assert counts == "1 waiting, 1 carrying"
    cargo = {c["name"]: c for c in shown["cargo"]}
    assert cargo["p9"]["state"] == "resting" and cargo["o1"]["state"] == "carried"

    def colour_near(c: dict) -> np.ndarray:  # beside the name written at the centre
        y, x = round(c["cy"]) - 8, round(c["cx"])
        return rgb[y - 2:y + 3, x - 2:x + 3].reshape(-1, 3).mean(axis=0)

    brown = 0.75 * np.array(hex_rgb("#8c6239"), dtype=float) + 0.25 * 255.0  # over white
    assert np.linalg.norm(colour_near(cargo["p9"]) - brown) < 25, colour_near(cargo["p9"])
    team = 0.35 * np.array(hex_rgb(cargo["o1"]["color"]), dtype=float) + 0.65 * 255.0
    assert np.linalg.norm(colour_near(cargo["o1"]) - team) < 25, colour_near(cargo["o1"])


def fake_watcher():
    """A live watcher on a session that only records subscriptions, and a ``put(key, bytes)``
    that hands it a sample as Zenoh would."""
    from types import SimpleNamespace

    from viewer.live import FleetWatcher

    class Session:
        def declare_subscriber(self, key, handler):
            return SimpleNamespace(undeclare=lambda: None)

    w = FleetWatcher(Session())

    def put(key: str, data: bytes) -> None:
        w.on_sample(SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: data)))

    return w, put


def test_the_live_watcher_lists_the_orders_posted_and_their_teams_reports():
    from wire.orders import BidMsg, OrderMsg, OrderStatusMsg, encode_order
    from wire.payloads import Pose, encode

    w, put = fake_watcher()
    put("warehouse/robot/f1/pose", encode(Pose(0.0, 0.0, 0.0, 20.0)))
    assert "orders" not in w.frame()  # a fleet without orders: no orders keys
    put("warehouse/order/o1", encode_order(OrderMsg("o1", "new", "pallet", "", "in-1", "rack-2",
                                                    stamp=3.0)))
    put("warehouse/order/m2", encode_order(OrderMsg("m2", "load", load="p9", to="out-1",
                                                    stamp=4.0)))
    put("warehouse/order/o1/bid/f1", encode_order(BidMsg("o1", "f1", 1, "bid", (1.0, 2.0))))
    put("warehouse/order/o1/status", encode_order(OrderStatusMsg(
        "o1", "carrying", 1, ("f3", "f1"), "f3", stamp=9.5)))
    # a status about another order than its key names is not that order's
    put("warehouse/order/m2/status", encode_order(OrderStatusMsg("o1", "failed", stamp=9.0)))
    put("warehouse/order/m2/bad", b"\x00")
    f = w.frame()
    assert [(o["id"], o["state"], o["since"], o["from"], o["to"], o["robots"]) for o in f["orders"]] \
        == [("o1", "carrying", 9.5, "in-1", "rack-2", ["f3", "f1"]),
            ("m2", "waiting", 4.0, "", "out-1", [])]
    assert list(f["order_counts"].items()) == [("waiting", 1), ("carrying", 1)]
    put("warehouse/order/m2/status", b"\x01garbage")
    assert w.frame()["orders"][1]["state"] == "waiting" and w.rejected == {"order_status": 1}


def test_the_live_watcher_draws_resting_loads_published_among_the_shelves_as_cargo():
    from geometry.shapes import box
    from wire.orders import OrderMsg, encode_order
    from wire.payloads import Obstacles, Pose, encode
    from wire.shapes import shape_to_msg

    w, put = fake_watcher()
    put("warehouse/robot/f1/pose", encode(Pose(0.0, 0.0, 0.0, 20.0)))
    shelf = box("shelf", (0.0, 0.0), (3.0, 0.6), 0.0, 0.15)
    load = box("o1", (-4.0, 1.5), (0.8, 0.6), 1.5708, 0.15)
    put("warehouse/obstacles", encode(Obstacles(20.0, (), (shape_to_msg(shelf),
                                                             shape_to_msg(load)))))
    assert [sh["name"] for sh in w.frame()["shapes"]] == ["shelf", "o1"]  # no order heard: a shelf
    put("warehouse/order/o1", encode_order(OrderMsg("o1", "new", "pallet", "", "in-1", "rack-2")))
    f = w.frame()
    assert [sh["name"] for sh in f["shapes"]] == ["shelf"]
    (cargo,) = f["cargo"]
    assert cargo["name"] == "o1" and cargo["state"] == "resting"
    assert cargo["outline"] == [[x, y] for x, y in load.corners()]
