"""Messages between the grader and a test process: a small JSON header and raw arrays, framed.

The test process runs submitted code, so everything that comes from it is untrusted: the grader
reads a frame with :func:`read_frame`, which takes nothing on trust: a fixed magic, a header of at
most :data:`MAX_HEADER` bytes that must be a JSON object, arrays only of the plain numeric dtypes
in :data:`ARRAY_DTYPES` whose shape, dtype and byte count agree, a total size cap, and nothing
unpickled. :func:`expect_arrays` then checks a kind's outputs against the shapes it asked for.

    frame = b"RTLB" + u32 header length + header JSON + array bytes (in the header's order)
    header = {"event": "result", ..., "arrays": [{"name": "t", "dtype": "<f4", "shape": [4096]}, ...]}
"""
from __future__ import annotations

import json
import os
import struct

import numpy as np

MAGIC = b"RTLB"
MAX_HEADER = 1 << 16                    # bytes of JSON in one frame
MAX_PAYLOAD = 32 * 2 ** 20              # bytes of arrays in one frame (a 1024x1024 render's hits: 20 MB)
MAX_ARRAYS = 64
ARRAY_DTYPES = {np.dtype(t).str: np.dtype(t) for t in (np.float32, np.float64, np.int32, np.int64, np.uint8,
                                                        np.uint32, np.int8)}


class ChannelError(Exception):
    """What a test process sent breaks the protocol (its message says how)."""


def write_frame(fd: int, header: dict, arrays: dict[str, np.ndarray] | None = None) -> None:
    """Send a frame on ``fd`` (blocking)."""
    arrays = arrays or {}
    meta, blobs = [], []
    for name, a in arrays.items():
        a = np.ascontiguousarray(a)
        if a.dtype.str not in ARRAY_DTYPES:
            a = a.astype(np.float64 if a.dtype.kind == "f" else np.int64)
        meta.append({"name": str(name), "dtype": a.dtype.str, "shape": list(a.shape)})
        blobs.append(a.tobytes())
    text = json.dumps({**header, "arrays": meta}, default=_jsonable).encode()
    data = MAGIC + struct.pack("<I", len(text)) + text + b"".join(blobs)
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _jsonable(x):
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


class FrameReader:
    """Frames from a byte stream fed in pieces (:meth:`feed`), each checked as it completes."""

    def __init__(self, max_payload: int = MAX_PAYLOAD):
        self.buf = bytearray()
        self.max_payload = max_payload
        self.need: tuple[int, dict, list] | None = None     # payload bytes, header, array specs

    def feed(self, data: bytes) -> list[tuple[dict, dict]]:
        self.buf += data
        out = []
        while True:
            frame = self._next()
            if frame is None:
                return out
            out.append(frame)

    def _next(self):
        if self.need is None:
            if len(self.buf) < 8:
                return None
            if bytes(self.buf[:4]) != MAGIC:
                raise ChannelError("the test process wrote something that is not a grader message to its result channel")
            size = struct.unpack("<I", self.buf[4:8])[0]
            if size > MAX_HEADER:
                raise ChannelError(f"a message header of {size:,} bytes (at most {MAX_HEADER:,})")
            if len(self.buf) < 8 + size:
                return None
            try:
                header = json.loads(bytes(self.buf[8:8 + size]).decode("utf-8"))
            except (UnicodeDecodeError, ValueError):
                raise ChannelError("a message header that is not JSON") from None
            if not isinstance(header, dict):
                raise ChannelError("a message header that is not a JSON object")
            specs = _array_specs(header.get("arrays", []))
            payload = sum(n for _, _, _, n in specs)
            if payload > self.max_payload:
                raise ChannelError(f"a message of {payload:,} bytes of arrays (at most {self.max_payload:,})")
            del self.buf[:8 + size]
            self.need = (payload, header, specs)
        payload, header, specs = self.need
        if len(self.buf) < payload:
            return None
        arrays, at = {}, 0
        for name, dtype, shape, n in specs:
            arrays[name] = np.frombuffer(bytes(self.buf[at:at + n]), dtype=dtype).reshape(shape).copy()
            at += n
        del self.buf[:payload]
        self.need = None
        header = {k: v for k, v in header.items() if k != "arrays"}
        return header, arrays


def _array_specs(meta) -> list[tuple[str, np.dtype, tuple, int]]:
    if not isinstance(meta, list) or len(meta) > MAX_ARRAYS:
        raise ChannelError(f"a message must list at most {MAX_ARRAYS} arrays")
    out, names = [], set()
    for m in meta:
        if not isinstance(m, dict):
            raise ChannelError("an array description that is not an object")
        name, dtype, shape = m.get("name"), m.get("dtype"), m.get("shape")
        if not isinstance(name, str) or not 0 < len(name) <= 64 or name in names:
            raise ChannelError(f"an array name {str(name)[:70]!r} (names are 1-64 characters, each once)")
        if dtype not in ARRAY_DTYPES:
            raise ChannelError(f"array {name}: dtype {str(dtype)[:20]!r} is not one of {', '.join(ARRAY_DTYPES)}")
        if (not isinstance(shape, list) or len(shape) > 4
                or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2 ** 31 for s in shape)):
            raise ChannelError(f"array {name}: a shape must be up to 4 non-negative integers")
        n = int(np.prod(shape, dtype=np.int64)) * ARRAY_DTYPES[dtype].itemsize
        if n > MAX_PAYLOAD:
            raise ChannelError(f"array {name}: {n:,} bytes of arrays (at most {MAX_PAYLOAD:,})")
        names.add(name)
        out.append((name, ARRAY_DTYPES[dtype], tuple(shape), n))
    return out


def expect_arrays(arrays: dict, wanted: dict[str, tuple]) -> dict[str, np.ndarray]:
    """The arrays a check reads, each with exactly the dtype and shape the kind expects
    (``wanted``: name -> (dtype, shape)); ChannelError naming the first that is missing or wrong."""
    out = {}
    for name, (dtype, shape) in wanted.items():
        a = arrays.get(name)
        if a is None:
            raise ChannelError(f"the test process returned no '{name}'")
        if a.dtype != np.dtype(dtype) or tuple(a.shape) != tuple(shape):
            raise ChannelError(f"'{name}' came back as {a.dtype} {tuple(a.shape)}, expected {np.dtype(dtype)} "
                               f"{tuple(shape)}")
        out[name] = a
    return out


def clean_text(value, limit: int = 8000) -> str:
    """A string from the test process, bounded and printable."""
    text = value if isinstance(value, str) else ""
    text = "".join(c if c.isprintable() or c in "\n\t" else "?" for c in text[:limit])
    return text


def clean_number(value, default: float = float("nan")) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return default
    return float(value)
