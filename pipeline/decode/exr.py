"""Linear OpenEXR files built directly in numpy buffers: uncompressed or ZIP, float or half.

An uncompressed scanline EXR is a short header, a table of line offsets and, per scanline,
``int32 y, int32 byte count`` followed by each channel's row of values, the channels in
alphabetical order. Building that layout in one numpy buffer (:class:`ExrBuffer`) lets the
decoder write its planes straight into the file's bytes, hash them in memory and write them in
one system call.

ZIP compression (OpenEXR's ``ZIP_COMPRESSION``, lossless) stores blocks of 16 scanlines, each
the zlib stream of the block's bytes after OpenEXR's fixed predictor (bytes split into even and
odd halves, then differences of neighbours). :func:`zip_exr` applies it to the same rows with
numpy for the predictor and ISA-L's deflate (``isal``, about 4x the speed of zlib at the same
ratio on decoded frames: 270 MB/s against 65, docs/decoding.md), so a compressed frame costs
little more than an uncompressed one. A block that does not shrink is stored as it is, as the
format allows. The files are ordinary single-part scanline EXRs (OpenEXR file format,
version 2) that every reader, OpenImageIO included, reads back bit for bit.
"""

import struct

import numpy as np
from isal import isal_zlib

__all__ = ["ExrBuffer", "exr_header", "encode_exr", "zip_exr", "zip_sample", "half_rows", "ZIP_LEVEL", "ZIP_LINES",
           "AUTO_MIN_RATIO", "SAMPLE_BYTES"]

_MAGIC = 20000630
_HALF, _FLOAT = 1, 2  # OpenEXR pixel types (16- and 32-bit IEEE floats)
_COMPRESSION = {"none": 0, "zip": 3}
_INCREASING_Y = 0
#: scanlines per ZIP block (fixed by the format)
ZIP_LINES = 16
#: ISA-L deflate level (0-3). On DiLiGenT ball / reading / cat sessions: level 0 1.93x (cat),
#: level 1 2.32 / 2.20 / 2.44 x, level 2 2.34 / 2.22 / 2.46 x, level 3 2.22 / 2.14 / 2.33 x; a
#: cat frame (1 MB) in 3.6, 4.2, 4.8 ms at levels 0, 1, 2: level 1 is 13 % faster than 2 for
#: 1 % more bytes.
ZIP_LEVEL = 1
#: bytes 'auto' compresses to judge a frame: 4 blocks of up to 32 KB, about 1 ms whatever its size
SAMPLE_BYTES = 1 << 17


