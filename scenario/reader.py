"""Bounded reading of a scenario file: from a path to plain Python data, or one ScenarioError.

A scenario file comes from anybody, so reading it must stay cheap whatever it holds:

* the path must name a regular file (a FIFO, ``/dev/zero``, a directory or a socket is refused
  without reading: the file is opened non-blocking and its type checked on the open descriptor);
* at most :data:`MAX_FILE_BYTES` bytes are read, and the text must be UTF-8 (an optional BOM
  is allowed); Latin-1 or UTF-16 files are refused naming the first bad byte's offset;
* :class:`ScenarioLoader`, our :class:`yaml.SafeLoader`, nests at most :data:`MAX_DEPTH`
  collections, counts every node an alias re-uses so that the document *as expanded* holds at
  most :data:`MAX_NODES` nodes (a 676-byte alias bomb stops at the first alias over the limit),
  refuses recursive aliases, duplicate keys (naming the key and both lines) and integers with
  more than :data:`MAX_INT_DIGITS` digits, and reads YAML 1.2 floats such as ``1e5`` and
  ``1.0e300`` as numbers (PyYAML's YAML 1.1 resolver reads them as text);
* every message is one line and quotes at most an :func:`excerpt` of a value.

Files that were valid before read the same: only plain scalars that YAML 1.1 left as text and
that look like a number with an exponent change type.
"""

from __future__ import annotations

import errno
import os
import re
import reprlib
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from yaml.constructor import SafeConstructor as _SafeConstructor
from yaml.nodes import MappingNode, Node, ScalarNode

MAX_FILE_BYTES = 1 << 20  # [bytes] 1 MiB: ten times a 1,000-robot fleet written out in full
MAX_DEPTH = 32  # nested collections; a scenario needs 6
MAX_NODES = 1_000_000  # YAML nodes of the document with every alias expanded
MAX_INT_DIGITS = 20  # every integer a scenario needs has fewer
EXCERPT_CHARS = 40  # longest quote of a value in a message
MAX_MESSAGE_CHARS = 400  # longest message (a guard: the parts are short already)


class ScenarioError(ValueError):
    """An invalid scenario; the message is one line naming the culprit."""

    def __init__(self, message: str) -> None:
        super().__init__(one_line(message))


def one_line(text: str, limit: int = MAX_MESSAGE_CHARS) -> str:
    """``text`` with control characters (newlines included) shown escaped, cut to ``limit``."""
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return out if len(out) <= limit else out[: limit - 3] + "..."


_REPR = reprlib.Repr()
_REPR.maxstring = EXCERPT_CHARS
_REPR.maxother = EXCERPT_CHARS
_REPR.maxlong = EXCERPT_CHARS
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = 4
_REPR.maxlevel = 2


def excerpt(value: object) -> str:
    """A short ``repr`` of any value: strings, numbers and nested collections are cut with
    ``...`` (bounded work and length even for a structure that shares itself many times)."""
    if isinstance(value, str) and len(value) > EXCERPT_CHARS:
        return one_line(repr(value[:EXCERPT_CHARS])[:-1] + f"...' ({len(value)} characters)")
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**18:
        return f"an integer of {len(str(abs(value)))} digits"
    return one_line(_REPR.repr(value), 2 * EXCERPT_CHARS)


# ------------------------------------------------------------------------------ the file


