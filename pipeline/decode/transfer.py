"""The transfer function (gamma) an integer image file declares, read from its own metadata.

OpenImageIO reports an ``oiio:ColorSpace`` for every PNG, JPEG and BMP, but for files that say
nothing it is a guess (sRGB), so the declarations are read here from the files: PNG ``cICP``,
``iCCP``, ``sRGB`` and ``gAMA`` chunks (in the precedence the PNG specification gives them),
ICC profiles (JPEG, TIFF, PNG: the tone curve of the first channel), JPEG's Exif
``ColorSpace = 1`` (sRGB), a TGA 2.0 file's gamma, and a BMP V4/V5 header's colour space.
A file that declares nothing gets the default chosen by :func:`choose_transfer`.
"""

import struct
import zlib

import numpy as np

from ..core.gamma import inverse_gamma_lut

__all__ = ["declared_transfer", "choose_transfer", "describe_transfer", "icc_transfer", "undeclared_8bit"]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_SRGB_PARAMS = np.array([2.4, 1 / 1.055, 0.055 / 1.055, 1 / 12.92, 0.04045])
_CICP = {13: "srgb", 8: "linear"}     # ITU-T H.273 transfer characteristics psrig undoes


def describe_transfer(transfer):
    """'sRGB', 'linear' or 'gamma 2.2' for messages."""
    if transfer == "srgb":
        return "sRGB"
    if transfer == "linear":
        return "linear"
    return f"gamma {float(transfer):g}"


def _power(exponent):
    """A decoding exponent as psrig's transfer value: 'linear' near 1, else the float."""
    return "linear" if abs(exponent - 1.0) < 0.01 else round(float(exponent), 4)


def _curve_transfer(curve):
    """Transfer of a sampled decoding curve (N,) in 0..1: sRGB or a power law when one fits
    within 1 % of full scale, else None."""
    codes = np.linspace(0, 1, len(curve))
    if np.abs(curve - inverse_gamma_lut("srgb", len(curve))).max() < 0.01:
        return "srgb"
    middle = (codes > 0.1) & (codes < 0.9) & (curve > 0)
    if not middle.any():
        return None
    exponent = float(np.median(np.log(curve[middle]) / np.log(codes[middle])))
    return _power(exponent) if np.abs(curve - codes ** exponent).max() < 0.01 else None


def _trc(data):
    """Transfer of an ICC 'curv' or 'para' tag, or None."""
    kind = data[:4]
    if kind == b"curv":
        count = struct.unpack(">I", data[8:12])[0]
        if count == 0:
            return "linear"
        if count == 1:
            return _power(struct.unpack(">H", data[12:14])[0] / 256.0)
        table = np.frombuffer(data[12:12 + 2 * count], ">u2").astype(np.float64) / 65535.0
        return _curve_transfer(table)
    if kind == b"para":
        function = struct.unpack(">H", data[8:10])[0]
        count = {0: 1, 1: 3, 2: 4, 3: 5, 4: 7}.get(function, 0)
        params = np.array(struct.unpack(f">{count}i", data[12:12 + 4 * count])) / 65536.0
        if function == 0:
            return _power(params[0])
        if function in (3, 4) and np.allclose(params[:5], _SRGB_PARAMS, atol=2e-3):
            return "srgb"
    return None


def _icc_name(profile, offset, size):
    """The ICC 'desc' text (v2 'desc' or v4 'mluc'), best effort."""
    data = profile[offset:offset + size]
    if data[:4] == b"desc":
        length = struct.unpack(">I", data[8:12])[0]
        return data[12:12 + length].split(b"\0")[0].decode("latin-1", "replace")
    if data[:4] == b"mluc" and len(data) >= 28:
        length, start = struct.unpack(">II", data[20:28])
        return data[start:start + length].decode("utf-16-be", "replace")
    return ""


def icc_transfer(profile):
    """(transfer or None, profile name) of an ICC profile's bytes."""
    profile = bytes(profile)
    if len(profile) < 132:
        return None, ""
    count = struct.unpack(">I", profile[128:132])[0]
    tags = {}
    for index in range(min(count, 100)):
        entry = profile[132 + 12 * index:144 + 12 * index]
        if len(entry) == 12:
            signature, offset, size = struct.unpack(">4sII", entry)
            tags[signature] = (offset, size)
    name = _icc_name(profile, *tags[b"desc"]) if b"desc" in tags else ""
    for signature in (b"rTRC", b"kTRC", b"gTRC"):
        if signature in tags:
            offset, size = tags[signature]
            return _trc(profile[offset:offset + size]), name
    return None, name


def _png_chunks(path):
    """{chunk type: data} of the chunks before the first IDAT."""
    chunks = {}
    with open(path, "rb") as fh:
        if fh.read(8) != _PNG_SIGNATURE:
            return chunks
        while True:
            head = fh.read(8)
            if len(head) < 8:
                return chunks
            length, kind = struct.unpack(">I4s", head)
            if kind == b"IDAT":
                return chunks
            chunks[kind] = fh.read(length)
            fh.seek(4, 1)   # CRC