def _attribute(name, kind, value):
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def exr_header(height, width, names, compression="none", half=False):
    """Bytes of the header of a scanline EXR, up to the offset table.

    Parameters
    ----------
    height, width : int
        Image size (pixels).
    names : sequence of str
        Channel names; the file stores them sorted, as the format requires.
    compression : {'none', 'zip'}
    half : bool
        16-bit half floats instead of 32-bit floats.

    Returns
    -------
    bytes
    """
    pixel = _HALF if half else _FLOAT
    channels = b"".join(name.encode() + b"\0" + struct.pack("<iB3xii", pixel, 0, 1, 1)
                        for name in sorted(names)) + b"\0"
    window = struct.pack("<4i", 0, 0, width - 1, height - 1)
    return b"".join([
        struct.pack("<ii", _MAGIC, 2),
        _attribute("channels", "chlist", channels),
        _attribute("compression", "compression", bytes([_COMPRESSION[compression]])),
        _attribute("dataWindow", "box2i", window),
        _attribute("displayWindow", "box2i", window),
        _attribute("lineOrder", "lineOrder", bytes([_INCREASING_Y])),
        _attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        _attribute("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0)),
        _attribute("screenWindowWidth", "float", struct.pack("<f", 1.0)),
        b"\0",
    ])


class ExrBuffer:
    """The complete bytes of an uncompressed float32 EXR, with writable views of its channels.

    Parameters
    ----------
    height, width : int
    names : sequence of str
        Channel names, e.g. ('R', 'G', 'B') or ('Y',).

    Attributes
    ----------
    data : ndarray (N,) uint8
        The whole file; write it as it is once the planes are filled.
    planes : dict
        {name: ndarray (height, width) float32}, strided views into ``data``.
    rows : ndarray (height, 4 * width * channels) uint8
        Each scanline's pixel bytes (channels sorted by name), the view :func:`zip_exr` reads.
    names : tuple of str
    """

    def __init__(self, height, width, names):
        if height < 1 or width < 1 or not names:
            raise ValueError(f"an EXR needs at least one pixel and one channel, got "
                             f"{height}x{width} with channels {names!r}")
        self.names = tuple(names)
        header = exr_header(height, width, names)
        line = 8 + 4 * width * len(names)  # a multiple of 4: every row of floats stays aligned
        first = len(header) + 8 * height
        size = first + line * height
        # Start the file where the first row of floats lands on a 64-byte boundary, so that
        # numpy and OpenCV see aligned float32 rows (no hidden copies, vector loads).
        spare = np.zeros(size + 64, np.uint8)  # calloc: the kernel's zero pages, no extra pass
        skip = -(spare.ctypes.data + first + 8) % 64
        self.data = spare[skip:skip + size]
        self.data[:len(header)] = np.frombuffer(header, np.uint8)
        offsets = first + line * np.arange(height, dtype=np.uint64)
        self.data[len(header):first] = offsets.astype("<u8").view(np.uint8)
        blocks = self.data[first:].reshape(height, line)
        heads = np.empty((height, 2), "<i4")
        heads[:, 0] = np.arange(height)
        heads[:, 1] = line - 8
        blocks[:, :8] = heads.view(np.uint8)
        self.rows = blocks[:, 8:]
        row = 4 * width
        self.planes = {name: blocks[:, 8 + row * index:8 + row * (index + 1)].view("<f4")
                       for index, name in enumerate(sorted(names))}

    @property
    def shape(self):
        """(height, width) of the image."""
        return self.rows.shape[0], self.rows.shape[1] // (4 * len(self.names))

    def fill(self, pixels, names):
        """Copy an image (H, W, C) into the planes named ``names`` (in the order of C)."""
        for index, name in enumerate(names):
            self.planes[name][...] = pixels[:, :, index]


def half_rows(exr):
    """The scanline bytes (H, 2 * W * C) uint8 of an :class:`ExrBuffer`'s planes as half floats
    (rounded to nearest; beyond 65504 they become infinite, as OpenEXR's own conversion does)."""
    height, width = exr.shape
    halves = np.empty((height, len(exr.names), width), "<f2")
    for index, name in enumerate(sorted(exr.names)):
        halves[:, index] = exr.planes[name]
    return halves.reshape(height, -1).view(np.uint8)


def _predicted(block):
    """OpenEXR's ZIP predictor over a block's bytes (N,) uint8: the bytes to deflate."""
    split = np.concatenate([block[0::2], block[1::2]])
    out = np.empty_like(split)
    out[0] = split[0]
    np.subtract(split[1:], split[:-1], out=out[1:])
    out[1:] += np.uint8(128)   # uint8 arithmetic wraps: (t[i] - t[i-1] + 128) mod 256
    return out


def _packed(rows, start, predicted, level):
    """A block's bytes in the file: deflated, or raw when deflate does not make it smaller
    (readers tell by the size)."""
    packed = isal_zlib.compress(predicted, level)
    raw_size = (min(start + ZIP_LINES, rows.shape[0]) - start) * rows.shape[1]
    return packed if len(packed) < raw_size else rows[start:start + ZIP_LINES].tobytes()


def _zip_block(rows, start, level):
    """(y, bytes) of the ZIP block starting at scanline ``start``; stored raw when deflate
    does not make it smaller (readers tell by the size)."""
    stop = min(start + ZIP_LINES, rows.shape[0])
    return _packed(rows, start, _predicted(rows[start:stop].reshape(-1)), level)


def zip_exr(rows, width, names, *, half=False, level=ZIP_LEVEL, done=None):
    """The bytes of a ZIP-compressed scanline EXR holding ``rows``.

    Parameters
    ----------
    rows : ndarray (H, B) uint8
        Each scanline's pixel bytes, channels sorted by name (:attr:`ExrBuffer.rows`, or
        :func:`half_rows` of one).
    width : int
    names : sequence of str
    half : bool
        The rows hold half floats.
    level : int
        Deflate level, 0-3.
    done : dict, optional
        {first scanline: block bytes} already compressed (by :func:`zip_sample`).

    Returns
    -------
    bytes
    """
    height = rows.shape[0]
    done = done or {}
    header = exr_header(height, width, names, "zip", half)
    blocks = [done[start] if start in done else _zip_block(rows, start, level)
              for start in range(0, height, ZIP_LINES)]
    first = len(header) + 8 * len(blocks)
    sizes = np.array([8 + len(b) for b in blocks], np.uint64)
    offsets = first + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.uint64)
    parts = [header, offsets.astype("<u8").tobytes()]
    for index, block in enumerate(blocks):
        parts += [struct.pack("<ii", index * ZIP_LINES, len(block)), block]
    return b"".join(parts)