def read_text(path: str | os.PathLike[str]) -> str:
    """The UTF-8 text of the regular file at ``path``, at most :data:`MAX_FILE_BYTES` bytes."""
    p = Path(path)
    try:
        # O_NONBLOCK: opening a FIFO does not wait for a writer; a regular file ignores it.
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot read: {exc.strerror or exc}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ScenarioError(f"{p}: not a regular file ({_file_kind(st.st_mode)})")
        if st.st_size > MAX_FILE_BYTES:
            raise ScenarioError(f"{p}: {st.st_size} bytes, more than the {MAX_FILE_BYTES} a "
                                f"scenario file may have")
        chunks, size = [], 0
        while size <= MAX_FILE_BYTES:
            try:
                chunk = os.read(fd, MAX_FILE_BYTES + 1 - size)
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                    raise ScenarioError(f"{p}: cannot read: it would block") from None
                raise ScenarioError(f"{p}: cannot read: {exc.strerror or exc}") from None
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > MAX_FILE_BYTES:
            raise ScenarioError(f"{p}: more than the {MAX_FILE_BYTES} bytes a scenario file "
                                f"may have (it grew while being read)")
    finally:
        os.close(fd)
    return decode(b"".join(chunks), str(p))


def decode(data: bytes, source: str) -> str:
    """UTF-8 (with or without a BOM) or one line naming the first byte that is not."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        hint = ""
        if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
            hint = " (it looks like UTF-16)"
        raise ScenarioError(
            f"{source}: not UTF-8 text: byte 0x{data[exc.start]:02x} at offset {exc.start}{hint};"
            f" save the file as UTF-8"
        ) from None


def _file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a plain file"


# ------------------------------------------------------------------------------ the loader


class LimitError(yaml.MarkedYAMLError):
    """A document beyond one of this module's limits (reported like a YAML error)."""


_INT_TAG = "tag:yaml.org,2002:int"
_FLOAT_TAG = "tag:yaml.org,2002:float"
_MERGE_TAG = "tag:yaml.org,2002:merge"
# YAML 1.2 floats with an exponent whose sign or fraction YAML 1.1 requires: 1e5, 1.0e300, .5E3
_FLOAT_12 = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)[eE][-+]?[0-9]+$")


if TYPE_CHECKING:  # the mixin's methods run on a SafeLoader; tell the type checker so
    _LoaderBase = yaml.SafeLoader
else:
    _LoaderBase = object


class _Limits(_LoaderBase):
    """The limits of the module docstring, as overrides of PyYAML's composer and constructor
    (mixed into a loader ahead of them)."""

    def _init_limits(self) -> None:
        self._depth = 0
        self._nodes = 0  # nodes so far, every alias counted as the nodes it stands for
        self._sizes: dict[int, int] = {}  # id(node) -> expanded size, for finished nodes

    def compose_node(self, parent: Node | None, index: Any) -> Node | None:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            node = self.anchors.get(event.anchor)
            if node is not None:
                size = self._sizes.get(id(node))
                if size is None:
                    raise LimitError(None, None, f"recursive alias *{event.anchor[:EXCERPT_CHARS]}"
                                     " (an anchor used inside itself)", event.start_mark)
                self._count(size, event.start_mark)
            return super().compose_node(parent, index)
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise LimitError(None, None, f"nested more than {MAX_DEPTH} levels deep",
                             self.peek_event().start_mark)
        before = self._nodes
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if node is not None:
            self._count(1, node.start_mark)
            self._sizes[id(node)] = self._nodes - before
        return node

    def _count(self, n: int, mark: yaml.Mark) -> None:
        self._nodes += n
        if self._nodes > MAX_NODES:
            raise LimitError(None, None, f"more than {MAX_NODES} values once aliases are "
                             "expanded (an alias bomb?)", mark)

    def construct_mapping(self, node: MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, MappingNode):
            first: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE_TAG:
                    continue
                key = self.construct_object(key_node, deep=False)
                try:
                    line = first.get(key)
                except TypeError:  # unhashable: the base class says so
                    continue
                if line is not None:
                    raise LimitError(None, None, f"duplicate key {excerpt(key)} (first at line "
                                     f"{line + 1})", key_node.start_mark)
                first[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep=deep)

    def construct_yaml_int(self, node: ScalarNode) -> int:
        text = self.construct_scalar(node)
        digits = sum(c.isalnum() for c in text)
        if digits > MAX_INT_DIGITS:
            raise LimitError(None, None, f"an integer of {digits} digits (at most "
                             f"{MAX_INT_DIGITS})", node.start_mark)
        return _SafeConstructor.construct_yaml_int(self, node)


