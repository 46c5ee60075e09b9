"""Zenoh key space of formation-cbf (docs/keys.md).

Every key starts with a configurable prefix (default ``warehouse``; it may have several
``/``-separated chunks, such as ``lab2/warehouse``):

========================================  ==================  ===============================================
key                                       class               from -> to
========================================  ==================  ===============================================
``{prefix}/robot/{id}/pose``              ``pose``            camera or world -> that robot's agent
``{prefix}/robot/{id}/state``             ``state``           agent -> its graph neighbours
``{prefix}/robot/{id}/cmd``               ``cmd``             agent -> robot base or world
``{prefix}/formation/{fid}/ellipse``      ``ellipse``         leader -> other leaders
``{prefix}/formation/{fid}/beacon``       ``beacon``          leader -> every leader, once a second
``{prefix}/formation/{fid}/others``       ``others``          leader -> own members
``{prefix}/obstacles``                    ``obstacles``       camera or world -> agents
``{prefix}/formation/{fid}/goal``         ``goal``            fleet manager -> that formation's leader
``{prefix}/formation/{fid}/status``       ``status``          leader -> anyone (also a queryable)
``{prefix}/formation/{fid}/plan``         ``plan``            leader -> its members
``{prefix}/order/{oid}``                  ``order``           fleet manager -> every robot (also a queryable)
``{prefix}/order/{oid}/bid/{rid}``        ``bid``             robot rid -> the other bidders of the order
``{prefix}/order/{oid}/status``           ``order_status``    the team's leader -> anyone
``{prefix}/world/loads``                  ``loads``           simulated world -> robots and viewers
anything else                             ``other``
========================================  ==================  ===============================================

Agents subscribe to exact keys, with two wildcards: :func:`all_robots_key` builds the one the
all-to-all baseline uses (``{prefix}/robot/*/state``), which exists so that baseline can be
measured, and a leader in real time hears every formation's ``beacon`` (its ellipse once a
second) through ``{prefix}/formation/*/beacon`` (:func:`all_formations_key`), to know which
formations are near enough to subscribe to their ``ellipse`` (:mod:`leader.listen`).
The order keys (:mod:`wire.orders` builds them) are the three :data:`ORDER_CLASSES`; a robot
subscribes to ``{prefix}/order/**`` and the fleet manager answers queries on
``{prefix}/order/*`` and ``{prefix}/order/*/status`` (its order book).

Ids (robot, formation, obstacle) and prefix chunks must be non-empty, at most
:data:`MAX_ID_LEN` characters, and free of ``/ * $ # ?`` and whitespace; otherwise the builders
raise ``ValueError`` naming the id. :func:`key_class` never raises on a well-formed prefix: a
key it does not recognise (including one carrying an invalid id) is ``other``.
"""

from __future__ import annotations

import functools
import logging

logger = logging.getLogger(__name__)

DEFAULT_PREFIX = "warehouse"
MAX_ID_LEN = 64  # [characters]

POSE = "pose"
STATE = "state"
CMD = "cmd"
ELLIPSE = "ellipse"
BEACON = "beacon"
OTHERS = "others"
OBSTACLES = "obstacles"
GOAL = "goal"
STATUS = "status"
PLAN = "plan"
ORDER = "order"
BID = "bid"
ORDER_STATUS = "order_status"
LOADS = "loads"
OTHER = "other"

#: Every class name :func:`key_class` can return, in a stable order.
KEY_CLASSES: tuple[str, ...] = (POSE, STATE, CMD, ELLIPSE, OTHERS, OBSTACLES, GOAL, STATUS, PLAN,
                                 BEACON, ORDER, BID, ORDER_STATUS, LOADS, OTHER)

ROBOT_CLASSES: tuple[str, ...] = (POSE, STATE, CMD)
FORMATION_CLASSES: tuple[str, ...] = (ELLIPSE, OTHERS, GOAL, STATUS, PLAN, BEACON)
#: the classes of lifelong operation's keys: orders, bids and votes, an order's status
ORDER_CLASSES: tuple[str, ...] = (ORDER, BID, ORDER_STATUS)

_FORBIDDEN = frozenset("/*$#?")


