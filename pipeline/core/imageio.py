"""Image files in and out, on OpenImageIO.

Reading always returns float32 arrays of shape (H, W, C): integer files are scaled so that the
type's maximum is 1.0 (uint8 / 255, uint16 / 65535); float files (EXR, float TIFF) are returned
as stored. Writing picks the pixel type from the extension unless ``bits`` says otherwise, and
every write is atomic.
"""

import os

import numpy as np
import OpenImageIO as oiio

from .atomic import atomic_path
from .errors import ImageFileError

__all__ = [
    "read_image",
    "read_image_native",
    "image_size",
    "write_image",
    "read_mask",
    "write_mask",
    "read_normal_png",
    "write_normal_png",
    "encode_normals_png",
    "read_workers",
]

_DEFAULT_BITS = {".exr": 32, ".png": 16, ".tif": 16, ".tiff": 16, ".jpg": 8, ".jpeg": 8, ".tga": 8}
_BITS_TO_TYPE = {8: oiio.UINT8, 16: oiio.UINT16, 32: oiio.FLOAT}
_CHANNEL_NAMES = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}


def _open(path):
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageFileError(f"{path}: cannot read image ({oiio.geterror() or 'unknown format'})")
    return inp


def read_image_native(path):
    """Read an image in its stored pixel type.

    Returns
    -------
    pixels : ndarray (H, W, C)
        uint8, uint16 or float32, as stored in the file.
    """
    inp = _open(path)
    try:
        pixels = inp.read_image(oiio.UNKNOWN)  # stored type; the default would convert to float
        if pixels is None:
            raise ImageFileError(f"{path}: truncated or corrupt image ({inp.geterror()})")
        spec = inp.spec()
    finally:
        inp.close()
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    return pixels.reshape(spec.height, spec.width, spec.nchannels)


def read_image(path):
    """Read an image as float32 (H, W, C); integer types scaled so their maximum is 1.0."""
    return to_float(read_image_native(path))


def to_float(pixels):
    """Pixels as :func:`read_image` returns them: float32, integer types scaled so their maximum
    is 1.0; float32 input is returned as it is (not copied)."""
    if np.issubdtype(pixels.dtype, np.integer):
        scaled = pixels.astype(np.float32)
        return np.divide(scaled, np.float32(np.iinfo(pixels.dtype).max), out=scaled)
    return pixels.astype(np.float32, copy=False)


def _above_half(dtype):
    """(max + 1,) bool: which values of an integer type :func:`read_image` scales above 0.5."""
    values = np.arange(np.iinfo(dtype).max + 1, dtype=dtype)
    return to_float(values) > 0.5


def image_size(path):
    """Return (height, width, channels) of an image file without reading its pixels."""
    inp = _open(path)
    spec = inp.spec()
    inp.close()
    return spec.height, spec.width, spec.nchannels


def write_image(path, pixels, bits=None, compression=None, channel_names=None):
    """Write an image atomically.

    Parameters
    ----------
    path : str or Path
        Destination; the extension chooses the format (.exr, .png, .tif, .jpg, .tga).
    pixels : ndarray (H, W) or (H, W, C)
        Float arrays are taken as 0..1 and scaled to the integer type (rounded, clipped);
        integer arrays are written as they are.
    bits : {8, 16, 32}, optional
        Pixel type: 8 / 16 bit unsigned or 32-bit float. Default by extension (EXR 32,
        PNG/TIFF 16, JPG/TGA 8).
    channel_names : sequence of str, optional
        Names of the channels (EXR); default Y / RGB / RGBA, or c00, c01, ... beyond 4 channels.
        EXR stores channels sorted by name and readers put R, G, B, A first, so names must sort
        in the intended order and must not end in a bare R, G, B or A (not even "layer.A").
    compression : str, optional
        EXR compression ('zip', 'none', 'piz', ...). Default 'zip'; 'none' is several times
        faster to write for large noisy frames, which barely compress.
    """
    from pathlib import Path

    path = Path(path)
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    if pixels.ndim != 3 or (pixels.shape[2] not in _CHANNEL_NAMES and channel_names is None
                            and path.suffix.lower() != ".exr"):
        raise ImageFileError(f"{path}: cannot write an array of shape {pixels.shape} as an image")
    bits = bits or _DEFAULT_BITS.get(path.suffix.lower())
    if bits not in _BITS_TO_TYPE:
        raise ImageFileError(f"{path}: unsupported image extension or bit depth {bits}")
    data = _convert(pixels, bits)
    height, width, channels = data.shape
    spec = oiio.ImageSpec(width, height, channels, _BITS_TO_TYPE[bits])
    spec.channelnames = tuple(channel_names or _CHANNEL_NAMES.get(channels)
                              or [f"c{i:02d}" for i in range(channels)])
    if bits == 32 and path.suffix.lower() == ".exr":
        spec.attribute("compression", compression or "zip")
    elif bits != 32:
        # no colour-space claim (OpenImageIO 3 marks every PNG sRGB unless told): a 16-bit
        # linear frame must not declare sRGB to the decoder, which trusts what a file says
        spec.attribute("oiio:ColorSpace", "data")
    # No write-time stamp: identical pixels give identical bytes, so an unchanged rerun of a
    # stage does not change the hashes that later stages check.
    spec.attribute("DateTime", "")
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise ImageFileError(f"{path}: cannot write image ({oiio.geterror()})")
        ok = out.write_image(np.ascontiguousarray(data))
        out.close()
        if not ok:
            raise ImageFileError(f"{path}: writing failed ({out.geterror()})")


