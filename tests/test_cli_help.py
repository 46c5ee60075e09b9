"""The command line's own contract (issue 12): every argument says what it is and its default,
``--version`` comes from the installed package, ``run --solver`` reaches the agents like
``sim --solver``, and ``deploy --dry-run`` checks the SSH keys."""

from __future__ import annotations

import argparse
import json
import signal
from importlib.metadata import version
from pathlib import Path

import pytest
import yaml

from agent.config import build_agent_configs, config_from_dict, config_to_dict
from formation.cli import build_parser, main
from formation.commands.run import LaterInterruptsWait
from scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "tests" / "scenarios" / "two-small.yaml"


def _shown(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """The help ``parser`` prints for ``action``, its option strings left out."""
    formatter = parser.formatter_class(prog=parser.prog)
    formatter.add_argument(action)
    shown = formatter.format_help()
    for option in action.option_strings:
        shown = shown.replace(option, "")
    return " ".join(shown.split())


def test_every_argument_of_every_subcommand_has_help_text_and_its_default():
    parser = build_parser()
    missing, no_default = [], []
    commands = {name: c.parser for name, c in parser.commands.items()}
    assert {"check", "sim", "run", "commcost", "montecarlo", "bench", "deploy", "view", "record",
            "replay"} <= set(commands)
    for name, sub in [("formation", parser), *commands.items()]:
        for argument in sub.arguments:
            action = argument.action
            if not (action.help or "").strip():
                missing.append(f"{name} {'/'.join(action.option_strings) or action.dest}")
                continue
            has_default = action.option_strings and not action.required and not any(
                action.default is v for v in (None, False, argparse.SUPPRESS))
            if has_default and "default" not in _shown(sub, action).lower():
                no_default.append(f"{name} {action.option_strings[0]}")
    assert missing == [] and no_default == []
    for name, command in parser.commands.items():
        assert command.help.strip(), name


def test_the_parser_keeps_every_argument_argparse_has():
    """formation.argspec's record is complete: the same actions argparse's own help shows."""
    parser = build_parser()
    for sub in [parser, *(c.parser for c in parser.commands.values())]:
        shown = sub.format_help()
        for argument in sub.arguments:
            for option in argument.action.option_strings:
                assert option in shown, (sub.prog, option)
        options = {o for a in sub.arguments for o in a.action.option_strings}
        assert {w.strip("[],|") for w in sub.format_usage().split() if w.startswith("[-")} <= options


def test_help_shows_defaults(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["montecarlo", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "(default: 40)" in out and "(default: 11)" in out and "--force" in out


def test_version_comes_from_the_package_metadata(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"formation {version('formation-cbf')}"


def test_the_solver_goes_into_the_agent_configs_and_exact_files_stay_as_they_were():
    scenario = load_scenario(SCENARIO)
    exact = build_agent_configs(scenario)
    osqp = build_agent_configs(scenario, solver="osqp")
    assert all(c.solver == "exact" for c in exact.values())
    assert "solver" not in config_to_dict(exact["a1"])
    d = config_to_dict(osqp["a1"])
    assert d["solver"] == "osqp"
    assert config_from_dict(yaml.safe_load(yaml.safe_dump(d))) == osqp["a1"]


def test_run_with_an_unknown_solver_is_exit_2_before_anything_starts(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", str(SCENARIO), "--out", str(out), "--solver", "nonesuch", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "nonesuch" in err and "\n" not in err
    assert not out.exists()


@pytest.mark.integration
def test_run_with_a_qpsolvers_backend_runs_the_agents_on_it(tmp_path):
    out = tmp_path / "o"
    before = signal.getsignal(signal.SIGINT)
    assert main(["run", str(SCENARIO), "--out", str(out), "--solver", "osqp", "--quiet",
                 "--no-plots"]) == 0
    # called from Python, the run leaves SIGINT as it found it (an ignored one was inherited by
    # every process the tests started later: formation replay never stopped on Ctrl-C)
    assert signal.getsignal(signal.SIGINT) is before
    summary = json.loads((out / "summary.json").read_text())
    assert summary["solver"] == "osqp" and summary["all_reached"] and summary["collisions"] == 0
    assert yaml.safe_load((out / "configs" / "a1.yaml").read_text())["solver"] == "osqp"


@pytest.mark.parametrize("whole_process", [False, True])
def test_an_interrupted_run_ignores_sigint_on_its_way_out_only_as_the_whole_program(whole_process):
    before = signal.getsignal(signal.SIGINT)
    try:
        with LaterInterruptsWait(whole_process) as interrupts:
            assert signal.getsignal(signal.SIGINT) not in (before, signal.SIG_IGN)
            interrupts.run_over()  # the run's files are being written: Ctrl-C only hurries
        after = signal.getsignal(signal.SIGINT)
        assert after is (signal.SIG_IGN if whole_process else before)
    finally:
        signal.signal(signal.SIGINT, before)
    with LaterInterruptsWait(whole_process):  # never interrupted: put back as it was
        pass
    assert signal.getsignal(signal.SIGINT) is before


DEPLOY_SCENARIO = """\
name: deploy-pair
dt: 0.05
duration: 10.0
robot: {max_speed: 0.22, radius: 0.105}
controller: {kp: 2.0, gamma: 1.0, epsilon: 0.05}
formations:
  - name: P
    leader: r1
    robots:
      r1: {start: [0.0, 0.0], goal: [1.0, 0.0]}
      r2: {start: [0.0, 0.5], goal: [1.0, 0.5]}
    edges: [[r1, r2]]
"""


def _deploy_files(tmp_path: Path, key: str) -> tuple[Path, Path]:
    scen = tmp_path / "s.yaml"
    scen.write_text(DEPLOY_SCENARIO)
    inv = tmp_path / "inv.yaml"
    inv.write_text(yaml.safe_dump({
        "base": "turtlebot3-humble",
        "zenoh": {"router": "tcp/192.168.0.10:7447", "mode": "client"},
        "defaults": {"user": "ubuntu", "key": key},
        "robots": [{"id": "r1", "host": "192.168.0.21"}, {"id": "r2", "host": "192.168.0.22"}],
    }, sort_keys=False))
    return inv, scen


def test_deploy_dry_run_with_a_missing_ssh_key_is_exit_2_naming_it(tmp_path, capsys):
    inv, scen = _deploy_files(tmp_path, "no-such-key")
    assert main(["deploy", str(inv), str(scen), "--dry-run"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "SSH key" in err and str(tmp_path / "no-such-key") in err
    assert "'r1'" in err


def test_deploy_dry_run_with_the_key_present_prints_the_plan(tmp_path, capsys):
    inv, scen = _deploy_files(tmp_path, "id_test")
    (tmp_path / "id_test").write_text("not a real key; a dry run never uses it\n")
    assert main(["deploy", str(inv), str(scen), "--dry-run"]) == 0
    assert "dry run: 2 robots planned" in capsys.readouterr().out