def id_problem(value: object) -> str | None:
    """Why ``value`` is not a valid id, or ``None`` when it is one."""
    if not isinstance(value, str):
        return f"must be a str, got {type(value).__name__}"
    if not value:
        return "must not be empty"
    if len(value) > MAX_ID_LEN:
        return f"must be at most {MAX_ID_LEN} characters, got {len(value)}"
    for ch in value:
        if ch in _FORBIDDEN or ch.isspace() or not ch.isprintable():
            return f"must not contain {ch!r}"
    return None


def validate_id(value: object, name: str = "id") -> str:
    """Return ``value`` if it is a valid id; otherwise raise ``ValueError`` naming ``name``."""
    problem = id_problem(value)
    if problem is not None:
        raise ValueError(f"{name} {value!r} {problem}")
    return value  # type: ignore[return-value]


def validate_prefix(prefix: object) -> str:
    """Return ``prefix`` if every ``/``-separated chunk of it is a valid id."""
    if not isinstance(prefix, str) or not prefix:
        raise ValueError(f"prefix {prefix!r} must be a non-empty str")
    for chunk in prefix.split("/"):
        problem = id_problem(chunk)
        if problem is not None:
            raise ValueError(f"prefix {prefix!r}: chunk {chunk!r} {problem}")
    return prefix


def _robot_key(prefix: str, robot_id: str, kind: str) -> str:
    return f"{validate_prefix(prefix)}/robot/{validate_id(robot_id, 'robot_id')}/{kind}"


def _formation_key(prefix: str, formation_id: str, kind: str) -> str:
    fid = validate_id(formation_id, "formation_id")
    return f"{validate_prefix(prefix)}/formation/{fid}/{kind}"


def pose_key(prefix: str, robot_id: str) -> str:
    """``{prefix}/robot/{robot_id}/pose``: camera or world -> that robot's agent."""
    return _robot_key(prefix, robot_id, POSE)


def state_key(prefix: str, robot_id: str) -> str:
    """``{prefix}/robot/{robot_id}/state``: agent -> its graph neighbours."""
    return _robot_key(prefix, robot_id, STATE)


def cmd_key(prefix: str, robot_id: str) -> str:
    """``{prefix}/robot/{robot_id}/cmd``: agent -> robot base or world."""
    return _robot_key(prefix, robot_id, CMD)


def ellipse_key(prefix: str, formation_id: str) -> str:
    """``{prefix}/formation/{formation_id}/ellipse``: leader -> other leaders."""
    return _formation_key(prefix, formation_id, ELLIPSE)


def beacon_key(prefix: str, formation_id: str) -> str:
    """``{prefix}/formation/{formation_id}/beacon``: leader -> every leader, once a second (the
    same ``EllipseMsg`` as ``ellipse``; :mod:`leader.listen`)."""
    return _formation_key(prefix, formation_id, BEACON)


def others_key(prefix: str, formation_id: str) -> str:
    """``{prefix}/formation/{formation_id}/others``: leader -> its own members."""
    return _formation_key(prefix, formation_id, OTHERS)


def goal_key(prefix: str, formation_id: str) -> str:
    """``{prefix}/formation/{fid}/goal``: fleet manager -> that formation's leader."""
    return _formation_key(prefix, formation_id, GOAL)


def status_key(prefix: str, formation_id: str) -> str:
    """``{prefix}/formation/{fid}/status``: leader -> anyone (published and queryable)."""
    return _formation_key(prefix, formation_id, STATUS)


def plan_key(prefix: str, formation_id: str) -> str:
    """``{prefix}/formation/{fid}/plan``: leader -> its members (goal, route, member goals)."""
    return _formation_key(prefix, formation_id, PLAN)


def obstacles_key(prefix: str) -> str:
    """``{prefix}/obstacles``: camera or world -> agents."""
    return f"{validate_prefix(prefix)}/{OBSTACLES}"


def loads_key(prefix: str) -> str:
    """``{prefix}/world/loads``: the simulated world -> robots and viewers (lifelong operation's
    loads, :class:`wire.orders.LoadsMsg`)."""
    return f"{validate_prefix(prefix)}/world/{LOADS}"


def all_robots_key(prefix: str, kind: str) -> str:
    """``{prefix}/robot/*/{kind}``: the wildcard of the all-to-all baseline only."""
    if kind not in ROBOT_CLASSES:
        raise ValueError(f"kind {kind!r} must be one of {ROBOT_CLASSES}")
    return f"{validate_prefix(prefix)}/robot/*/{kind}"