class ScenarioLoader(_Limits, yaml.SafeLoader):
    """:class:`yaml.SafeLoader` with the limits of the module docstring (pure Python)."""

    def __init__(self, stream: str) -> None:
        yaml.SafeLoader.__init__(self, stream)
        self._init_limits()


_LOADERS: list[Any] = [ScenarioLoader]

if getattr(yaml, "__with_libyaml__", False):
    from yaml._yaml import CParser
    from yaml.composer import Composer
    from yaml.constructor import SafeConstructor
    from yaml.resolver import Resolver

    class FastScenarioLoader(_Limits, CParser, Composer, SafeConstructor, Resolver):
        """:class:`ScenarioLoader` with libyaml's parser: libyaml turns the text into events
        (iteratively, without recursion), and the same Python composer, limits, constructor
        and resolver as :class:`ScenarioLoader` build the data, at well under half the CPU of the
        pure-Python parser (docs/performance.md, "What bounds it")."""

        def __init__(self, stream: str) -> None:
            CParser.__init__(self, stream)
            Composer.__init__(self)
            SafeConstructor.__init__(self)
            Resolver.__init__(self)
            self._init_limits()

        # CParser composes in C, which these limits cannot watch: compose in Python instead.
        check_node = Composer.check_node
        get_node = Composer.get_node
        get_single_node = Composer.get_single_node
        compose_document = Composer.compose_document

    _LOADERS.append(FastScenarioLoader)

for _loader in _LOADERS:
    _loader.add_constructor(_INT_TAG, _Limits.construct_yaml_int)
    _loader.add_implicit_resolver(_FLOAT_TAG, _FLOAT_12, list("-+0123456789."))

# libyaml's scanner in PyYAML 6.0.4's wheels (FastScenarioLoader's parser) stops a flow
# collection nested 1,000 deep with this problem while it reads ahead, before the composer's
# MAX_DEPTH sees it
_LIBYAML_DEPTH = "exceeded maximum nesting depth"

#: The loader :func:`load_yaml` uses: libyaml's parser when PyYAML has it.
LOADER: type[yaml.SafeLoader] = _LOADERS[-1]
LOADERS: tuple[type, ...] = tuple(_LOADERS)


def load_yaml(text: str, source: str = "<scenario>") -> Any:
    """Parse one YAML document with :data:`LOADER`; ScenarioError with one line."""
    if len(text) > MAX_FILE_BYTES:
        raise ScenarioError(f"{source}: {len(text)} characters, more than the {MAX_FILE_BYTES}"
                            " a scenario may have")
    loader = None
    try:
        loader = LOADER(text)  # the pure-Python reader checks every character here
        return loader.get_single_data()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = exc.problem or exc.context or "invalid YAML"
        kind = "YAML syntax error" if not isinstance(exc, LimitError) else "refused"
        if _LIBYAML_DEPTH in problem:  # libyaml's own limit (1,000 levels) met before ours
            kind, problem = "refused", f"nested more than {MAX_DEPTH} levels deep"
        raise ScenarioError(f"{source}: {kind}{where}: {problem}") from None
    except yaml.reader.ReaderError as exc:  # a character YAML does not allow
        ch = exc.character
        ch = f"U+{ch:04X}" if isinstance(ch, int) else excerpt(ch)
        raise ScenarioError(f"{source}: YAML syntax error: character {ch} at offset "
                            f"{exc.position} is not allowed in YAML") from None
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{source}: YAML syntax error: {exc}") from None
    except RecursionError:  # a guard: MAX_DEPTH keeps the composer far from the limit
        raise ScenarioError(f"{source}: refused: nested too deeply") from None
    finally:
        if loader is not None:
            loader.dispose()