def _convert(pixels, bits):
    if bits == 32:
        return pixels.astype(np.float32, copy=False)
    dtype = np.uint8 if bits == 8 else np.uint16
    if np.issubdtype(pixels.dtype, np.integer):
        return pixels.astype(dtype)
    top = np.iinfo(dtype).max
    return np.clip(np.rint(np.nan_to_num(pixels) * top), 0, top).astype(dtype)


_ABOVE_HALF = {}


def read_mask(path):
    """Read a mask image as bool (H, W): true where any channel is above half scale."""
    pixels = read_image_native(path)
    if pixels.dtype in (np.uint8, np.uint16):
        # a table of the 256 or 65536 values, decided as read_image's floats would be, instead
        # of a float32 copy of the image
        table = _ABOVE_HALF.get(pixels.dtype.type)
        if table is None:
            table = _ABOVE_HALF.setdefault(pixels.dtype.type, _above_half(pixels.dtype))
        above = table[pixels]
    else:
        above = to_float(pixels) > 0.5
    return above.any(axis=2) if above.shape[2] > 1 else above[:, :, 0]


def write_mask(path, mask):
    """Write a bool (H, W) mask as an 8-bit PNG (0 / 255)."""
    write_image(path, np.asarray(mask, dtype=np.uint8) * np.uint8(255), bits=8)


def encode_normals_png(normals, mask=None):
    """Encode unit normals (H, W, 3) as uint16 RGB = (n + 1) / 2 * 65535; 0 outside ``mask``."""
    encoded = np.clip(np.rint((np.asarray(normals, np.float64) + 1.0) * 0.5 * 65535), 0, 65535)
    encoded = encoded.astype(np.uint16)
    if mask is not None:
        encoded[~np.asarray(mask, bool)] = 0
    return encoded


def write_normal_png(path, normals, mask=None):
    """Write normals (H, W, 3), camera frame, as a 16-bit PNG in DiLiGenT's encoding."""
    write_image(path, encode_normals_png(normals, mask), bits=16)


def read_normal_png(path):
    """Read a normal-map PNG in DiLiGenT's encoding.

    Returns
    -------
    normals : ndarray (H, W, 3) float32
        Unit vectors, camera frame; zero where the pixel is black (outside the object).
    mask : ndarray (H, W) bool
        Pixels that carry a normal.
    """
    rgb = read_image(path)
    if rgb.shape[2] < 3:
        raise ImageFileError(f"{path}: a normal map needs 3 channels, found {rgb.shape[2]}")
    rgb = rgb[:, :, :3]
    mask = rgb.any(axis=2)
    normals = rgb * 2.0 - 1.0
    norm = np.linalg.norm(normals, axis=2, keepdims=True)
    mask &= norm[:, :, 0] > 0.5
    normals = np.where(mask[:, :, None], normals / np.maximum(norm, 1e-12), 0.0)
    return normals.astype(np.float32), mask


def read_workers():
    """Threads that read frames: the cores this process may use, at most 8 (OpenImageIO's
    read and the EXR decompression release the GIL; beyond the cores they only add frames in
    flight, each one frame's worth of memory)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(8, cores))
