"""Uncompressed float32 OpenEXR files built directly in a numpy buffer.

The decode stage writes 12-megapixel float32 frames that barely compress (noise fills every
mantissa). An uncompressed scanline EXR is a short header, a table of line offsets and, per
scanline, ``int32 y, int32 byte count`` followed by each channel's row of float32 values, the
channels in alphabetical order. Building that layout in one numpy buffer lets the decoder
write its planes straight into the file's bytes (no interleaved copy, no per-line conversion
in the EXR library), hash the bytes in memory and write them in one system call. The files are
ordinary single-part scanline EXRs (OpenEXR file format, version 2) that every reader,
OpenImageIO included, reads back bit for bit.
"""

import struct

import numpy as np

__all__ = ["ExrBuffer", "exr_header"]

_MAGIC = 20000630
_FLOAT = 2  # OpenEXR pixel type FLOAT (32-bit IEEE)
_NO_COMPRESSION = 0
_INCREASING_Y = 0


def _attribute(name, kind, value):
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def exr_header(height, width, names):
    """Bytes of the header of an uncompressed float32 scanline EXR, up to the offset table.

    Parameters
    ----------
    height, width : int
        Image size (pixels).
    names : sequence of str
        Channel names; the file stores them sorted, as the format requires.

    Returns
    -------
    bytes
    """
    channels = b"".join(name.encode() + b"\0" + struct.pack("<iB3xii", _FLOAT, 0, 1, 1)
                        for name in sorted(names)) + b"\0"
    window = struct.pack("<4i", 0, 0, width - 1, height - 1)
    return b"".join([
        struct.pack("<ii", _MAGIC, 2),
        _attribute("channels", "chlist", channels),
        _attribute("compression", "compression", bytes([_NO_COMPRESSION])),
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
    """

    def __init__(self, height, width, names):
        if height < 1 or width < 1 or not names:
            raise ValueError(f"an EXR needs at least one pixel and one channel, got "
                             f"{height}x{width} with channels {names!r}")
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
        row = 4 * width
        self.planes = {name: blocks[:, 8 + row * index:8 + row * (index + 1)].view("<f4")
                       for index, name in enumerate(sorted(names))}

    def fill(self, pixels, names):
        """Copy an image (H, W, C) into the planes named ``names`` (in the order of C)."""
        for index, name in enumerate(names):
            self.planes[name][...] = pixels[:, :, index]
