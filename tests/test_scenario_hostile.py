"""Hostile scenario files (issue 14 item 5): each one gets exit status 2 and one short line from
``formation check`` and ``formation sim``, fast and without reading more than the file-size
limit; loading stays bounded (depth, alias expansion, size) and the validation work grows
linearly with the robots; one name rule is shared by the scenario, the ACL and deploy."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import scenario.load as load_module
from deploy.inventory import InventoryError, parse_inventory
from formation.cli import main
from formation.commands.check import plural
from scenario import ScenarioError, limits, load_scenario, parse_scenario, reader
from scenario.bench import fleet_mapping as fleet
from scenario.reader import MAX_FILE_BYTES, excerpt
from scenario.shipped import shipped_names
from wire import acl, keys

ROOT = Path(__file__).resolve().parents[1]
MAX_LINE = 300  # [characters] "one short line"

GOOD = """\
name: t
dt: 0.05
duration: 60.0
robot: {max_speed: 0.22, radius: 0.105}
controller: {kp: 2.0, gamma: 1.0, epsilon: 0.05}
formations:
  - name: A
    leader: a1
    robots:
      a1: {start: [0.0, 0.0], goal: [4.0, 0.0]}
      a2: {start: [0.5, 0.0], goal: [4.5, 0.0]}
    edges: [[a1, a2, 0.5]]
obstacles:
  - {name: o1, center: [2.0, 0.6], safe_distance: 0.3}
