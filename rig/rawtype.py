"""What kind of file a camera delivered, told from its bytes, never from its name.

A camera's file name is the camera's business: it may hold a NUL, path separators or an
extension that lies (an ``.EXR`` name on a DNG would make decode take the raw for a finished
image). psrig names raw files itself (``raw/<frame id>.<ext>``) with the extension this module
reads from the content, and keeps the camera's name only as metadata in the manifest.
"""

import struct

__all__ = ["raw_extension", "RawTypeError", "TIFF_RAW_EXTENSIONS"]

TIFF_RAW_EXTENSIONS = ("dng", "nef", "nrw", "cr2", "arw", "pef", "tif")
"""Extensions of TIFF-based raw files (the rig's ``raw_format`` may name one of them)."""

_DNG_VERSION = 50706   # TIFF tag DNGVersion: only DNG files carry it
_MAKE = 271            # TIFF tag Make
_MAKERS = {b"NIKON": "nef", b"SONY": "arw", b"PENTAX": "pef", b"RICOH": "pef"}
_MAX_IFD_ENTRIES = 4096


class RawTypeError(ValueError):
    """The bytes are no raw or image format psrig knows."""


def raw_extension(data, fallback=None):
    """The file extension (without dot) for a camera's file, from its first bytes.

    Parameters
    ----------
    data : bytes
        The file as the camera delivered it.
    fallback : str, optional
        The rig's ``raw_format``: used for a TIFF-based file whose maker the content does not
        tell, when it names a TIFF-based raw format.

    Returns
    -------
    str
        'dng', 'cr2', 'cr3', 'nef', 'arw', 'pef', 'raf', 'orf', 'rw2', 'jpg' or 'tif'.

    Raises
    ------
    RawTypeError
        For content that is none of these (the message shows its first bytes).
    """
    head = bytes(data[:16])
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return _tiff_kind(data, fallback)
    for magic, ext in ((b"FUJIFILMCCD-RAW", "raf"), (b"IIRO", "orf"), (b"IIRS", "orf"),
                       (b"MMOR", "orf"), (b"IIU\x00", "rw2"), (b"\xff\xd8\xff", "jpg")):
        if head.startswith(magic):
            return ext
    if head[4:8] == b"ftyp" and head[8:12] == b"crx ":
        return "cr3"
    raise RawTypeError(f"not a raw or image format psrig knows (it starts with {head[:8]!r}, "
                       f"{len(data)} bytes)")


def _tiff_kind(data, fallback):
    if data[8:11] == b"CR\x02":
        return "cr2"
    tags = _ifd0_tags(data)
    if _DNG_VERSION in tags:
        return "dng"
    make = tags.get(_MAKE, b"").strip(b"\x00 ").upper()
    for maker, ext in _MAKERS.items():
        if make.startswith(maker):
            return ext
    if fallback in TIFF_RAW_EXTENSIONS:
        return fallback
    return "tif"


def _ifd0_tags(data):
    """{tag: raw value bytes (Make) or True} of the first IFD; {} when it cannot be read."""
    order = "<" if data[:2] == b"II" else ">"
    try:
        (offset,) = struct.unpack_from(order + "I", data, 4)
        (count,) = struct.unpack_from(order + "H", data, offset)
        tags = {}
        for i in range(min(count, _MAX_IFD_ENTRIES)):
            tag, kind, n, value = struct.unpack_from(order + "HHII", data, offset + 2 + 12 * i)
            if tag == _MAKE and kind == 2:  # ASCII, inline when 4 bytes or fewer
                start = offset + 2 + 12 * i + 8 if n <= 4 else value
                tags[tag] = bytes(data[start:start + min(n, 64)])
            else:
                tags[tag] = True
        return tags
    except struct.error:
        return {}
