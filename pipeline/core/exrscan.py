"""Scanline EXRs of float or half channels, uncompressed or ZIP, read straight into numpy.

The normals stage reads every decoded frame of a session (96 RGB float frames of 4 MP are
4.6 GB of pixels). Through OpenImageIO a ZIP frame of 4 MP costs about 0.23 s of CPU and an
uncompressed one 0.04 s, with a copy of every buffer into the binding's array. Here the file is
read once into an aligned buffer: an uncompressed frame's channel rows are used where they lie
(a strided view, no copy), and a ZIP frame's blocks are inflated by ISA-L and the format's
predictor undone by a compiled kernel straight into the output: 0.12-0.14 s a 4 MP ZIP frame
(docs/big-captures.md). The same pixels to the bit as OpenImageIO's (tested).

Only what psrig's decode writes and what is common beside it is read here: one part, scanlines,
``NONE``, ``ZIPS`` or ``ZIP`` compression, every channel FLOAT or every channel HALF, sampling
1. :func:`read_exr_planes` returns None for any other EXR (tiled, multi-part, deep, PIZ, mixed
channel types...), and the caller reads it with OpenImageIO.

>>> planes, names = read_exr_planes("linear/frame_000.exr")   # doctest: +SKIP
>>> planes.shape, names                                        # (H, C, W), the file's order
((1736, 3, 2312), ('B', 'G', 'R'))
"""

import os
import struct

import numpy as np

from .errors import ImageFileError
from .jit import Compiled, njit

__all__ = ["read_exr_planes", "exr_layout", "unpredict", "READER_KERNELS"]

_MAGIC = 20000630
#: version flags this reader refuses: tiled, deep ("non-image") and multi-part files
_UNSUPPORTED_FLAGS = 0x200 | 0x800 | 0x1000
_TYPES = {1: np.dtype("<f2"), 2: np.dtype("<f4")}
#: compression code -> scanlines per block (NONE, ZIPS, ZIP)
_LINES = {0: 1, 2: 1, 3: 16}
#: the header is read in one piece of at most this many bytes
_HEADER_BYTES = 1 << 16


def _attributes(head):
    """{name: (type, bytes)} of an EXR header and the offset just past it; None when it does not
    end within ``head``."""
    attrs, pos = {}, 8
    try:
        while head[pos] != 0:
            name_end = head.index(b"\0", pos)
            type_end = head.index(b"\0", name_end + 1)
            (size,) = struct.unpack_from("<i", head, type_end + 1)
            start = type_end + 5
            if size < 0 or start + size > len(head):
                return None
            attrs[head[pos:name_end].decode("latin-1")] = (head[name_end + 1:type_end], head[start:start + size])
            pos = start + size
    except (IndexError, ValueError, struct.error):
        return None
    return attrs, pos + 1


def _channels(value):
    """[(name, pixel type, x sampling, y sampling)] of a ``chlist`` attribute."""
    out, pos = [], 0
    while pos < len(value) and value[pos] != 0:
        end = value.index(b"\0", pos)
        kind, _, xs, ys = struct.unpack_from("<iB3xii", value, end + 1)
        out.append((value[pos:end].decode("latin-1"), kind, xs, ys))
        pos = end + 17
    return out


