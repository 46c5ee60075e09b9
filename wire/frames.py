"""The ``frame`` payload: one encoded camera image and its capture stamp.

The simulated world (``formation run --camera process``) or a remote camera PC publishes frames
on a key of its choice (by default ``{prefix}/camera/frame``, :func:`frame_key`); the camera
service (``formation camera`` with ``source: zenoh:KEY``) decodes and detects them.

Layout (``zenoh.ext.z_serialize`` of one tuple, see :mod:`wire.payloads`)::

    version:u8, stamp:f64, encoding:str, image:bytes

``encoding`` is ``"jpeg"`` or ``"png"``; ``image`` (a LEB128 length, then the bytes) is the file
as ``cv2.imencode`` writes it; ``stamp`` [s] is the capture time on the sender's clock. Decoding
(:func:`decode_frame`) is plain Python over the bytes and raises nothing but
:class:`wire.payloads.DecodeError`: wrong version, truncated, trailing bytes, a non-finite stamp,
an unknown encoding, an image whose first bytes are not that encoding's signature, or a payload
over :data:`MAX_FRAME_BYTES`. The pixels themselves are decoded by the receiver (``cv2.imdecode``
returns ``None`` on garbage, which the camera service counts).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import zenoh
from zenoh.ext import UInt8, z_serialize

from wire import keys
from wire.payloads import DecodeError

FRAME_VERSION = 1
MAX_FRAME_BYTES = 32 * 1024 * 1024  # [B] largest frame payload accepted (a 4K PNG fits)
ENCODINGS = ("jpeg", "png")
_SIGNATURES = {"jpeg": b"\xff\xd8\xff", "png": b"\x89PNG\r\n\x1a\n"}
FRAME_SUFFIX = "camera/frame"
STATS_SUFFIX = "camera/stats"
_F64 = struct.Struct("<d")


def frame_key(prefix: str = keys.DEFAULT_PREFIX) -> str:
    """``{prefix}/camera/frame``: the default key of encoded frames."""
    return f"{keys.validate_prefix(prefix)}/{FRAME_SUFFIX}"


def stats_key(prefix: str = keys.DEFAULT_PREFIX) -> str:
    """``{prefix}/camera/stats``: the camera service's counters (a queryable, JSON)."""
    return f"{keys.validate_prefix(prefix)}/{STATS_SUFFIX}"


@dataclass(frozen=True, slots=True)
class Frame:
    """One encoded image (``encoding`` ``"jpeg"`` or ``"png"``) captured at ``stamp`` [s]."""

    stamp: float
    encoding: str
    image: bytes

    def __post_init__(self) -> None:
        if isinstance(self.stamp, bool) or not isinstance(self.stamp, int | float) \
                or not math.isfinite(self.stamp):
            raise ValueError(f"stamp must be a finite number, got {self.stamp!r}")
        if self.encoding not in ENCODINGS:
            raise ValueError(f"encoding must be one of {ENCODINGS}, got {self.encoding!r}")
        if not isinstance(self.image, bytes):
            raise ValueError(f"image must be bytes, got {type(self.image).__name__}")
        if not self.image.startswith(_SIGNATURES[self.encoding]):
            raise ValueError(f"image does not start with the {self.encoding} signature")


def encode_frame(frame: Frame) -> bytes:
    """Serialize ``frame`` (see the module docstring)."""
    return z_serialize((UInt8(FRAME_VERSION), float(frame.stamp), frame.encoding,
                        frame.image)).to_bytes()


def _varint(data: bytes, pos: int, what: str) -> tuple[int, int]:
    value = 0
    for index in range(10):
        if pos >= len(data):
            raise DecodeError(f"frame: truncated {what}")
        byte = data[pos]
        pos += 1
        value |= (byte & 0x7F) << (7 * index)
        if not byte & 0x80:
            if byte == 0 and index > 0:
                raise DecodeError(f"frame: non-canonical varint for {what}")
            return value, pos
    raise DecodeError(f"frame: varint for {what} too long")


def _chunk(data: bytes, pos: int, what: str) -> tuple[bytes, int]:
    n, pos = _varint(data, pos, what)
    if n > len(data) - pos:
        raise DecodeError(f"frame: truncated {what}: needs {n} bytes, {len(data) - pos} left")
    return data[pos:pos + n], pos + n


def decode_frame(payload: bytes | bytearray | memoryview | zenoh.ZBytes) -> Frame:
    """Decode a ``frame`` payload; raises only :class:`DecodeError`."""
    if isinstance(payload, zenoh.ZBytes):
        data = payload.to_bytes()
    elif isinstance(payload, bytes | bytearray | memoryview):
        data = bytes(payload)
    else:
        raise DecodeError(f"frame: payload must be bytes, got {type(payload).__name__}")
    if not data:
        raise DecodeError("frame: empty payload")
    if len(data) > MAX_FRAME_BYTES:
        raise DecodeError(f"frame: payload of {len(data)} bytes exceeds {MAX_FRAME_BYTES}")
    if data[0] != FRAME_VERSION:
        raise DecodeError(f"frame: unsupported version {data[0]} (expected {FRAME_VERSION})")
    if len(data) < 1 + _F64.size:
        raise DecodeError("frame: truncated stamp")
    (stamp,) = _F64.unpack_from(data, 1)
    raw, pos = _chunk(data, 1 + _F64.size, "encoding")
    image, pos = _chunk(data, pos, "image")
    if pos != len(data):
        raise DecodeError(f"frame: {len(data) - pos} trailing bytes")
    try:
        encoding = raw.decode("utf-8")
        return Frame(stamp, encoding, image)
    except (UnicodeDecodeError, ValueError) as exc:
        raise DecodeError(f"frame: invalid ({exc})") from None