def _from_png(path):
    chunks = _png_chunks(path)
    if b"cICP" in chunks and chunks[b"cICP"][1] in _CICP:
        return _CICP[chunks[b"cICP"][1]], f"its cICP chunk (transfer {chunks[b'cICP'][1]})"
    if b"iCCP" in chunks:
        name, _, rest = chunks[b"iCCP"].partition(b"\0")
        try:
            transfer, text = icc_transfer(zlib.decompress(rest[1:]))
        except zlib.error:
            transfer, text = None, ""
        if transfer is not None:
            return transfer, f"its ICC profile '{text or name.decode('latin-1')}'"
    if b"sRGB" in chunks:
        return "srgb", "its sRGB chunk"
    if b"gAMA" in chunks and len(chunks[b"gAMA"]) == 4:
        encoding = struct.unpack(">I", chunks[b"gAMA"])[0] / 100000.0
        if encoding > 0:
            return _power(1.0 / encoding), f"its gAMA chunk ({encoding:g})"
    return None


def _from_bmp(path):
    with open(path, "rb") as fh:
        head = fh.read(14 + 108)
    if len(head) < 14 + 108 or head[:2] != b"BM" or struct.unpack("<I", head[14:18])[0] < 108:
        return None   # BITMAPINFOHEADER and older: no colour space
    kind = head[14 + 56:14 + 60]
    if kind in (b"BGRs", b" niW"):   # 'sRGB', 'Win ' stored little-endian
        return "srgb", "its BMP colour space (sRGB)"
    if kind == b"\0\0\0\0":          # LCS_CALIBRATED_RGB: gamma per channel, 16.16 fixed
        gamma = struct.unpack("<I", head[14 + 96:14 + 100])[0] / 65536.0
        if gamma > 0:
            return _power(gamma), f"its BMP colour space (gamma {gamma:g})"
    return None


def _from_spec(spec, name):
    """From what OpenImageIO read: an ICC profile, JPEG Exif, a TGA gamma."""
    profile = spec.getattribute("ICCProfile")
    if profile is not None:
        transfer, text = icc_transfer(np.asarray(profile, np.uint8).tobytes())
        if transfer is not None:
            return transfer, f"its ICC profile '{text}'"
    if name == "jpeg" and spec.getattribute("Exif:ColorSpace") == 1:
        return "srgb", "its Exif ColorSpace (sRGB)"
    if name == "targa":
        gamma = spec.getattribute("oiio:Gamma")
        space = str(spec.getattribute("oiio:ColorSpace") or "")
        if gamma:
            return _power(float(gamma)), f"its TGA gamma ({float(gamma):g})"
        if space.startswith("lin"):
            return "linear", "its TGA gamma (1.0)"
    return None


def declared_transfer(path, name, spec):
    """(transfer, where it was read) from the file's metadata, or None when it says nothing.

    Parameters
    ----------
    path : str or Path
    name : str
        OpenImageIO's format name ('png', 'jpeg', 'bmp', 'targa', 'tiff', ...).
    spec : OpenImageIO.ImageSpec
        The file's spec (attributes as OpenImageIO read them).
    """
    readers = {"png": _from_png, "bmp": _from_bmp}
    try:
        found = readers[name](path) if name in readers else None
    except OSError:
        found = None
    return found or _from_spec(spec, name)


def choose_transfer(requested, declared, bits, decided=None):
    """(transfer, why) for an integer image file.

    ``requested`` is the decode option ('auto' or a transfer): anything but 'auto' wins.
    Otherwise the file's declaration; else, for 8-bit files, ``decided`` ({'transfer', 'why'}:
    what the decode stage read from the session's object frames,
    :mod:`pipeline.decode.autotransfer`) when given; else the default: sRGB for 8-bit files
    (cameras and editors encode them so) and linear for 16-bit ones (the photometric-stereo
    datasets that ship 16-bit PNGs without metadata, DiLiGenT among them, store linear values).
    """
    if requested != "auto":
        return requested, "--gamma"
    if declared is not None:
        return declared[0], f"declared by {declared[1]}"
    if bits <= 8 and decided:
        return decided["transfer"], decided["why"]
    if bits <= 8:
        return "srgb", "assumed: 8-bit file without colour metadata"
    return "linear", f"assumed: {bits}-bit file without colour metadata"


def undeclared_8bit(path):
    """True when ``path`` is an 8-bit integer image that declares no transfer function (the
    files ``--gamma auto`` decides from the data); reads the header only."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # not an image (a camera raw): not this function's to report
        return False
    try:
        spec, name = inp.spec(), inp.format_name()
    finally:
        inp.close()
    if spec.format.basetype not in (oiio.UINT8, oiio.INT8):
        return False
    try:
        return declared_transfer(path, name, spec) is None
    except Exception:  # an unreadable header is decode's to report, frame by frame
        return False