def exr_layout(head):
    """What :func:`read_exr_planes` needs of a file whose first bytes are ``head``, or None
    when it is not a kind read here.

    Returns
    -------
    dict or None
        ``height``, ``width``, ``y0`` (the data window's first row), ``names`` (channels in
        the file's order), ``dtype`` (float32 or float16), ``lines`` (scanlines per block),
        ``compression`` (0, 2 or 3), ``table`` (byte offset of the block offsets), ``blocks``.
    """
    if len(head) < 8:
        return None
    magic, version = struct.unpack_from("<ii", head)
    if magic != _MAGIC or version & 0xFF != 2 or version & _UNSUPPORTED_FLAGS:
        return None
    parsed = _attributes(head)
    if parsed is None:
        return None
    attrs, table = parsed
    try:
        channels = _channels(attrs["channels"][1])
        compression = attrs["compression"][1][0]
        x0, y0, x1, y1 = struct.unpack("<4i", attrs["dataWindow"][1])
    except (KeyError, IndexError, ValueError, struct.error):
        return None
    kinds = {kind for _, kind, _, _ in channels}
    if (not channels or len(kinds) != 1 or kinds - set(_TYPES) or compression not in _LINES
            or any((xs, ys) != (1, 1) for _, _, xs, ys in channels) or x1 < x0 or y1 < y0
            or "tiles" in attrs or attrs.get("type", (b"", b"scanlineimage\0"))[1].rstrip(b"\0") != b"scanlineimage"):
        return None
    height, lines = y1 - y0 + 1, _LINES[compression]
    return {"height": height, "width": x1 - x0 + 1, "y0": y0, "names": tuple(name for name, *_ in channels),
            "dtype": _TYPES[kinds.pop()], "lines": lines, "compression": compression, "table": table,
            "blocks": -(-height // lines)}


def _unpredict_py(data, out):
    """OpenEXR's ZIP predictor undone: ``data`` (N,) uint8 as inflated -> ``out`` (N,) uint8,
    the block's bytes (running sums of the differences, then the two halves interleaved)."""
    diffs = data.copy()
    diffs[1:] -= np.uint8(128)   # wraps: t[i] = t[i - 1] + d[i] - 128 (mod 256)
    summed = np.cumsum(diffs, dtype=np.uint8)
    half = (data.size + 1) // 2
    out[0::2], out[1::2] = summed[:half], summed[half:]


def _unpredict_kernel(data, out):
    n = data.size
    half = (n + 1) // 2
    acc = np.uint8(data[0])
    out[0] = acc
    for i in range(1, half):
        acc = np.uint8((acc + data[i] - 128) & 255)
        out[2 * i] = acc
    for i in range(half, n):
        acc = np.uint8((acc + data[i] - 128) & 255)
        out[2 * (i - half) + 1] = acc


def _build():
    kernel = njit(_unpredict_kernel)
    probe = np.arange(7, dtype=np.uint8)
    kernel(probe, np.empty_like(probe))
    return kernel


READER_KERNELS = Compiled("EXR reading kernel", _build)


def unpredict(data, out):
    """Undo OpenEXR's ZIP predictor (compiled when it can be, else numpy; the same bytes)."""
    kernel = READER_KERNELS.get()
    (kernel or _unpredict_py)(data, out)


def _read_all(path, layout, head):
    """The whole file in a buffer whose first block's pixel bytes start 4-byte aligned (the
    uncompressed planes are used where they lie)."""
    size = os.path.getsize(path)
    first = struct.unpack_from("<Q", head, layout["table"])[0] if len(head) >= layout["table"] + 8 else 0
    pad = (-(first + 8)) % 4
    buf = np.empty(size + pad, np.uint8)
    with open(path, "rb", buffering=0) as handle:
        view, got = memoryview(buf)[pad:], 0
        while got < size:
            count = handle.readinto(view[got:])
            if not count:
                raise ImageFileError(f"{path}: truncated image (read {got} of {size} bytes)")
            got += count
    return buf[pad:]


def _uncompressed(buf, layout, line):
    """The rows (H, line) of an uncompressed file laid out in order, as a view; None otherwise."""
    height, stride = layout["height"], line + 8
    offsets = np.frombuffer(buf, "<u8", layout["blocks"], layout["table"]).astype(np.int64)
    start = int(offsets[0])
    if (start + height * stride > buf.size or
            not np.array_equal(offsets, start + stride * np.arange(height, dtype=np.int64))):
        return None
    rows = buf[start:start + height * stride].reshape(height, stride)
    heads = rows[:, :8].copy().view("<i4")
    if not (np.array_equal(heads[:, 0], layout["y0"] + np.arange(height)) and (heads[:, 1] == line).all()):
        return None
    return rows[:, 8:]


def _inflated(buf, layout, line, path):
    """The rows (H, line) of a ZIP or ZIPS file, inflated and the predictor undone."""
    from isal import isal_zlib

    height, lines, y0 = layout["height"], layout["lines"], layout["y0"]
    rows = np.empty((height, line), np.uint8)
    flat = rows.reshape(-1)
    seen = np.zeros(layout["blocks"], bool)
    for offset in np.frombuffer(buf, "<u8", layout["blocks"], layout["table"]).tolist():
        if offset + 8 > buf.size:
            raise ImageFileError(f"{path}: truncated or corrupt image (a block starts beyond the file)")
        y, size = struct.unpack_from("<ii", buf, offset)
        block = (y - y0) // lines
        if (y - y0) % lines or not 0 <= block < layout["blocks"] or seen[block] or size < 0 \
                or offset + 8 + size > buf.size:
            raise ImageFileError(f"{path}: truncated or corrupt image (block at row {y})")
        seen[block] = True
        count = min(lines, height - (y - y0)) * line
        target = flat[(y - y0) * line:(y - y0) * line + count]
        data = buf[offset + 8:offset + 8 + size]
        if size == count:   # stored as it is: deflate did not make it smaller
            target[:] = data
            continue
        try:
            inflated = isal_zlib.decompress(data)
        except Exception as exc:   # isal's error type differs between versions
            raise ImageFileError(f"{path}: corrupt ZIP block at row {y} ({exc})") from None
        if len(inflated) != count:
            raise ImageFileError(f"{path}: corrupt ZIP block at row {y} ({len(inflated)} bytes, {count} expected)")
        unpredict(np.frombuffer(inflated, np.uint8), target)
    if not seen.all():
        raise ImageFileError(f"{path}: truncated or corrupt image (rows missing)")
    return rows


def read_exr_planes(path):
    """The pixels of a scanline EXR as planes (H, C, W) in the file's channel order.

    Returns
    -------
    planes : ndarray (H, C, W) float32 or float16
        As stored (a view of the file's bytes for an uncompressed file).
    names : tuple of str
        The channels, in the file's (alphabetical) order.

    None for an EXR of a kind not read here (see the module); raises ImageFileError for a
    truncated or corrupt one.
    """
    with open(path, "rb") as handle:
        head = handle.read(_HEADER_BYTES)
    layout = exr_layout(head)
    if layout is None:
        return None
    channels, width = len(layout["names"]), layout["width"]
    line = channels * width * layout["dtype"].itemsize
    buf = _read_all(path, layout, head)
    if buf.size < layout["table"] + 8 * layout["blocks"]:
        raise ImageFileError(f"{path}: truncated image (the block table is cut short)")
    rows = _uncompressed(buf, layout, line) if layout["compression"] == 0 else _inflated(buf, layout, line, path)
    if rows is None:
        return None
    planes = rows.view(layout["dtype"]).reshape(layout["height"], channels, width)
    return planes, layout["names"]