"""


def _bomb() -> str:
    """The classic 'billion laughs' in YAML: 9 levels of 9 aliases, 9**9 leaves expanded."""
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for prev, cur in zip("abcdefgh", "bcdefghi", strict=True):
        lines.append(f"{cur}: &{cur} [{','.join(['*' + prev] * 9)}]")
    return "\n".join(lines) + "\nformations: *i\n"


def _names(robot: str = "a1", formation: str = "A", obstacle: str = "o1") -> str:
    return (GOOD.replace("leader: a1", f"leader: '{robot}'")
            .replace("      a1:", f"      '{robot}':").replace("[[a1,", f"[['{robot}',")
            .replace("name: A", f"name: '{formation}'").replace("name: o1", f"name: '{obstacle}'"))


def _obstacles(n: int) -> str:
    rows = "".join(f"  - {{name: s{k}, center: [{100 + k}.0, 50.0], safe_distance: 0.3}}\n"
                   for k in range(n))
    return GOOD.split("obstacles:")[0] + "obstacles:\n" + rows


# (id, file content as bytes or str, a fragment the one line must hold)
HOSTILE: list[tuple[str, bytes | str, str]] = [
    ("dt 1.0e+300", GOOD.replace("dt: 0.05", "dt: 1.0e+300"), "dt: out of range, got 1e+300"),
    ("dt 1.0e300 (no exponent sign)", GOOD.replace("dt: 0.05", "dt: 1.0e300"),
     "dt: out of range, got 1e+300"),
    ("dt 1e-9", GOOD.replace("dt: 0.05", "dt: 1e-9"), "allowed: from 0.001 to 1 s"),
    ("a million-fold duration", GOOD.replace("duration: 60.0", "duration: 1.0e9"),
     "more than 1,000,000"),
    ("speed of 100 m/s", GOOD.replace("max_speed: 0.22", "max_speed: 100"),
     "robot.max_speed: out of range"),
    ("a start 1e300 m away", GOOD.replace("start: [0.0, 0.0]", "start: [1e300, 0.0]"),
     "robots.a1.start[0]: out of range"),
    ("a heading of 1e6 rad", GOOD.replace("start: [0.0, 0.0]", "start: [0.0, 0.0, 1.0e6]"),
     "heading"),
    ("an obstacle at 1000 m/s", GOOD.replace("safe_distance: 0.3}", "safe_distance: 0.3, "
                                             "velocity: [1000, 0]}"), "velocity[0]: out of range"),
    ("alias bomb", _bomb(), "alias"),
    ("recursive alias", "formations: &x [*x]\n", "recursive alias"),
    ("deep nesting", "formations: " + "[" * 5000 + "]" * 5000 + "\n", "nested more than"),
    ("deep block nesting", "".join(" " * k + "k:\n" for k in range(200)), "nested more than"),
    ("300-digit integer", GOOD.replace("dt: 0.05", "dt: 1" + "0" * 299),
     "an integer of 300 digits"),
    ("300-digit integer as a name", GOOD.replace("name: A", "name: " + "7" * 300),
     "an integer of 300 digits"),
    ("duplicate key", GOOD.replace("duration: 60.0", "duration: 60.0\ndt: 0.1"),
     "duplicate key 'dt' (first at line 2)"),
    ("duplicate robot key", GOOD.replace("      a2:", "      a1: {start: [9, 9], goal: [9, 9]}\n"
                                         "      a2:"), "duplicate key 'a1'"),
    ("Latin-1 file", GOOD.replace("name: t", "name: café").encode("latin-1"), "not UTF-8 text"),
    ("UTF-16 file", GOOD.encode("utf-16"), "looks like UTF-16"),
    ("NUL byte", GOOD.replace("name: t", "name: t\x00"), "not allowed in YAML"),
    ("file over the size limit", GOOD + "#" * MAX_FILE_BYTES + "\n", "bytes"),
    ("a huge value in an error", GOOD.replace("dt: 0.05", "dt: " + "x" * 200_000),
     "dt: must be a number, got 'xxxx"),
    ("a huge unknown key", GOOD.replace("dt: 0.05", "dt: 0.05\n" + "k" * 1000 + ": 1"),
     "unknown key 'kkk"),
    ("robot name with NBSP", _names(robot="a\u00a01"), "not a valid name"),
    ("robot name with U+200B", _names(robot="a\u200b1"), "not a valid name"),
    ("robot name with U+202E", _names(robot="a\u202e1"), "not a valid name"),
    ("robot name of 65 characters", _names(robot="r" * 65), "at most 64 characters"),
    ("robot named camera", _names(robot="camera"), "is reserved"),
    ("robot named manager", _names(robot="manager"), "is reserved"),
    ("robot named viewer", _names(robot="viewer"), "is reserved"),
    ("formation named zone", _names(formation="zone"), "is reserved"),
    ("robot name with a colon", _names(robot="a:1"), "must not contain ':'"),
    ("formation name with U+200B", _names(formation="A\u200b"), "formations[0].name"),
    ("obstacle name with a slash", _names(obstacle="o/1"), "obstacles[0].name"),
    ("257 obstacles", _obstacles(257), "obstacles: 257 entries, more than the 256"),
]


@pytest.fixture(params=[c.__name__ for c in reader.LOADERS])
def loader(request, monkeypatch):
    """Each YAML loader this PyYAML has (pure Python, and libyaml's parser when present)."""
    cls = next(c for c in reader.LOADERS if c.__name__ == request.param)
    monkeypatch.setattr(reader, "LOADER", cls)
    return cls


def _write(tmp_path: Path, content: bytes | str) -> Path:
    p = tmp_path / "hostile.yaml"
    p.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
    return p


def _one_line(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err[:2000]
    assert len(lines[0]) <= MAX_LINE and "Traceback" not in lines[0], lines[0]
    assert captured.out == ""
    return lines[0]


@pytest.mark.parametrize("what,content,fragment", HOSTILE, ids=[h[0] for h in HOSTILE])
def test_every_hostile_scenario_gets_exit_2_and_one_short_line_from_check_and_sim(
        tmp_path, capsys, loader, what, content, fragment):
    path = _write(tmp_path, content)
    assert main(["check", str(path)]) == 2
    line = _one_line(capsys)
    assert fragment in line and str(path) in line
    out = tmp_path / "out"
    assert main(["sim", str(path), "--out", str(out), "--quiet"]) == 2
    assert _one_line(capsys) == line.replace("formation check", "formation sim")
    assert not out.exists()


@pytest.mark.parametrize("target,kind", [("/dev/zero", "a character device"),
                                         (".", "a directory")])
def test_a_device_or_a_directory_is_refused_without_reading_it(capsys, target, kind):
    assert main(["check", target]) == 2
    assert f"not a regular file ({kind})" in _one_line(capsys)


@pytest.mark.integration
@pytest.mark.parametrize("command", ["check", "sim"])
def test_a_fifo_is_refused_at_once_without_waiting_for_a_writer(tmp_path, command):
    fifo = tmp_path / "scenario.yaml"
    os.mkfifo(fifo)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    argv = [sys.executable, "-m", "formation", command, str(fifo)]
    if command == "sim":
        argv += ["--out", str(tmp_path / "out")]
    proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a regular file (a FIFO)" in lines[0]


def test_yaml_1_2_floats_are_numbers_and_everything_else_reads_as_before(loader):
    s = parse_scenario(GOOD.replace("dt: 0.05", "dt: 5e-2").replace("duration: 60.0",
                                                                       "duration: 1.2E2"))
    assert (s.dt, s.duration) == (0.05, 120.0)
    data = load_module.load_yaml("a: 1e5\nb: 1.0e300\nc: .5e1\nd: -2e-3\ne: '1e5'\nf: 1.5\n"
                                 "g: 12\nh: e5\ni: 1e\nj: 2024-01-01\n")
    assert data["a"] == 1e5 and data["b"] == 1e300 and data["c"] == 5.0 and data["d"] == -2e-3
    assert data["e"] == "1e5" and data["f"] == 1.5 and data["g"] == 12
    assert data["h"] == "e5" and data["i"] == "1e"
    for path in sorted((ROOT / "scenarios").glob("*.yaml")) + sorted(
            (ROOT / "tests/scenarios").glob("*.yaml")):
        assert load_module.load_yaml(path.read_text(encoding="utf-8")) == yaml.safe_load(
            path.read_text(encoding="utf-8")), path


def test_anchors_and_aliases_within_the_limits_are_fine(loader):
    text = GOOD.replace("controller: {kp", "controller: &c {kp") + "x_unused: 0\n"
    with pytest.raises(ScenarioError, match="unknown key 'x_unused'"):
        parse_scenario(text)
    shared = GOOD.replace("      a1: {start: [0.0, 0.0], goal: [4.0, 0.0]}",
                          "      a1: {start: &s0 [0.0, 0.0], goal: [4.0, 0.0]}")
    assert parse_scenario(shared).robots[0].start[:2] == (0.0, 0.0)
    merged = "base: &b {x: 1, y: 2}\nother: {<<: *b, y: 3}\n"
    assert load_module.load_yaml(merged)["other"] == {"x": 1, "y": 3}  # a merge is not a duplicate


def test_an_alias_bomb_fails_after_little_work(loader):
    text = _bomb()
    assert len(text.encode()) < 700
    calls = 0
    orig = loader.construct_object

    def counting(self, node, deep=False):
        nonlocal calls
        calls += 1
        return orig(self, node, deep)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(loader, "construct_object", counting)
        with pytest.raises(ScenarioError, match="more than 1000000 values once aliases"):
            parse_scenario(text)
    assert calls == 0  # refused while composing, before anything was built


def test_error_excerpts_stay_short_whatever_the_value():
    nested: list = []
    for _ in range(50):
        nested = [nested] * 50  # shares itself: huge if printed in full
    assert len(excerpt(nested)) < 100
    assert len(excerpt("y" * 10**6)) < 100 and "1000000 characters" in excerpt("y" * 10**6)
    assert len(excerpt(10**299)) < 100


def test_the_limits_table_in_the_docs_is_the_one_the_code_applies():
    doc = (ROOT / "docs" / "scenarios.md").read_text(encoding="utf-8")
    assert limits.describe() in doc


def test_numbers_at_the_edges_of_their_ranges_are_accepted():
    s = parse_scenario(GOOD.replace("dt: 0.05", "dt: 0.001").replace("duration: 60.0",
                                                                        "duration: 1000.0"))
    assert s.steps == 1_000_000
    s = parse_scenario(GOOD.replace("dt: 0.05", "dt: 1").replace("max_speed: 0.22", "max_speed: 5"))
    assert (s.dt, s.robot.max_speed) == (1.0, 5.0)
    with pytest.raises(ScenarioError, match="more than 1,000,000"):
        parse_scenario(GOOD.replace("dt: 0.05", "dt: 0.001").replace("duration: 60.0",
                                                                       "duration: 1000.01"))


# ------------------------------------------------------------------------- one name rule

_NAME_CHARS = st.one_of(st.sampled_from(list("ab1_-.:/*$#? \t\u00a0\u200b\u202e\u00e9")),
                        st.characters())


@settings(max_examples=200, deadline=None)
@given(name=st.one_of(st.text(_NAME_CHARS, min_size=0, max_size=70),
                      st.sampled_from(["camera", "r" * 64, "r" * 65, "a:b", "ok-name.1"])))
def test_a_name_the_scenario_accepts_is_one_run_and_deploy_accept(name):
    text = _names(robot="R0").replace("'R0'", yaml.safe_dump(name, default_style='"', width=10**6).strip())
    try:
        s = parse_scenario(text)
    except ScenarioError as exc:
        accepted = False
        assert "\n" not in str(exc)
    else:
        accepted = True
        assert s.robot_ids[0] == name
    assert accepted == (keys.name_problem(name) is None)
    if accepted:
        keys.pose_key("warehouse", name)  # run: the keys and the ACL take it
        acl.fleet_acl({name: "A"}, {"A": name})
        acl.new_credentials([acl.CAMERA_USER, name])
    inv = {"zenoh": {"router": "tcp/10.0.0.1:7447"},
           "robots": [{"id": name, "host": "10.0.0.2", "user": "u", "key": "k"}]}
    try:
        parse_inventory(inv, ROOT / "inv.yaml")
    except InventoryError:
        assert not accepted
    else:
        assert accepted


# ------------------------------------------------------------------------- linear work


def test_validation_work_grows_linearly_with_the_robots(monkeypatch):
    """Counts the inner checks between robots (pair distances and ellipse tests) and the robot
    lookups by id: 4 times the robots is at most about 4 times the work."""
    work = {"pairs": 0, "ellipse": 0, "lookups": 0}
    closer, ellipse_value = load_module.closer, load_module.ellipse_value
    spec = load_module.Scenario.robot_spec

    def count(key, fn):
        def wrapped(*args, **kwargs):
            work[key] += 1
            return fn(*args, **kwargs)
        return wrapped

    monkeypatch.setattr(load_module, "closer", count("pairs", closer))
    monkeypatch.setattr(load_module, "ellipse_value", count("ellipse", ellipse_value))
    monkeypatch.setattr(load_module.Scenario, "robot_spec", count("lookups", spec))
    totals = {}
    for n in (200, 800):
        work.update(pairs=0, ellipse=0, lookups=0)
        s = load_module.scenario_from_dict(fleet(n))
        assert len(s.robots) == n
        totals[n] = dict(work)
    assert totals[200]["pairs"] > 0 and totals[200]["ellipse"] > 0  # both checks ran
    for key in work:
        assert totals[800][key] <= 4.5 * max(totals[200][key], 1), (key, totals)
        assert totals[800][key] <= 20 * 800, (key, totals)  # a bounded amount per robot


def test_overlapping_starts_are_still_found_by_the_grid():
    d = fleet(8)
    # 0.14 m from f0r1 at (0.5, 0), in the next cell of the 0.21 m grid
    d["formations"][1]["robots"]["f1r0"]["start"] = [0.64, -0.0]
    with pytest.raises(ScenarioError, match="robots 'f0r1' and 'f1r0' start 0.140 m apart"):
        load_module.scenario_from_dict(d)
    d = fleet(8)
    assert math.isclose(load_module.scenario_from_dict(d).robots[4].start[0], 1.2)


def test_a_start_inside_another_formations_ellipse_is_found_by_the_grid():
    d = fleet(128)
    d["formations"].append({"name": "intruder", "leader": "x1",
                            "robots": {"x1": {"start": [12.25, 1.525], "goal": [12.25, 90.0]},
                                       "x2": {"start": [12.25, 1.025], "goal": [12.25, 89.5]}},
                            "edges": [["x1", "x2"]]})
    with pytest.raises(ScenarioError, match="inside the ellipse of formation 'f26'"):
        load_module.scenario_from_dict(d)


def test_load_scenario_reports_a_missing_file_in_one_line(tmp_path):
    with pytest.raises(ScenarioError, match=r"missing\.yaml: no such file$"):
        load_scenario(tmp_path / "missing.yaml")


# ------------------------------------------------------------------------- --out (issue 12)


def test_an_out_that_is_a_file_or_under_a_file_is_exit_2_before_any_work(tmp_path, capsys):
    scenario_file = _write(tmp_path, GOOD)
    a_file = tmp_path / "taken"
    a_file.write_text("x")
    for out, fragment in ((a_file, "exists and is not a folder"),
                          (a_file / "sub", "is not a folder")):
        for argv in (["sim", str(scenario_file), "--out", str(out), "--quiet"],
                     ["run", str(scenario_file), "--out", str(out), "--quiet"],
                     ["montecarlo", "--n", "1", "--out", str(out)]):
            assert main(argv) == 2
            line = _one_line(capsys)
            assert "--out" in line and fragment in line
    assert a_file.read_text() == "x"


def test_an_out_on_a_read_only_place_is_exit_2(tmp_path, capsys):
    scenario_file = _write(tmp_path, GOOD)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        probe = locked / "probe"
        try:
            probe.write_text("x")  # root may write anyway: then only /proc is left to try
            probe.unlink()
            out = Path("/proc/formation-out-check")
        except OSError:
            out = locked
        assert main(["sim", str(scenario_file), "--out", str(out), "--quiet"]) == 2
        line = _one_line(capsys)
        assert "--out" in line and ("not writable" in line or "cannot be created" in line)
    finally:
        locked.chmod(0o700)


def test_a_valid_out_is_accepted_and_not_created_by_the_check(tmp_path):
    from formation.outdir import out_problem

    assert out_problem(tmp_path / "new" / "deeper") is None
    assert not (tmp_path / "new").exists()
    assert out_problem(tmp_path) is None
    assert list(tmp_path.iterdir()) == []  # the write probe left nothing


def test_a_start_too_near_an_obstacle_names_the_safe_distance_and_the_look_ahead_apart(tmp_path):
    text = (ROOT / "scenarios" / "thesis-6.5.yaml").read_text()
    text += "obstacles:\n  - {name: crate, center: [0.3, 0.25], safe_distance: 0.3}\n"
    with pytest.raises(ScenarioError) as err:
        parse_scenario(text)
    msg = str(err.value)
    # a1's control point is 0.05 m ahead of (0, 0.25): 0.25 m from the crate
    assert ("robot 'a1' starts 0.250 m from obstacle 'crate', inside its safe distance 0.300 m "
            "plus the look-ahead 0.050 m") in msg, msg


def test_check_counts_in_the_right_number(tmp_path, capsys):
    assert [plural(1, "formation"), plural(2, "obstacle"), plural(0, "robot")] == [
        "1 formation", "2 obstacles", "0 robots"]


@pytest.mark.parametrize("name", ["thesis-5.2.3", "thesis-5.2.3.yaml", "scenarios/thesis-5.2.3.yaml"])
def test_a_name_that_is_no_file_nor_shipped_scenario_says_so_and_names_the_shipped_ones(capsys, name):
    assert main(["check", name]) == 2
    line = _one_line(capsys)
    assert line.startswith(f"formation check: error: {name}: no such file, nor a shipped scenario")
    assert all(shipped in line for shipped in shipped_names()) and "thesis-5.2.2" in line


def test_a_missing_path_that_is_not_a_bare_name_is_only_no_such_file(tmp_path, capsys):
    path = tmp_path / "nowhere" / "thesis-5.2.3.yaml"
    assert main(["check", str(path)]) == 2
    assert _one_line(capsys) == f"formation check: error: {path}: no such file"
