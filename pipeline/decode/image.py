"""Frames that are already images (any format OpenImageIO reads) turned into linear RGB.

Float files (EXR, float TIFF, HDR) are linear as stored. Integer files (8 or 16 bit) have their
transfer function undone: the one the file declares in its metadata
(:mod:`pipeline.decode.transfer`), else sRGB for 8-bit and linear for 16-bit files, unless the
``gamma`` option names one; the choice and where it came from go into the frame's info. An
integer value at the type's maximum is saturated.
"""

import numpy as np
import OpenImageIO as oiio

from ..core.errors import ImageFileError, InputError
from ..core.gamma import inverse_gamma_lut, parse_gamma
from .formats import check_image_size
from .transfer import choose_transfer, declared_transfer

__all__ = ["decode_image", "read_native"]


def _to_rgb(pixels, path):
    channels = pixels.shape[2]
    if channels in (1, 2):
        return np.repeat(pixels[:, :, :1], 3, axis=2)
    if channels in (3, 4):
        return pixels[:, :, :3]
    raise InputError(f"{path}: cannot use an image with {channels} channels as a frame")


def read_native(path):
    """(pixels (H, W, C) in the stored type, OpenImageIO format name, spec) of an image file."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageFileError(f"{path}: cannot read image ({oiio.geterror() or 'unknown format'})")
    try:
        spec, name = inp.spec(), inp.format_name()
        check_image_size(path, spec.height, spec.width)   # before any pixel is read
        # stored type (the default would convert to float); 1-, 2- and 4-bit files come as uint8
        pixels = inp.read_image(oiio.UNKNOWN)
        if pixels is None:
            # one line: OpenImageIO passes on libpng's lines as they came
            said = " ".join(inp.geterror().split())
            raise ImageFileError(f"{path}: truncated or corrupt image ({said})")
    finally:
        inp.close()
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    return pixels.reshape(spec.height, spec.width, spec.nchannels), name, spec


def _finite(linear, path):
    """``linear``, refused when it holds NaN or infinite values (float files can; integer ones
    cannot): photometric stereo would silently lose every pixel they touch."""
    finite = np.isfinite(linear)
    if not finite.all():
        bad = int(finite.size - np.count_nonzero(finite))
        raise ImageFileError(f"{path}: {bad} value{'s' * (bad != 1)} NaN or infinite; a frame "
                             "must hold finite linear values")
    return linear


def decode_image(path, *, gamma="auto", decided=None):
    """Read an image frame as linear RGB.

    Parameters
    ----------
    path : str or Path
    gamma : 'auto', 'srgb', 'linear' or float
        Transfer function of integer files: 'auto' takes what the file declares, else sRGB
        (8-bit) or linear (16-bit); any other value is applied to every integer file. Float
        files are always linear.
    decided : dict, optional
        ``transfer`` and ``why``: what ``--gamma auto`` decided from the session's data for
        8-bit files that declare nothing (:mod:`pipeline.decode.autotransfer`).

    Returns
    -------
    rgb : ndarray (H, W, 3) float32
        Linear, 1.0 = the type's maximum (integer files) or as stored (float).
    saturated : ndarray (H, W) bool
        Integer files: any channel at the type's maximum. Float files: none.
    info : dict
        ``raw`` False, ``format`` (OpenImageIO's name), ``bits`` (8, 16 or 32), ``transfer``
        ('srgb', 'linear' or the exponent) and ``transfer_from`` (why); ``gamma``, the same
        value, when an encoding was undone.
    """
    native, name, spec = read_native(path)
    native = _to_rgb(native, path)
    info = {"raw": False, "format": name, "bits": native.dtype.itemsize * 8}
    if not np.issubdtype(native.dtype, np.integer):
        info.update(transfer="linear", transfer_from="floating-point file")
        return _finite(native.astype(np.float32), path), np.zeros(native.shape[:2], bool), info
    if native.dtype not in (np.uint8, np.uint16):
        native = (native >> (8 * (native.dtype.itemsize - 2))).astype(np.uint16)  # 32-bit integers
        info["bits"] = 16
    transfer, why = choose_transfer(parse_gamma(gamma), declared_transfer(path, name, spec), info["bits"],
                                     decided)
    info.update(transfer=transfer, transfer_from=why)
    if transfer != "linear":
        info["gamma"] = transfer
    top = int(np.iinfo(native.dtype).max)
    if transfer == "linear" and native.dtype == np.uint16:
        # the float32 product of earlier versions, bit for bit (a table lookup rounds differently)
        rgb = native.astype(np.float32) * np.float32(1.0 / top)
    else:
        rgb = inverse_gamma_lut(transfer, levels=top + 1)[native]
    saturated = (native == np.iinfo(native.dtype).max).any(axis=2)
    return rgb, saturated, info
