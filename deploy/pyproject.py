"""What deploy reads of ``pyproject.toml``, on Python 3.10 too (no ``tomllib`` there): the
project's name and version, and setuptools' package list.

Not a TOML parser: a table's keys whose values are one string (``"..."`` or ``'...'``, without
escapes) or an array of such strings (over several lines, with comments) are read; any other
value is left out, so a key that matters and is missing says so (:func:`string`, :func:`strings`).
"""

from __future__ import annotations

import re

_TABLE = re.compile(r"^\[\s*([A-Za-z0-9_.-]+)\s*\]\s*(?:#.*)?$")
_KEY = re.compile(r"^([A-Za-z0-9_-]+)\s*=\s*(.*)$")
# a string (double- or single-quoted, no escapes) or a comment, in the order they come
_TOKEN = re.compile(r""""([^"\\\n]*)"|'([^'\n]*)'|(#[^\n]*)""")


class PyprojectError(ValueError):
    """A field deploy needs is not in ``pyproject.toml`` in a form this reader takes."""


def table(text: str, name: str) -> dict[str, str | list[str]]:
    """The string and string-array keys of the table ``[name]`` of the TOML ``text``."""
    out: dict[str, str | list[str]] = {}
    current = ""
    lines = iter(text.splitlines())
    for raw in lines:
        line = raw.strip()
        header = _TABLE.match(line)
        if header is not None:
            current = header.group(1)
            continue
        key = _KEY.match(line) if current == name else None
        if key is None:
            continue
        value = key.group(2)
        if value.startswith("["):
            while not _closed(value):
                value += "\n" + next(lines, "]")
            out[key.group(1)] = _strings(value)
        else:
            found = _strings(value)
            if len(found) == 1 and value.startswith(("'", '"')):
                out[key.group(1)] = found[0]
    return out


def string(text: str, table_name: str, key: str) -> str:
    """The string ``key`` of ``[table_name]``; :class:`PyprojectError` when it has none."""
    value = table(text, table_name).get(key)
    if not isinstance(value, str):
        raise PyprojectError(f"[{table_name}] has no {key} as a plain string")
    return value


def strings(text: str, table_name: str, key: str) -> list[str]:
    """The string array ``key`` of ``[table_name]``; :class:`PyprojectError` when it has none."""
    value = table(text, table_name).get(key)
    if not isinstance(value, list):
        raise PyprojectError(f"[{table_name}] has no {key} as an array of strings")
    return value


def _strings(value: str) -> list[str]:
    """The strings of ``value``, its comments left out."""
    return [m.group(1) if m.group(1) is not None else m.group(2)
            for m in _TOKEN.finditer(value) if m.group(3) is None]


def _closed(value: str) -> bool:
    """Whether the array ``value`` (from its ``[``) has its closing ``]`` outside strings and
    comments."""
    return "]" in _TOKEN.sub("", value)
