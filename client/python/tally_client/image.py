"""Images of tally's image jobs: per-pixel mean, standard error and sample count.

Two sources give the same float32 values: the tiles endpoint (JSON, one tile per request,
works while the job runs) and the server's OpenEXR file (one request; channels R, G, B,
StdErr.R/G/B, SampleCount, ``tally:*`` header attributes). The EXR reader here covers what
tally-server writes: scanline images, 32-bit float / half / uint channels, compression
none, ZIPS or ZIP. It needs only the standard library.

numpy is optional: :class:`Image` keeps flat row-major ``array('f')`` buffers, and its
``mean``, ``std_error`` and ``samples`` properties return numpy arrays of shape
(height, width, 3) / (height, width) when numpy is installed.
"""

from __future__ import annotations

import struct
import sys
import zlib
from array import array
from dataclasses import dataclass, field
from typing import Any, Dict, List, Sequence, Tuple

__all__ = ["Image", "ExrError", "decode_exr", "image_from_tiles"]


class ExrError(ValueError):
    """The bytes are not an OpenEXR file this reader understands."""


def _numpy() -> Any:
    try:
        import numpy  # noqa: PLC0415 (optional dependency)
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            "tally_client.Image arrays need numpy (pip install numpy, or Debian's python3-numpy); "
            "the flat buffers mean_flat/std_error_flat/samples_flat work without it"
        ) from e
    return numpy


@dataclass
class Image:
    """One snapshot of a job's image. Buffers are row-major, RGB interleaved, float32."""

    width: int
    height: int
    mean_flat: "array[float]"  # width*height*3
    std_error_flat: "array[float]"  # width*height*3
    samples_flat: "array[float]"  # width*height
    metadata: Dict[str, Any] = field(default_factory=dict)

    @property
    def mean(self) -> Any:
        """numpy float32 array (height, width, 3): the estimate of each pixel's RGB."""
        return _numpy().frombuffer(self.mean_flat, dtype=_native_f4()).reshape(self.height, self.width, 3)

    @property
    def std_error(self) -> Any:
        """numpy float32 array (height, width, 3): the standard error of each mean."""
        return _numpy().frombuffer(self.std_error_flat, dtype=_native_f4()).reshape(self.height, self.width, 3)

    @property
    def samples(self) -> Any:
        """numpy float32 array (height, width): samples per pixel."""
        return _numpy().frombuffer(self.samples_flat, dtype=_native_f4()).reshape(self.height, self.width)

    def pixel(self, x: int, y: int) -> Tuple[Tuple[float, float, float], Tuple[float, float, float], float]:
        """(mean RGB, standard error RGB, samples) of one pixel, without numpy."""
        if not (0 <= x < self.width and 0 <= y < self.height):
            raise IndexError(f"pixel ({x}, {y}) is outside the {self.width}x{self.height} image")
        i = y * self.width + x
        m = self.mean_flat
        s = self.std_error_flat
        return ((m[3 * i], m[3 * i + 1], m[3 * i + 2]), (s[3 * i], s[3 * i + 1], s[3 * i + 2]), self.samples_flat[i])


def _native_f4() -> str:
    return "<f4" if sys.byteorder == "little" else ">f4"


def image_from_tiles(width: int, height: int, tiles: Sequence[Dict[str, Any]]) -> Image:
    """Assembles tile documents (GET /v1/jobs/{id}/tiles/{n}) into one image."""
    n = width * height
    mean = array("f", bytes(4 * 3 * n))
    se = array("f", bytes(4 * 3 * n))
    samples = array("f", bytes(4 * n))
    for t in tiles:
        x0, y0, w, h = int(t["x"]), int(t["y"]), int(t["w"]), int(t["h"])
        tm, ts, tn = t["mean"], t["std_error"], t["samples"]
        if len(tm) != 3 * w * h or len(ts) != 3 * w * h or len(tn) != w * h:
            raise ValueError(f"tile {t.get('tile')}: {w}x{h} but {len(tm)} means, {len(ts)} errors, {len(tn)} counts")
        for row in range(h):
            dst = (y0 + row) * width + x0
            src = row * w
            mean[3 * dst:3 * (dst + w)] = array("f", tm[3 * src:3 * (src + w)])
            se[3 * dst:3 * (dst + w)] = array("f", ts[3 * src:3 * (src + w)])
            samples[dst:dst + w] = array("f", tn[src:src + w])
    return Image(width, height, mean, se, samples)


# --- OpenEXR -------------------------------------------------------------------------

_MAGIC = 20000630
_PIXEL_BYTES = {0: 4, 1: 2, 2: 4}  # UINT, HALF, FLOAT
_LINES_PER_CHUNK = {0: 1, 2: 1, 3: 16}  # NONE, ZIPS, ZIP


