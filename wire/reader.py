"""Reading a payload of the Zenoh serialization format, defensively (:mod:`wire.payloads`).

Decoding is plain Python over the bytes, NOT ``zenoh.ext.z_deserialize``: zenoh-python 1.10's
``z_deserialize`` reserves a string's memory from the length the payload claims before checking
it against the payload, so a 9-byte payload claiming a 2**35-byte string aborts the whole process
("memory allocation of 34359738368 bytes failed"), which no Python ``except`` can catch. Here
every length and count is checked against what is left of the payload before anything is read.

:class:`Reader` is the cursor (``f64`` runs, LEB128 varints, strings, counts, ``(id, f64 * k)``
items, point lists); :func:`decode_payload` checks a payload's size and version byte and runs a
message's parser over it, turning every failure into a :class:`DecodeError`.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Iterator, Mapping
from typing import Any, TypeAlias

import zenoh

WIRE_VERSION = 1  # the version byte of every payload kind's first layout
MAX_POINTS = 64  # most points one ellipse carries (scenario.limits.MAX_FORMATION_ROBOTS)
# A payload longer than this is rejected before parsing [bytes]. The largest valid message (an
# Others with 256 + 1 ellipses whose ids are 64 four-byte UTF-8 characters, each with 64
# points and headings) is about 480 kB.
MAX_PAYLOAD_BYTES = 524288
MAX_VARINT_BYTES = 10  # an unsigned LEB128 u64 takes at most 10 bytes
FLOATS = {n: struct.Struct(f"<{n}d") for n in range(1, 10)}  # the format of n f64

Item: TypeAlias = tuple[str, tuple[float, ...]]  # a decoded (id, floats) entry
Points = tuple[tuple[tuple[float, float], ...], tuple[float, ...]]  # an ellipse's points, headings


class DecodeError(ValueError):
    """A payload that is not a valid message of the expected kind."""


@functools.lru_cache(maxsize=MAX_POINTS)
def _pairs(n: int) -> struct.Struct:
    """The format of ``n`` points (2 n f64)."""
    return struct.Struct(f"<{2 * n}d")


@functools.lru_cache(maxsize=MAX_POINTS)
def _singles(n: int) -> struct.Struct:
    """The format of ``n`` headings (n f64)."""
    return struct.Struct(f"<{n}d")


def as_bytes(payload: object) -> bytes:
    """The bytes of a payload (bytes, a buffer or ``zenoh.ZBytes``); :class:`DecodeError` for
    anything else."""
    if isinstance(payload, bytes):
        return payload
    if isinstance(payload, bytearray | memoryview):
        return bytes(payload)
    if isinstance(payload, zenoh.ZBytes):
        return payload.to_bytes()
    raise DecodeError(f"payload must be bytes or zenoh.ZBytes, got {type(payload).__name__}")


class Reader:
    """A cursor over one payload; every read checks the bytes it needs are there."""

    __slots__ = ("data", "pos")

    def __init__(self, data: bytes, pos: int) -> None:
        self.data = data
        self.pos = pos

    def _need(self, n: int, what: str) -> None:
        if n > len(self.data) - self.pos:
            raise DecodeError(
                f"truncated: {what} needs {n} bytes at offset {self.pos}, "
                f"{len(self.data) - self.pos} left"
            )

    def floats(self, n: int, what: str) -> tuple[float, ...]:
        fmt = FLOATS[n]
        self._need(fmt.size, what)
        values = fmt.unpack_from(self.data, self.pos)
        self.pos += fmt.size
        return values

    def u8(self, what: str) -> int:
        """One unsigned byte."""
        self._need(1, what)
        value = self.data[self.pos]
        self.pos += 1
        return value

    def varint(self, what: str) -> int:
        value = 0
        for index in range(MAX_VARINT_BYTES):
            self._need(1, what)
            byte = self.data[self.pos]
            self.pos += 1
            value |= (byte & 0x7F) << (7 * index)
            if not byte & 0x80:
                if byte == 0 and index > 0:
                    raise DecodeError(f"non-canonical varint for {what}")
                return value
        raise DecodeError(f"varint for {what} longer than {MAX_VARINT_BYTES} bytes")

    def string(self, what: str) -> str:
        n = self.varint(what)
        self._need(n, what)
        raw = self.data[self.pos : self.pos + n]
        self.pos += n
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise DecodeError(f"{what} is not valid UTF-8") from None

    def count(self, what: str, limit: int) -> int:
        n = self.varint(what)
        if n > limit:
            raise DecodeError(f"{what} must hold at most {limit} entries, got {n}")
        return n

    def _id_and_floats(self, fmt: struct.Struct) -> tuple[str, tuple[float, ...]] | None:
        """The usual case of an ``(id:str, f64 * k)`` item, read in one go: a one-byte length,
        valid UTF-8 and every byte present. ``None`` (nothing consumed) for anything else,
        which the caller then reads field by field, with the checks and messages of
        :meth:`string` and :meth:`floats`."""
        data, pos = self.data, self.pos
        if pos >= len(data) or data[pos] & 0x80:
            return None
        start = pos + 1 + data[pos]
        end = start + fmt.size
        if end > len(data):
            return None
        try:
            ident = data[pos + 1 : start].decode("utf-8")
        except UnicodeDecodeError:
            return None
        self.pos = end
        return ident, fmt.unpack_from(data, start)

    def item(self, fmt: struct.Struct, name: str, index: int | None, id_field: str) -> Item:
        """An ``(id:str, f64 * k)`` item; ``name[index]`` names it and ``id_field`` its id in
        error messages."""
        item = self._id_and_floats(fmt)
        if item is not None:
            return item
        what = name if index is None else f"{name}[{index}]"
        ident = self.string(f"{what}.{id_field}")
        return ident, self.floats(fmt.size // 8, what)

    def points(self, name: str, index: int | None = None) -> Points:
        """An ellipse's ``points:list[(x, y)]`` and ``headings:list[f64]`` (no headings, or one
        per point; at most :data:`MAX_POINTS`)."""
        fast = self._points_in_one_go()
        if fast is not None:
            return fast
        what = (name if index is None else f"{name}[{index}]") + ".points"
        n = self.count(what, MAX_POINTS)
        pts: tuple[tuple[float, float], ...] = ()
        if n:
            fmt = _pairs(n)
            self._need(fmt.size, what)
            values = fmt.unpack_from(self.data, self.pos)
            self.pos += fmt.size
            pts = tuple(zip(values[0::2], values[1::2], strict=True))
        what = (name if index is None else f"{name}[{index}]") + ".headings"
        k = self.count(what, MAX_POINTS)
        if k not in (0, n):
            raise DecodeError(f"{what}: {k} headings for {n} points")
        if not k:
            return pts, ()
        fmt = _singles(k)
        self._need(fmt.size, what)
        hs = fmt.unpack_from(self.data, self.pos)
        self.pos += fmt.size
        return pts, hs

    def _points_in_one_go(self) -> Points | None:
        """The usual case of :meth:`points`, read in one go: one-byte counts (at most
        :data:`MAX_POINTS` points, as many headings or none) and every byte present. ``None``
        (nothing consumed) for anything else, which :meth:`points` then reads step by step, with
        its checks and messages."""
        data, pos = self.data, self.pos
        size = len(data)
        if pos >= size:
            return None
        n = data[pos]
        heads = pos + 1 + 16 * n  # where the headings' count is
        if n > MAX_POINTS or heads >= size:  # (a count byte of 0x80 or more exceeds MAX_POINTS)
            return None
        k = data[heads]
        stop = heads + 1 + 8 * k
        if (k != n and k != 0) or stop > size:
            return None
        pts: tuple[tuple[float, float], ...] = ()
        if n:
            values = _pairs(n).unpack_from(data, pos + 1)
            pts = tuple(zip(values[0::2], values[1::2], strict=True))
        hs = _singles(k).unpack_from(data, heads + 1) if k else ()
        self.pos = stop
        return pts, hs

    def end(self) -> None:
        if self.pos != len(self.data):
            raise DecodeError(
                f"trailing bytes: {len(self.data) - self.pos} after the message's "
                f"{self.pos} bytes"
            )


def decode_payload(payload: object, parse: Callable[[Reader], Any], kind: str,
                   version: int = WIRE_VERSION,
                   parsers: Mapping[int, Callable[[Reader], Any]] | None = None) -> Any:
    """Decode ``payload`` with ``parse`` (version ``version``), or with the parser ``parsers``
    names for its version byte; every failure is a :class:`DecodeError` naming ``kind``."""
    try:
        data = as_bytes(payload)
        if not data:
            raise DecodeError("empty payload")
        if len(data) > MAX_PAYLOAD_BYTES:
            raise DecodeError(f"payload of {len(data)} bytes exceeds {MAX_PAYLOAD_BYTES}")
        if parsers is not None and data[0] in parsers:
            parse = parsers[data[0]]
        elif data[0] != version:
            known = " or ".join(str(v) for v in sorted(parsers or (version,)))
            raise DecodeError(f"unsupported version {data[0]} (expected {known})")
        reader = Reader(data, 1)
        try:
            msg = parse(reader)
        except DecodeError:
            raise
        except (ValueError, TypeError) as exc:  # a field failed the message's own validation
            raise DecodeError(f"invalid message ({exc})") from None
        reader.end()
        return msg
    except DecodeError as exc:
        raise DecodeError(f"{kind}: {exc}") from None


def decoded_replies(session: zenoh.Session, selector: str, decode: Callable[[bytes], Any],
                    timeout: float) -> Iterator[Any]:
    """Each reply to ``selector`` from every queryable that answers (not only the best match),
    decoded with ``decode``; an error reply or a malformed payload is skipped."""
    for reply in session.get(selector, target=zenoh.QueryTarget.ALL,
                             consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout):
        if reply.ok is None:
            continue
        try:
            yield decode(reply.ok.payload.to_bytes())
        except DecodeError:
            continue
