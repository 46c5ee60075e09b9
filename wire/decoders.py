"""The decoder of each key class (see :func:`wire.keys.key_class`): the robots' payloads
(:mod:`wire.payloads`), the navigation ones (:mod:`wire.navigation`) and lifelong operation's
orders, bids, order status and the world's loads (:mod:`wire.orders`; a bid must also pass
:func:`wire.orders.bid_is_forged` against its key)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import zenoh

from wire import keys
from wire.navigation import decode_goal, decode_plan, decode_status
from wire.orders import decode_bid, decode_loads, decode_order, decode_order_status
from wire.payloads import (
    decode_cmd,
    decode_ellipse,
    decode_obstacles,
    decode_others,
    decode_pose,
    decode_state,
)

DECODERS: dict[str, Callable[[bytes | zenoh.ZBytes], Any]] = {
    keys.POSE: decode_pose,
    keys.STATE: decode_state,
    keys.CMD: decode_cmd,
    keys.ELLIPSE: decode_ellipse,
    keys.BEACON: decode_ellipse,
    keys.OTHERS: decode_others,
    keys.OBSTACLES: decode_obstacles,
    keys.GOAL: decode_goal,
    keys.PLAN: decode_plan,
    keys.STATUS: decode_status,
    keys.ORDER: decode_order,
    keys.BID: decode_bid,
    keys.ORDER_STATUS: decode_order_status,
    keys.LOADS: decode_loads,
}