def zip_sample(rows, *, budget=SAMPLE_BYTES, level=ZIP_LEVEL):
    """Estimated ZIP compression ratio (uncompressed / compressed) of ``rows`` (H, B) uint8
    from about ``budget`` bytes of blocks spread over the image, and the blocks compressed.

    Blocks of up to a quarter of the budget are compressed whole and returned
    ({first scanline: bytes}) for :func:`zip_exr` to reuse; larger ones (a 12 MP frame's are
    768 KB) are cut, and only estimate.
    """
    height, line = rows.shape
    block = ZIP_LINES * line
    count = min(-(-height // ZIP_LINES), max(budget // block, 4))
    starts = np.unique(np.linspace(0, height - 1, count).astype(int) // ZIP_LINES * ZIP_LINES)
    raw = packed = 0
    done = {}
    for start in starts:
        stop = min(start + ZIP_LINES, height)
        if block * 4 <= budget:
            done[int(start)] = _zip_block(rows, start, level)
            raw, packed = raw + (stop - start) * line, packed + len(done[int(start)])
        else:
            data = _predicted(rows[start:stop].reshape(-1)[:budget // count])
            raw, packed = raw + data.size, packed + len(isal_zlib.compress(data, level))
    return raw / max(packed, 1), done


#: 'auto' compresses a frame when a sample of it (:func:`zip_sample`) shrinks at least this much. A ZIP frame
#: costs about 2-4x the time of an uncompressed one to read back (every later stage reads the
#: frames), so compression is kept for frames where it halves the disk or more: those decoded
#: from 8- and 16-bit files (DiLiGenT 2.2-2.5x). The simulated rig's frames shrink 1.4-1.6x and
#: stay uncompressed (compressed, the demo's reads took 1.5-2.5 s longer), as do raw frames full
#: of sensor noise (1.07-1.13x, for 0.5 s of CPU a 12 MP frame): docs/decoding.md.
AUTO_MIN_RATIO = 1.8


def encode_exr(exr, compression="auto", half=False):
    """The bytes to write for a filled :class:`ExrBuffer`, and what was written.

    Parameters
    ----------
    exr : ExrBuffer
    compression : {'auto', 'zip', 'none'}
    half : bool
        Half floats (lossy: 11-bit mantissa), ZIP-compressed unless ``compression`` is 'none'.

    Returns
    -------
    data : ndarray or bytes
    written : dict
        ``compression`` ('zip' or 'none'), ``pixels`` ('float' or 'half'), ``bytes``; with
        'auto', ``estimated_ratio`` (the sample's).
    """
    height, width = exr.shape
    rows = half_rows(exr) if half else exr.rows
    written, done = {}, None
    if compression == "auto":
        ratio, done = zip_sample(rows)
        written["estimated_ratio"] = round(ratio, 3)
        compression = "zip" if ratio >= AUTO_MIN_RATIO else "none"
    if compression == "zip":
        data = zip_exr(rows, width, exr.names, half=half, done=done)
    elif half:
        data = _uncompressed_half(rows, width, exr.names)
    else:
        data = exr.data
    written.update(compression=compression, pixels="half" if half else "float", bytes=len(data))
    return data, written


def _uncompressed_half(rows, width, names):
    """Bytes of an uncompressed half-float EXR of ``rows`` (H, 2 W C) uint8."""
    height, line = rows.shape
    header = exr_header(height, width, names, "none", half=True)
    first = len(header) + 8 * height
    offsets = first + (8 + line) * np.arange(height, dtype=np.uint64)
    heads = np.empty((height, 2), "<i4")
    heads[:, 0], heads[:, 1] = np.arange(height), line
    body = np.concatenate([heads.view(np.uint8), rows], axis=1)
    return header + offsets.astype("<u8").tobytes() + body.tobytes()
