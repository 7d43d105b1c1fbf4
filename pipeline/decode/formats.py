"""What a frame file is, decided by its content (not its suffix): an image or a camera raw.

OpenImageIO is asked first: it reads the image formats (PNG, TIFF, EXR, JPEG, TGA, BMP, ...),
each plugin checking the file's own signature. Camera raw files are mostly TIFF containers
(DNG, CR2, NEF, ARW, ...) whose first directory OpenImageIO would happily return as a
thumbnail or a grey mosaic, so a file it reads as TIFF is offered to LibRaw too, which accepts
only real camera raws; a file OpenImageIO cannot open (RAF, CR3, ...) goes to LibRaw alone.
"""

import os
from dataclasses import dataclass
from functools import lru_cache

import OpenImageIO as oiio
import rawpy

from ..core.errors import ImageFileError

__all__ = ["FrameFormat", "frame_format", "readable_formats", "RAW_EXAMPLES", "FrameTooLarge",
           "MAX_IMAGE_PIXELS", "IMAGE_DECODE_BYTES_PER_PIXEL", "check_image_size", "png_problem"]

#: Most pixels an image frame may have. The largest camera frames (pixel-shift composites) are
#: about 400 MP; a PNG of a flat colour claiming 30000 x 30000 is under 1 MB on disk, so the
#: file's size bounds nothing (unlike a raw file's) and the header's size is checked instead.
MAX_IMAGE_PIXELS = 400_000_000
#: Bytes of memory decoding an image frame takes per pixel (the stored pixels, the float32 RGB
#: frame, its saturation flags, the linear file's encoding buffers).
IMAGE_DECODE_BYTES_PER_PIXEL = 32


class FrameTooLarge(ImageFileError):
    """A frame's header claims more pixels than psrig decodes, or than this machine can hold."""

#: a few of the camera raw formats LibRaw reads, for messages
RAW_EXAMPLES = "DNG, CR2, CR3, NEF, ARW, RAF, ORF, RW2, PEF"


@dataclass(frozen=True)
class FrameFormat:
    """``kind`` 'image' (OpenImageIO) or 'raw' (LibRaw), ``name`` (OpenImageIO's format name,
    such as 'png' or 'targa', or 'raw') and, for images, ``size`` (height, width) and
    ``channels``."""

    kind: str
    name: str
    size: tuple = None
    channels: int = None


def _oiio_format(path):
    """(format name, (height, width), channels) for ``path``, or None when no plugin reads it."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear the pending message: it is not this module's to report
        return None
    spec = inp.spec()
    found = inp.format_name(), (spec.height, spec.width), spec.nchannels
    inp.close()
    return found


def _is_camera_raw(path):
    try:
        with rawpy.imread(str(path)):
            return True
    except (rawpy.LibRawError, OSError, ValueError):
        return False


def frame_format(path):
    """Decide how to decode a frame file from its content.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    FrameFormat

    Raises
    ------
    ImageFileError
        Neither OpenImageIO nor LibRaw reads the file; the message lists what they read.
    """
    try:
        stat = os.stat(path)
    except OSError as exc:
        raise ImageFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    # a decode worker asks twice per frame (its fast path, then the decoder): answered once
    return _frame_format(str(path), stat.st_mtime_ns, stat.st_size)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_problem(path):
    """Why the PNG file ``path`` is not whole, or None: each chunk must be complete and match
    its CRC, and the file must reach its IEND chunk. A header alone (what OpenImageIO reads to
    open a file) says nothing of a file cut short in a copy or damaged on disk.

    Returns
    -------
    str or None
        'truncated (...)' or 'corrupt (...)' with the chunk and byte offset.
    """
    import struct
    import zlib

    with open(path, "rb") as fh:
        data = fh.read()
    if not data.startswith(_PNG_SIGNATURE):
        return "corrupt (no PNG signature)"
    at = len(_PNG_SIGNATURE)
    while True:
        if at + 8 > len(data):
            return f"truncated (it ends at byte {len(data)}, before its IEND chunk)"
        length, kind = struct.unpack_from(">I4s", data, at)
        end = at + 8 + length + 4
        name = kind.decode("latin-1")
        if end > len(data):
            return f"truncated (it ends at byte {len(data)}, inside its {name!r} chunk at byte {at})"
        crc = struct.unpack_from(">I", data, end - 4)[0]
        if zlib.crc32(data[at + 4:end - 4]) != crc:
            return f"corrupt (its {name!r} chunk at byte {at} fails its CRC)"
        if kind == b"IEND":
            return None
        at = end


def check_image_size(path, height, width):
    """FrameTooLarge when an image frame of ``height`` x ``width`` pixels (from its header) is
    beyond :data:`MAX_IMAGE_PIXELS` or its decoding (:data:`IMAGE_DECODE_BYTES_PER_PIXEL`)
    beyond half of this machine's memory; checked before any pixel is read."""
    from .raw import physical_memory

    pixels = int(height) * int(width)
    size = f"{width} x {height} image ({pixels / 1e6:.1f} MP)"
    if pixels > MAX_IMAGE_PIXELS:
        raise FrameTooLarge(f"{path}: a {size} is more than the {MAX_IMAGE_PIXELS / 1e6:.0f} MP psrig decodes "
                            "as a frame; a damaged or forged file, or crop or scale it down")
    need, budget = pixels * IMAGE_DECODE_BYTES_PER_PIXEL, physical_memory() // 2
    if budget and need > budget:
        raise FrameTooLarge(f"{path}: a {size} needs about {need / 2**30:.1f} GiB to decode, more than "
                            f"half of this machine's {2 * budget / 2**30:.1f} GiB")


@lru_cache(maxsize=64)
def _frame_format(path, mtime_ns, size):
    found = _oiio_format(path)
    if found is not None and found[0] != "tiff":
        check_image_size(path, *found[1])
        return FrameFormat("image", *found)
    if _is_camera_raw(path):
        return FrameFormat("raw", "raw")
    if found is not None:
        check_image_size(path, *found[1])
        return FrameFormat("image", *found)
    raise ImageFileError(f"{path}: neither an image nor a camera raw file psrig can decode; "
                         f"{readable_formats()}")


@lru_cache(maxsize=1)
def readable_formats():
    """One sentence naming the formats psrig decodes (OpenImageIO's plugins and LibRaw)."""
    plugins = []
    for entry in oiio.get_string_attribute("extension_list").split(";"):
        name, _, suffixes = entry.partition(":")
        if name in ("null", "term", "zfile") or not suffixes:
            continue
        plugins.append(suffixes.split(",")[0].upper())
    return (f"readable are the images OpenImageIO reads ({', '.join(plugins)}) and the camera "
            f"raw files LibRaw reads ({RAW_EXAMPLES}, ...)")
