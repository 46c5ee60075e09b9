"""An ellipse's confidence radius on the wire (``controller.localisation: fused``): a leader
puts its formation's largest radius on its ``ellipse`` and ``others``, which round-trip; a
malformed radius is dropped and counted; without one the bytes are the camera run's."""

from __future__ import annotations

import asyncio
import struct

import pytest

from agent.odom_in import OdomIn
from wire import traffic
from wire.payloads import (
    ELLIPSE_SIGMA_VERSION,
    DecodeError,
    EllipseMsg,
    Others,
    State,
    decode_ellipse,
    decode_others,
    encode,
)


def _ellipse(name: str, sigma: float | None = None) -> EllipseMsg:
    return EllipseMsg(name, 1.0, 2.0, 0.1, 0.6, 0.3, 0.2, 0.0, 0.0, 4.5, ((1.0, 2.0), (1.5, 2.0)),
                      (0.0, 0.1), sigma)


def test_an_ellipse_with_its_radius_round_trips_as_version_3() -> None:
    msg = _ellipse("F1", 0.07)
    raw = encode(msg)
    assert raw[0] == ELLIPSE_SIGMA_VERSION
    assert decode_ellipse(raw) == msg and decode_ellipse(raw).sigma == 0.07
    others = Others("F1", 4.5, (_ellipse("F2", 0.12), _ellipse("F3")), _ellipse("F1", 0.07))
    raw = encode(others)
    assert raw[0] == ELLIPSE_SIGMA_VERSION
    got = decode_others(raw)
    assert got == others
    assert [e.sigma for e in got.ellipses] == [0.12, None] and got.own is not None \
        and got.own.sigma == 0.07


def test_without_a_radius_the_bytes_are_the_camera_runs() -> None:
    plain = _ellipse("F1")
    assert encode(plain)[0] == 2 and decode_ellipse(encode(plain)).sigma is None
    others = Others("F1", 4.5, (_ellipse("F2"),), plain)
    assert encode(others)[0] == 2
    assert encode(_ellipse("F1", 0.0)) != encode(plain)  # a zero radius is still a radius


@pytest.mark.parametrize("sigma", [-0.01, float("nan"), float("inf")])
def test_a_malformed_radius_is_refused(sigma: float) -> None:
    raw = bytearray(encode(_ellipse("F1", 0.05)))
    raw[-8:] = struct.pack("<d", sigma)
    with pytest.raises(DecodeError, match="sigma"):
        decode_ellipse(bytes(raw))
    with pytest.raises(ValueError, match="sigma"):
        _ellipse("F1", sigma)


def test_a_malformed_radius_in_others_is_refused() -> None:
    raw = bytearray(encode(Others("F1", 4.5, (), _ellipse("F1", 0.05))))
    raw[-8:] = struct.pack("<d", -1.0)  # the own ellipse's radius comes last
    with pytest.raises(DecodeError, match="sigma"):
        decode_others(bytes(raw))
    with pytest.raises(DecodeError):  # truncated inside the radius
        decode_others(bytes(raw[:-3]))


def test_a_mailbox_drops_a_malformed_ellipse_and_counts_it() -> None:
    async def scenario() -> traffic.Mailbox:
        box: traffic.Mailbox[EllipseMsg] = traffic.Mailbox(asyncio.get_running_loop(),
                                                            decode_ellipse)
        key = "warehouse/formation/F1/ellipse"
        bad = bytearray(encode(_ellipse("F1", 0.05)))
        bad[-8:] = struct.pack("<d", -1.0)
        box.offer(key, bytes(bad))
        box.offer(key, encode(_ellipse("F1", 0.05)))
        await box.wait_for(key, timeout=5.0)
        return box

    box = asyncio.run(asyncio.wait_for(scenario(), 10.0))
    assert (box.received, box.dropped_malformed, box.accepted) == (2, 1, 1)
    got = box.latest("warehouse/formation/F1/ellipse")
    assert got is not None and got.sigma == 0.05


def test_an_agent_hears_the_radius_of_every_formation_in_its_view() -> None:
    loc = OdomIn("r1", "warehouse", (0.0, 0.0, 0.0), 0.05, True)
    loc.radius = 0.02
    members = [(State(0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.04), 1.0), None]
    assert loc.formation_radius(members) == 0.04  # what its leader would put on its ellipse
    loc.hear(Others("F1", 1.0, (_ellipse("F2", 0.15),), _ellipse("F1", 0.04)))
    assert loc.formation_radii == (0.04, 0.15)
    loc.hear(Others("F1", 1.0, (), _ellipse("F1", 0.04)))  # F2 out of view: not heard
    assert loc.formation_radii == (0.04,)
