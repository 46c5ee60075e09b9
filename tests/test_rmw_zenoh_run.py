"""``formation run --base rmw_zenoh``: the world plays the robots' bases and takes each robot's
command from its rmw_zenoh data key (simulator.bases), reading samples as rmw_zenoh does."""

from __future__ import annotations

from pathlib import Path

import pytest

from agent.base import encode_cmd
from simulator.bases import command_of, plan_bases, run_bases
from wire import rmw_zenoh as rmw

ROOT = Path(__file__).resolve().parent.parent
GID = bytes(range(16))


def _att(layout: str, seq: int = 1, ts_ns: int = 1_700_000_000_500_000_000) -> bytes:
    return rmw.encode_attachment(rmw.Attachment(seq, ts_ns, GID), layout)


def test_bases_of_a_run_are_in_each_robots_namespace():
    bases = run_bases(["r1", "r2"], rmw.RmwSettings(cmd_type="Twist", domain=7))
    assert bases["r2"].key == "7/r2/cmd_vel/geometry_msgs::msg::dds_::Twist_/" + rmw.rihs01(rmw.TWIST)
    humble = plan_bases(["r1"], rmw.RmwSettings(), "humble")["r1"]
    assert humble.key.endswith("/TypeHashNotSupported") and humble.type_name == rmw.TWIST


def test_commands_are_read_as_rmw_zenoh_reads_them():
    stamped = plan_bases(["r1"], rmw.RmwSettings(), "jazzy")["r1"]
    cmd = command_of(stamped, encode_cmd(rmw.TWIST_STAMPED, 0.1, -0.5, 12.25),
                     _att(rmw.POSITIONAL))
    assert (cmd.v, cmd.omega, cmd.stamp, cmd.ux, cmd.uy) == (0.1, -0.5, 12.25, 0.0, 0.0)
    twist = plan_bases(["r1"], rmw.RmwSettings(release="jazzy-0.2.3", cmd_type="Twist"),
                       "jazzy")["r1"]
    cmd = command_of(twist, encode_cmd(rmw.TWIST, 0.2, 0.3, 0.0), _att(rmw.KEYED))
    assert (cmd.v, cmd.omega) == (0.2, 0.3)
    assert cmd.stamp == pytest.approx(1_700_000_000.5)  # the attachment's source timestamp
    # what an rmw_zenoh subscription drops: no attachment, another release's layout, bad CDR
    for payload, att in ((encode_cmd(rmw.TWIST, 0.2, 0.3, 0.0), None),
                         (encode_cmd(rmw.TWIST, 0.2, 0.3, 0.0), _att(rmw.POSITIONAL)),
                         (b"\x00\x01\x00\x00", _att(rmw.KEYED))):
        with pytest.raises(ValueError):
            command_of(twist, payload, att)
