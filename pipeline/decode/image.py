"""Frames that are already images (PNG, TIFF, EXR, JPG) turned into linear RGB.

16-bit integer and float files are taken as linear (16-bit: value / 65535). 8-bit files are
display-encoded: their gamma is undone (the sRGB curve by default, or a power law), and they are
reported as not raw. An integer value at the type's maximum is saturated.
"""

import numpy as np

from ..errors import InputError
from ..gamma import inverse_gamma_lut, parse_gamma
from ..imageio import read_image_native

__all__ = ["IMAGE_SUFFIXES", "decode_image"]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".exr", ".jpg", ".jpeg")


def _to_rgb(pixels, path):
    channels = pixels.shape[2]
    if channels in (1, 2):
        return np.repeat(pixels[:, :, :1], 3, axis=2)
    if channels in (3, 4):
        return pixels[:, :, :3]
    raise InputError(f"{path}: cannot use an image with {channels} channels as a frame")


def decode_image(path, *, gamma="srgb"):
    """Read an image frame as linear RGB.

    Parameters
    ----------
    path : str or Path
    gamma : 'srgb' or float
        Encoding of 8-bit files (ignored for 16-bit and float files).

    Returns
    -------
    rgb : ndarray (H, W, 3) float32
        Linear, 1.0 = the type's maximum (16-bit) or as stored (float).
    saturated : ndarray (H, W) bool
        Integer files: any channel at the type's maximum. Float files: none.
    info : dict
        ``raw`` False, ``bits`` (8, 16 or 32), ``gamma`` for 8-bit files.
    """
    native = _to_rgb(read_image_native(path), path)
    info = {"raw": False, "bits": native.dtype.itemsize * 8}
    if native.dtype == np.uint8:
        info["gamma"] = parse_gamma(gamma)
        rgb = inverse_gamma_lut(gamma)[native]
    elif np.issubdtype(native.dtype, np.integer):
        rgb = native.astype(np.float32) * np.float32(1.0 / np.iinfo(native.dtype).max)
    else:
        return native.astype(np.float32), np.zeros(native.shape[:2], bool), info
    saturated = (native == np.iinfo(native.dtype).max).any(axis=2)
    return rgb, saturated, info