def all_formations_key(prefix: str, kind: str) -> str:
    """``{prefix}/formation/*/{kind}``: every formation's key of one kind (a leader subscribes
    to every ``beacon`` with it, in real time)."""
    if kind not in FORMATION_CLASSES:
        raise ValueError(f"kind {kind!r} must be one of {FORMATION_CLASSES}")
    return f"{validate_prefix(prefix)}/formation/*/{kind}"


def parse_key(prefix: str, key: object) -> tuple[str, str | None]:
    """Split a concrete key into ``(class, id)``.

    ``id`` is the robot or formation id (the order id for the :data:`ORDER_CLASSES`), ``None``
    for ``obstacles``, ``loads`` and ``other``. Never raises
    for a valid ``prefix``; ``key`` may be a ``str`` or anything whose ``str()`` is the key
    (such as a ``zenoh.KeyExpr``).
    """
    return _parse_key(validate_prefix(prefix), str(key))


@functools.lru_cache(maxsize=4096)
def _parse_key(prefix: str, key: str) -> tuple[str, str | None]:
    head = prefix + "/"
    if not key.startswith(head):
        return OTHER, None
    rest = key[len(head):].split("/")
    if rest == [OBSTACLES]:
        return OBSTACLES, None
    if rest == ["world", LOADS]:
        return LOADS, None
    if rest[0] == "order":
        return _order_class(rest)
    if len(rest) != 3 or id_problem(rest[1]) is not None:
        return OTHER, None
    group, ident, kind = rest
    if group == "robot" and kind in ROBOT_CLASSES:
        return kind, ident
    if group == "formation" and kind in FORMATION_CLASSES:
        return kind, ident
    return OTHER, None


def _order_class(rest: list[str]) -> tuple[str, str | None]:
    """``order/{oid}``, ``order/{oid}/bid/{rid}`` or ``order/{oid}/status`` split (``rest``
    holds the key's chunks after the prefix), every id checked; ``other`` for anything else."""
    if any(id_problem(part) is not None for part in rest[1::2]):
        return OTHER, None
    if len(rest) == 2:
        return ORDER, rest[1]
    if len(rest) == 3 and rest[2] == STATUS:
        return ORDER_STATUS, rest[1]
    if len(rest) == 4 and rest[2] == BID:
        return BID, rest[1]
    return OTHER, None


def key_class(prefix: str, key: object) -> str:
    """The class name of a concrete key (one of :data:`KEY_CLASSES`), for traffic counting."""
    return parse_key(prefix, key)[0]


CAMERA_USER = "camera"  # the camera service, or the simulated world that stands in for it
MANAGER_USER = "manager"  # the fleet manager: sends goals, reads everything
VIEWER_USER = "viewer"  # read-only: the live page, recorders, status
ZONE_USER = "zone"  # a pose zone router of the world's process (simulator.zones): relays

#: User names of the fleet's services in the router's access control (``wire.acl``): no robot,
#: formation or obstacle may be called so (a robot's user and credentials file would be the
#: service's: a robot ``manager`` passed ``check`` and failed ``run`` with a ValueError).
RESERVED_NAMES: frozenset[str] = frozenset({CAMERA_USER, MANAGER_USER, VIEWER_USER, ZONE_USER})


def user_problem(value: object) -> str | None:
    """Why ``value`` cannot be a Zenoh user name of the fleet (a valid id without ``:``, which
    separates user and password in the router's dictionary), or ``None``."""
    problem = id_problem(value)
    if problem is None and ":" in value:  # type: ignore[operator]
        problem = "must not contain ':'"
    return problem


def name_problem(value: object) -> str | None:
    """The one rule for robot, formation and obstacle names, shared by ``formation check``,
    ``sim``, ``run`` and ``deploy``: a valid id (at most :data:`MAX_ID_LEN` characters, no
    ``/ * $ # ?``, whitespace such as U+00A0 or invisible characters such as U+200B and U+202E),
    no ``:``, and not one of :data:`RESERVED_NAMES`. ``None`` when ``value`` follows it."""
    problem = user_problem(value)
    if problem is None and value in RESERVED_NAMES:
        problem = "is reserved (a service's user name)"
    return problem