class _Reader:
    def __init__(self, data: bytes):
        self.data = data
        self.pos = 0

    def take(self, n: int) -> bytes:
        if self.pos + n > len(self.data):
            raise ExrError("truncated EXR file")
        b = self.data[self.pos:self.pos + n]
        self.pos += n
        return b

    def cstring(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise ExrError("truncated EXR header")
        s = self.data[self.pos:end].decode("latin-1")
        self.pos = end + 1
        return s

    def unpack(self, fmt: str) -> Tuple[Any, ...]:
        return struct.unpack(fmt, self.take(struct.calcsize(fmt)))


def _attribute_value(kind: str, raw: bytes) -> Any:
    if kind == "double":
        return struct.unpack("<d", raw)[0]
    if kind == "float":
        return struct.unpack("<f", raw)[0]
    if kind == "int":
        return struct.unpack("<i", raw)[0]
    if kind == "string":
        return raw.decode("utf-8", "replace")
    if kind == "box2i":
        return struct.unpack("<4i", raw)
    if kind == "compression" or kind == "lineOrder":
        return raw[0]
    return raw


def _channels(raw: bytes) -> List[Tuple[str, int]]:
    r = _Reader(raw)
    out: List[Tuple[str, int]] = []
    while True:
        name = r.cstring()
        if not name:
            return out
        pixel_type, _linear, xs, ys = r.unpack("<iB3xii")
        if (xs, ys) != (1, 1):
            raise ExrError(f"channel {name}: subsampled channels are not supported")
        if pixel_type not in _PIXEL_BYTES:
            raise ExrError(f"channel {name}: unknown pixel type {pixel_type}")
        out.append((name, pixel_type))


def _unzip(chunk: bytes, expected: int) -> bytes:
    t = bytearray(zlib.decompress(chunk))
    if len(t) != expected:
        raise ExrError(f"ZIP chunk holds {len(t)} bytes, expected {expected}")
    # Undo the predictor (each byte stored as the difference to the previous + 128)...
    for i in range(1, len(t)):
        t[i] = (t[i - 1] + t[i] - 128) & 0xFF
    # ...and the split into even and odd bytes.
    out = bytearray(len(t))
    half = (len(t) + 1) // 2
    out[0::2] = t[:half]
    out[1::2] = t[half:]
    return bytes(out)


def _to_floats(raw: bytes, pixel_type: int) -> "array[float]":
    if pixel_type == 2:
        a = array("f", raw)
    elif pixel_type == 0:
        a = array("f", (float(v) for v in array("I", raw)))
        if sys.byteorder != "little":
            raise ExrError("uint channels on big-endian machines are not supported")
        return a
    else:
        a = array("f", (struct.unpack("<e", raw[i:i + 2])[0] for i in range(0, len(raw), 2)))
        return a
    if sys.byteorder != "little":
        a.byteswap()
    return a


def decode_exr(data: bytes) -> Image:
    """Decodes tally-server's EXR (GET /v1/jobs/{id}/image.exr) into an :class:`Image`.

    The image covers the data window; ``metadata`` holds the ``tally:*`` attributes
    (job_id, state, samples, passes, spec) without the prefix.
    """
    r = _Reader(data)
    magic, version = r.unpack("<ii")
    if magic != _MAGIC:
        raise ExrError("not an OpenEXR file")
    if version & 0x200 or version & 0x1000:
        raise ExrError("tiled or multi-part EXR files are not supported")
    attrs: Dict[str, Tuple[str, bytes]] = {}
    while True:
        name = r.cstring()
        if not name:
            break
        kind = r.cstring()
        (size,) = r.unpack("<i")
        attrs[name] = (kind, r.take(size))
    for required in ("channels", "compression", "dataWindow"):
        if required not in attrs:
            raise ExrError(f"EXR header has no {required}")
    channels = _channels(attrs["channels"][1])
    compression = attrs["compression"][1][0]
    if compression not in _LINES_PER_CHUNK:
        raise ExrError(f"EXR compression {compression} is not supported (none, ZIPS and ZIP are)")
    xmin, ymin, xmax, ymax = struct.unpack("<4i", attrs["dataWindow"][1])
    width, height = xmax - xmin + 1, ymax - ymin + 1
    lines = _LINES_PER_CHUNK[compression]
    nchunks = (height + lines - 1) // lines
    offsets = r.unpack(f"<{nchunks}Q")

    planes: Dict[str, "array[float]"] = {name: array("f") for name, _ in channels}
    line_bytes = sum(_PIXEL_BYTES[t] for _, t in channels) * width
    rows_seen = 0
    for off in sorted(offsets):
        r.pos = off
        y, size = r.unpack("<ii")
        chunk = r.take(size)
        rows = min(lines, ymax + 1 - y)
        expected = rows * line_bytes
        raw = chunk if size == expected or compression == 0 else _unzip(chunk, expected)
        if len(raw) != expected:
            raise ExrError(f"chunk at line {y} holds {len(raw)} bytes, expected {expected}")
        pos = 0
        for _ in range(rows):
            for name, t in channels:
                n = _PIXEL_BYTES[t] * width
                planes[name].extend(_to_floats(raw[pos:pos + n], t))
                pos += n
        rows_seen += rows
    if rows_seen != height:
        raise ExrError(f"EXR chunks hold {rows_seen} lines, the data window {height}")

    def plane(name: str) -> "array[float]":
        if name not in planes:
            raise ExrError(f"EXR has no channel {name} (has {', '.join(planes)})")
        return planes[name]

    n = width * height
    mean = array("f", bytes(4 * 3 * n))
    se = array("f", bytes(4 * 3 * n))
    for c, ch in enumerate("RGB"):
        mean[c::3] = plane(ch)
        se[c::3] = plane("StdErr." + ch)
    metadata = {}
    for name, (kind, raw_value) in attrs.items():
        if name.startswith("tally:"):
            metadata[name[len("tally:"):]] = _attribute_value(kind, raw_value)
    return Image(width, height, mean, se, array("f", plane("SampleCount")), metadata)
