"""The command-line reference of docs/cli.md, written from the real argument parser.

``python -m formation.clidoc --write docs/cli.md`` replaces everything after the marker line of
that file with the reference of every subcommand and option as :func:`formation.cli.build_parser`
defines them; ``tests/test_docs.py`` checks the file is up to date.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from formation.argspec import Argument, Parser
from formation.cli import build_parser

MARKER = "<!-- generated below by: .venv/bin/python -m formation.clidoc --write docs/cli.md -->"


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def _option_row(argument: Argument) -> str:
    action = argument.action
    if action.option_strings:
        names = ", ".join(f"`{s}`" for s in action.option_strings)
        if action.nargs != 0:
            names += f" `{action.metavar or action.dest.upper()}`"
    else:
        names = f"`{action.metavar or action.dest.upper()}`"
    notes = []
    if action.choices is not None:
        notes.append("one of " + ", ".join(f"`{c}`" for c in action.choices))
    if action.required and action.option_strings:
        notes.append("required")
    if argument.kind == "append":
        notes.append("may be given more than once")
    if action.option_strings and action.nargs != 0 and action.default not in (None, argparse.SUPPRESS):
        notes.append(f"default `{action.default}`")
    text = (action.help or "").replace("%(default)s", str(action.default))
    return f"| {names} | {_cell(text)} | {_cell('; '.join(notes))} |"


def _section(name: str, sub: Parser, summary: str) -> list[str]:
    usage = " ".join(sub.format_usage().split())
    usage = usage.removeprefix("usage: ")
    lines = [f"### `formation {name}`", "", _cell(summary) + ("." if summary else ""), "",
             "```text", usage, "```", ""]
    arguments = [a for a in sub.arguments if a.kind != "help"]
    if arguments:
        lines += ["| argument | meaning | notes |", "| --- | --- | --- |"]
        lines += [_option_row(a) for a in arguments]
        lines.append("")
    return lines


def render(parser: Parser | None = None) -> str:
    """The generated part of docs/cli.md."""
    parser = parser or build_parser()
    lines = ["## Every command and option", "",
             "Global options, before the command:", "",
             "| argument | meaning | notes |", "| --- | --- | --- |"]
    lines += [_option_row(a) for a in parser.arguments
              if a.action.option_strings and a.kind != "help"]
    lines.append("")
    for name, command in parser.commands.items():
        lines += _section(name, command.parser, command.help)
    return "\n".join(lines).rstrip() + "\n"


def updated(text: str) -> str:
    """``text`` (docs/cli.md) with the part after :data:`MARKER` regenerated."""
    head, found, _ = text.partition(MARKER)
    if not found:
        raise ValueError(f"docs/cli.md has no marker line {MARKER!r}")
    return head + MARKER + "\n\n" + render()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m formation.clidoc", description=__doc__)
    p.add_argument("--write", metavar="FILE", help="regenerate FILE (docs/cli.md) in place")
    ns = p.parse_args(argv)
    if ns.write:
        path = Path(ns.write)
        path.write_text(updated(path.read_text(encoding="utf-8")), encoding="utf-8")
    else:
        sys.stdout.write(render())
    return 0


if __name__ == "__main__":
    sys.exit(main())
