"""Decoding of one frame file, raw or image, into linear float32 plus a saturation mask.

What a file is comes from its content (:func:`pipeline.decode.formats.frame_format`), not its
suffix: any image OpenImageIO reads, or any camera raw LibRaw reads.
"""

from pathlib import Path

import numpy as np

from ..core.errors import ImageFileError, InputError
from ..core.gamma import parse_gamma
from ..settings.decode import DecodeOptions
from .formats import frame_format
from .image import decode_image
from .raw import METHODS, bin_rgb, decode_raw, open_raw

__all__ = ["decode_frame", "frame_size", "check_options", "CHANNELS", "BINNINGS", "COMPRESSIONS"]

CHANNELS = DecodeOptions.specs()["channels"][1].choices
BINNINGS = DecodeOptions.specs()["binning"][1].choices
#: how linear/ EXRs are written: 'auto' compresses (ZIP) the frames that shrink 1.8x or more
#: (:data:`pipeline.decode.exr.AUTO_MIN_RATIO`), 'zip' every frame, 'none' none
COMPRESSIONS = DecodeOptions.specs()["compression"][1].choices


def check_options(method="mosaic", channels="rgb", binning=1, gamma="auto", compression="auto", half=False):
    """Validate decoding options; returns them normalised as a dict (gamma as 'auto', 'srgb',
    'linear' or a float)."""
    METHODS[method]  # an unknown name is an error listing the known ones
    if channels not in CHANNELS:
        raise InputError(f"channels: expected one of {', '.join(CHANNELS)}, got {channels!r}")
    if binning not in BINNINGS:
        raise InputError(f"binning: expected 1 or 2, got {binning!r}")
    if compression not in COMPRESSIONS:
        raise InputError(f"compression: expected one of {', '.join(COMPRESSIONS)}, got {compression!r}")
    if not isinstance(half, bool):
        raise InputError(f"half: expected true or false, got {half!r}")
    return {"method": method, "channels": channels, "binning": int(binning), "gamma": parse_gamma(gamma),
            "compression": compression, "half": half}


def frame_size(path, binning=1):
    """(height, width) that :func:`decode_frame` will produce, read from the header only."""
    if not Path(path).is_file():
        raise ImageFileError(f"{path}: file is missing")
    found = frame_format(path)
    if found.kind == "image":
        height, width = found.size
    else:
        with open_raw(path) as raw:
            height, width = raw.sizes.height, raw.sizes.width
    return (height // 2, width // 2) if binning == 2 else (height, width)


def decode_frame(path, *, method="mosaic", channels="rgb", binning=1, gamma="auto", decided=None):
    """Decode one frame file into linear values.

    Parameters
    ----------
    path : str or Path
        A camera raw file (anything LibRaw reads) or an image (anything OpenImageIO reads).
    method : {'mosaic', 'postprocess'}
        Raw decoding path for Bayer sensors (see :mod:`pipeline.decode.raw`); ignored for
        images.
    channels : {'rgb', 'grey'}
        Output camera RGB, or grey = the mean of R, G and B.
    binning : {1, 2}
        2: half size, each output pixel the mean of a 2x2 cell (raw: R, (G1+G2)/2, B).
    gamma : 'auto', 'srgb', 'linear' or float
        Transfer function of integer image files (see :func:`pipeline.decode.image.decode_image`).
    decided : dict, optional
        What ``gamma='auto'`` decided from the session's data for 8-bit image files that declare
        no transfer (``transfer``, ``why``).

    Returns
    -------
    linear : ndarray (H, W, C) float32
        C = 3 (rgb) or 1 (grey); 1.0 = the white level minus black. Not clipped at 0.
    saturated : ndarray (H, W) bool
        True where any channel (any binned photosite) reached the white level.
    info : dict
        ``raw`` (bool); raw files: ``sensor``, ``decoded_by``, ``cfa``, ``black`` (DN),
        ``white`` (DN); images: ``format``, ``bits``, ``transfer``, ``transfer_from``.
    """
    options = check_options(method, channels, binning, gamma)
    if not Path(path).is_file():
        raise ImageFileError(f"{path}: file is missing")
    if frame_format(path).kind == "image":
        rgb, saturated, info = decode_image(path, gamma=options["gamma"], decided=decided)
        if binning == 2:
            rgb, saturated = bin_rgb(rgb, saturated)
    else:
        rgb, saturated, info = decode_raw(path, method=method, binning=binning)
    if channels == "grey":
        rgb = rgb.mean(axis=2, keepdims=True, dtype=np.float32)
    return np.ascontiguousarray(rgb, dtype=np.float32), saturated, info
