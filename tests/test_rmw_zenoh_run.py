"""``formation run --base rmw_zenoh``: the world plays the robots' bases and takes each robot's
command from its rmw_zenoh data key (simulator.bases), reading samples as rmw_zenoh does."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from agent.base import encode_cmd
from formation.cli import main
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


@pytest.mark.parametrize("scenario,argv,message", [
    ("thesis-6.3", ["--cmd-type", "Twist"], "--cmd-type Twist: carries no stamp"),
    ("thesis-6.3", ["--ros-domain", "500"], "--base rmw_zenoh: ROS domain id"),
    ("thesis-5.1.1", [], "--base rmw_zenoh: a ROS base takes (v, omega)"),  # single integrator
])
def test_bad_options_exit_2_with_one_line(tmp_path, capsys, scenario, argv, message):
    code = main(["run", str(ROOT / f"scenarios/{scenario}.yaml"), "--out", str(tmp_path / "o"),
                 "--base", "rmw_zenoh", *argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()  # refused before anything started


def test_a_lockstep_run_through_rmw_zenoh_drives_like_the_cmd_key(tmp_path):
    """Lock-step with TwistStamped: every tick's command comes through the rmw_zenoh keys (the
    world receives no ``cmd`` message), and the robots move exactly as they do on the ``cmd``
    key (robots.csv equal but for ux, uy, which a ROS base is not sent)."""
    out, plain = tmp_path / "rmw", tmp_path / "plain"
    # 2 simulated seconds: short of the goals, so both runs exit 1 ("incomplete") alike
    code = main(["run", str(ROOT / "scenarios/thesis-6.3.yaml"), "--out", str(out),
                 "--base", "rmw_zenoh", "--duration", "2", "--no-plots", "--quiet"])
    assert code == main(["run", str(ROOT / "scenarios/thesis-6.3.yaml"), "--out", str(plain),
                         "--duration", "2", "--no-plots", "--quiet"])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["comm"]["classes"]["cmd"]["recv"]["messages"] == 0
    assert summary["world"]["missing_cmds"] == 0 and summary["world"]["malformed_cmds"] == 0
    rows = list(csv.DictReader((out / "robots.csv").read_text().splitlines()))
    ref = list(csv.DictReader((plain / "robots.csv").read_text().splitlines()))
    assert len(rows) == len(ref) > 0
    cols = [c for c in ref[0] if c not in ("ux", "uy")]
    assert [[r[c] for c in cols] for r in rows] == [[r[c] for c in cols] for r in ref]


def test_the_reader_drops_what_rmw_zenoh_drops_and_says_so():
    from simulator.bases import RmwBaseReader

    class Sample:  # what the reader reads of a zenoh.Sample
        def __init__(self, key, payload, attachment):
            self.key_expr, self._payload, self._att = key, payload, attachment

        @property
        def payload(self):
            return type("Z", (), {"to_bytes": lambda _s: self._payload})()

        @property
        def attachment(self):
            return None if self._att is None else type("Z", (), {"to_bytes": lambda _s: self._att})()

    base = plan_bases(["r1"], rmw.RmwSettings(), "jazzy")["r1"]
    got, drops = [], []
    reader = RmwBaseReader({"r1": base}, lambda *a: got.append(a), lambda: drops.append(1))
    payload = encode_cmd(rmw.TWIST_STAMPED, 0.1, 0.0, 3.0)
    reader.callback(Sample(base.key, payload, None))
    reader.callback(Sample(base.key, payload, _att(rmw.KEYED)))
    reader.callback(Sample("0/other/cmd_vel/x/y", payload, _att(rmw.POSITIONAL)))  # not a base
    reader.callback(Sample(base.key, payload, _att(rmw.POSITIONAL)))
    assert reader.dropped == 2 and len(drops) == 2
    assert [(r, c.v, c.stamp, k, n) for r, c, k, n in got] == [("r1", 0.1, 3.0, base.key,
                                                                  len(payload))]
