"""Decoding of one frame file, raw or image, into linear float32 plus a saturation mask."""

from pathlib import Path

import numpy as np

from ..gamma import parse_gamma
from .image import IMAGE_SUFFIXES, decode_image
from .raw import METHODS, decode_raw, open_raw
from ..errors import ImageFileError, InputError
from ..imageio import image_size

__all__ = ["decode_frame", "frame_size", "is_image_file", "check_options", "CHANNELS", "BINNINGS"]

CHANNELS = ("rgb", "grey")
BINNINGS = (1, 2)


def is_image_file(path):
    """True for already-decoded image files (PNG, TIFF, EXR, JPG), False for camera raw."""
    return Path(path).suffix.lower() in IMAGE_SUFFIXES


def check_options(method, channels, binning, gamma):
    """Validate decoding options; returns them normalised (gamma as 'srgb' or float)."""
    METHODS[method]  # an unknown name is an error listing the known ones
    if channels not in CHANNELS:
        raise InputError(f"channels: expected one of {', '.join(CHANNELS)}, got {channels!r}")
    if binning not in BINNINGS:
        raise InputError(f"binning: expected 1 or 2, got {binning!r}")
    return method, channels, int(binning), parse_gamma(gamma)


def frame_size(path, binning=1):
    """(height, width) that :func:`decode_frame` will produce, read from the header only."""
    if not Path(path).is_file():
        raise ImageFileError(f"{path}: file is missing")
    if is_image_file(path):
        height, width, _ = image_size(path)
    else:
        with open_raw(path) as raw:
            height, width = raw.sizes.height, raw.sizes.width
    return (height // 2, width // 2) if binning == 2 else (height, width)


def _bin_image(rgb, saturated):
    """2x2 mean of an RGB image; a bin is saturated when any of its pixels is."""
    height, width = (rgb.shape[0] // 2) * 2, (rgb.shape[1] // 2) * 2
    cells = rgb[:height, :width].reshape(height // 2, 2, width // 2, 2, rgb.shape[2])
    flags = saturated[:height, :width].reshape(height // 2, 2, width // 2, 2)
    return cells.mean(axis=(1, 3), dtype=np.float32), flags.any(axis=(1, 3))


def decode_frame(path, *, method="mosaic", channels="rgb", binning=1, gamma="srgb"):
    """Decode one frame file into linear values.

    Parameters
    ----------
    path : str or Path
        A camera raw file (anything LibRaw reads) or an image (PNG, TIFF, EXR, JPG).
    method : {'mosaic', 'postprocess'}
        Raw decoding path (see :mod:`pipeline.decode.raw`); ignored for images.
    channels : {'rgb', 'grey'}
        Output camera RGB, or grey = the mean of R, G and B.
    binning : {1, 2}
        2: half size, each output pixel the mean of a 2x2 cell (raw: R, (G1+G2)/2, B).
    gamma : 'srgb' or float
        Encoding of 8-bit image files.

    Returns
    -------
    linear : ndarray (H, W, C) float32
        C = 3 (rgb) or 1 (grey); 1.0 = the white level minus black. Not clipped at 0.
    saturated : ndarray (H, W) bool
        True where any channel (any binned photosite) reached the white level.
    info : dict
        ``raw`` (bool) and, for raw files, ``cfa``, ``black`` (DN, CFA order), ``white`` (DN).
    """
    method, channels, binning, gamma = check_options(method, channels, binning, gamma)
    if not Path(path).is_file():
        raise ImageFileError(f"{path}: file is missing")
    if is_image_file(path):
        rgb, saturated, info = decode_image(path, gamma=gamma)
        if binning == 2:
            rgb, saturated = _bin_image(rgb, saturated)
    else:
        rgb, saturated, info = decode_raw(path, method=method, binning=binning)
    if channels == "grey":
        rgb = rgb.mean(axis=2, keepdims=True, dtype=np.float32)
    return np.ascontiguousarray(rgb, dtype=np.float32), saturated, info
