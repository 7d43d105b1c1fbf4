"""Linear decoding of camera raw files (anything LibRaw reads) with rawpy.

Two paths for Bayer sensors:

* ``mosaic`` (default): straight from ``raw_image_visible``; the black level of each CFA cell
  is subtracted and the result divided by (white level - that black level), so 1.0 = the white
  level. Sub-black noise stays negative (unbiased dark values). Full size is demosaiced by a
  bilinear (normalised-convolution) interpolation, which is linear in the data; ``binning=2``
  averages each 2x2 cell to (R, (G1 + G2) / 2, B) at half size without any interpolation.
* ``postprocess``: LibRaw's own pipeline with a truly linear recipe (gamma 1, no auto
  brightness, ``adjust_maximum_thr=0``, unit white balance, raw colour space, 16 bit). LibRaw
  clips at black, so dark values are biased upwards.

X-Trans, monochrome and linear (already demosaiced) DNG files take LibRaw's linear postprocess
whatever the method, with linear interpolation for X-Trans; the frame's info records it.

Saturation is always judged on the raw values, before black subtraction: a photosite at or
above the white level is saturated, and so is every output pixel whose value it feeds.
"""

import contextlib
import os
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import rawpy

from ..core.errors import ImageFileError
from ..core.registry import Registry

__all__ = ["open_raw", "raw_layout", "decode_raw", "bilinear_demosaic", "bin2x2", "bin_rgb", "METHODS", "RawPath",
           "OTHER_LAYOUTS", "physical_memory"]

#: raw decoding paths by name (``psrig decode --method NAME``), see :class:`RawPath`
METHODS = Registry("raw decoding method")
# Bilinear interpolation as a convolution of each colour's sparse plane (zeros at the other
# colours' photosites). R and B (one per 2x2 cell): 2 orthogonal neighbours weigh 1/2 each,
# 4 diagonal ones 1/4 each. G (two per cell, on a quincunx): 4 orthogonal neighbours 1/4 each.
# The weights reaching any pixel sum to 1 in every Bayer phase.
_KERNEL = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]], np.float32)
_KERNEL_GREEN = np.array([[0, 0.25, 0], [0.25, 1.0, 0.25], [0, 0.25, 0]], np.float32)
_RAW_ERRORS = (rawpy.LibRawError, OSError, ValueError)


#: Fewest bits a raw file spends per photosite: uncompressed raws spend 8 to 16, lossless JPEG
#: (DNG, CR2, NEF) at least 1 (its shortest Huffman code). A header claiming more photosites
#: than the file could hold at this rate lies (a 346 KB file claiming 20000 x 20000).
MIN_BITS_PER_PHOTOSITE = 0.5
#: Bytes of memory decoding takes per photosite (mosaic, work arrays, the RGB float32 output
#: buffer; the postprocess path a little more).
DECODE_BYTES_PER_PHOTOSITE = 32


@contextlib.contextmanager
def open_raw(path):
    """Open a raw file with rawpy; LibRaw failures become :class:`ImageFileError` naming it.

    The size its header claims is checked before anything is decoded: against what the file
    can hold (:data:`MIN_BITS_PER_PHOTOSITE`) and against half of this machine's memory
    (:data:`DECODE_BYTES_PER_PHOTOSITE`).
    """
    try:
        raw = rawpy.imread(str(path))
    except _RAW_ERRORS as exc:
        raise ImageFileError(f"{path}: cannot read raw file ({_reason(exc)})") from None
    with raw:
        _check_claimed_size(raw.sizes, path)
        yield raw


def _check_claimed_size(sizes, path):
    """ImageFileError when a header's size cannot be true or cannot be decoded here."""
    photosites = int(sizes.raw_height) * int(sizes.raw_width)
    size = f"{sizes.raw_width} x {sizes.raw_height}"
    holds = os.path.getsize(path) * 8 / MIN_BITS_PER_PHOTOSITE
    if photosites > holds:
        raise ImageFileError(f"{path}: the header claims {size} photosites, more than the "
                             f"{os.path.getsize(path)} bytes of the file can hold; a damaged or "
                             "forged raw file")
    need, budget = photosites * DECODE_BYTES_PER_PHOTOSITE, physical_memory() // 2
    if budget and need > budget:
        raise ImageFileError(f"{path}: a {size} raw frame needs about {need / 2**30:.1f} GiB to "
                             f"decode, more than half of this machine's {2 * budget / 2**30:.1f} GiB")


def physical_memory():
    """Physical memory in bytes (0 when unknown)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 0


def _reason(exc):
    text = exc.args[0] if exc.args else type(exc).__name__
    return text.decode(errors="replace") if isinstance(text, bytes) else str(text)


#: sensor layouts that only LibRaw's linear postprocess decodes (the mosaic path is Bayer's)
OTHER_LAYOUTS = ("x-trans", "linear", "monochrome")


def raw_layout(raw, path):
    """Sensor layout, colours and levels of an open raw file.

    Returns
    -------
    dict
        ``sensor``: 'bayer' (a 2x2 RGB colour filter array), 'x-trans' (Fujifilm's 6x6),
        'linear' (a linear DNG: already demosaiced, 3 values per pixel) or 'monochrome';
        ``cfa`` str such as 'RGGB' (Bayer), 'X-Trans', 'linear RGB' or 'mono';
        ``black`` (2, 2) float, black level (DN) per cell of the Bayer cell (other layouts: the
        per-channel levels); ``white`` float, white level (DN); Bayer also ``colours`` (2, 2)
        int, 0 R / 1 G / 2 B of each cell.
    """
    pattern = raw.raw_pattern
    desc = raw.color_desc.decode(errors="replace")
    per_channel = np.asarray(raw.black_level_per_channel, np.float64)
    white = float(raw.white_level)
    if raw.raw_type == rawpy.RawType.Stack:
        return {"sensor": "linear", "cfa": "linear RGB", "black": per_channel.reshape(2, 2), "white": white}
    if raw.num_colors == 1 or pattern is None or pattern.shape == (1, 1):
        return {"sensor": "monochrome", "cfa": "mono", "black": per_channel.reshape(2, 2), "white": white}
    if pattern.shape == (6, 6) and set(desc[int(c)] for c in np.unique(pattern)) == {"R", "G", "B"}:
        return {"sensor": "x-trans", "cfa": "X-Trans", "black": per_channel.reshape(2, 2), "white": white}
    if pattern.shape != (2, 2) or raw.num_colors < 3:
        raise ImageFileError(f"{path}: a colour filter array of {pattern.shape[0]}x{pattern.shape[1]} cells "
                             f"({raw.num_colors} colours) that psrig cannot decode linearly; it decodes "
                             "Bayer, X-Trans, monochrome and linear (demosaiced) raw files")
    letters = np.array([desc[int(c)] for c in pattern.ravel()]).reshape(2, 2)
    if set(letters.ravel()) != {"R", "G", "B"}:
        raise ImageFileError(f"{path}: unsupported colour filter array {desc!r} (colours other "
                             "than red, green and blue)")
    colours = np.select([letters == "R", letters == "G"], [0, 1], 2)
    return {
        "sensor": "bayer",
        "colours": colours,
        "cfa": "".join(letters.ravel()),
        "black": per_channel[pattern],
        "white": white,
    }


def _work(scratch, name, shape):
    """A float32 work array from the caller's ``scratch`` dict, reused while the shape is the
    same (a fresh 12 MP array costs page faults, about 0.02 s of system time each), or a new
    one when ``scratch`` is None."""
    if scratch is None:
        return np.empty(shape, np.float32)
    array = scratch.get(name)
    if array is None or array.shape != tuple(shape):
        array = scratch[name] = np.empty(shape, np.float32)
    return array


def _linear_mosaic(mosaic, layout, scratch=None):
    """(mosaic - black of its cell) / (white - black of its cell), float32 (H, W)."""
    linear = _work(scratch, "linear", mosaic.shape)
    width = mosaic.shape[1]
    for i in range(2):
        # Whole rows of one Bayer phase at a time (contiguous rows, alternating black levels):
        # twice as fast as four strided passes, and the same float32 arithmetic.
        black = np.resize(layout["black"][i].astype(np.float32), width)
        scale = np.resize((1.0 / (layout["white"] - layout["black"][i])).astype(np.float32), width)
        rows = linear[i::2]
        np.subtract(mosaic[i::2], black, out=rows, dtype=np.float32)
        rows *= scale
    return linear


def bilinear_demosaic(linear, colours, out=None, scratch=None):
    """Bilinear demosaic of a linear Bayer mosaic.

    Parameters
    ----------
    linear : ndarray (H, W) float32
        Black-subtracted mosaic.
    colours : ndarray (2, 2) int
        Colour (0 R, 1 G, 2 B) of each cell of the 2x2 Bayer cell.
    out : sequence of 3 ndarray (H, W) float32, optional
        R, G and B planes to write into (rows may be strided, e.g. views into a file buffer).
    scratch : dict, optional
        Work arrays kept between calls (see :func:`decode_raw`).

    Returns
    -------
    ndarray (H, W, 3) float32, or ``out``
        RGB; measured samples are kept as they are, the others are the mean of their nearest
        2 or 4 samples of that colour.
    """
    planes = []
    sparse = _work(scratch, "sparse", linear.shape)
    for channel in range(3):
        sparse.fill(0)
        for i, j in zip(*np.nonzero(colours == channel)):
            sparse[i::2, j::2] = linear[i::2, j::2]
        kernel = _KERNEL_GREEN if channel == 1 else _KERNEL
        # Reflect-101 mirrors about the edge photosite, which keeps the Bayer phase, so edge
        # pixels average the mirrored samples with the same weights.
        if out is None:
            planes.append(cv2.filter2D(sparse, -1, kernel, borderType=cv2.BORDER_REFLECT_101))
        elif cv2.filter2D(sparse, -1, kernel, dst=out[channel],
                          borderType=cv2.BORDER_REFLECT_101) is not out[channel]:
            raise ValueError("bilinear_demosaic: out planes must be float32 (H, W) arrays "
                             "with contiguous rows")
    return cv2.merge(planes) if out is None else out


def bin2x2(linear, colours):
    """Half-size RGB from a linear Bayer mosaic: (R, (G1 + G2) / 2, B) per 2x2 cell.

    Parameters
    ----------
    linear : ndarray (H, W) float32
    colours : ndarray (2, 2) int

    Returns
    -------
    ndarray (H // 2, W // 2, 3) float32 (an odd last row / column is dropped)
    """
    height, width = (linear.shape[0] // 2) * 2, (linear.shape[1] // 2) * 2
    cells = [linear[i:height:2, j:width:2] for i in range(2) for j in range(2)]
    flat = colours.ravel()
    greens = [c for c, k in zip(cells, flat) if k == 1]
    red = cells[int(np.flatnonzero(flat == 0)[0])]
    blue = cells[int(np.flatnonzero(flat == 2)[0])]
    return np.stack([red, (greens[0] + greens[1]) * np.float32(0.5), blue], axis=2)


def _saturation(mosaic, white, binning, reach):
    """Saturated output pixels: raw >= white, spread to every output pixel it feeds."""
    clipped = mosaic >= white
    if binning == 2:
        height, width = (mosaic.shape[0] // 2) * 2, (mosaic.shape[1] // 2) * 2
        return clipped[:height, :width].reshape(height // 2, 2, width // 2, 2).any(axis=(1, 3))
    if not clipped.any():
        return clipped
    kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    return cv2.dilate(clipped.view(np.uint8), kernel).astype(bool)


def _postprocess(raw, layout, binning):
    """LibRaw's linear pipeline; 1.0 = white minus each colour's black.

    LibRaw scales every colour by 1 / (white - smallest black); unit white balance would thus
    leave channels with a higher black below 1.0 at white. Per-colour multipliers
    (white - smallest black) / (white - black) fix that before demosaicing. LibRaw merges the
    two greens before scaling, so both use the mean of their black levels.
    """
    white, black, colours = layout["white"], layout["black"], layout["colours"]
    common = white - black.min()
    gains = [common / (white - black[colours == c].mean()) for c in range(3)]
    rgb16 = raw.postprocess(
        gamma=(1, 1), no_auto_bright=True, adjust_maximum_thr=0.0, use_camera_wb=False,
        use_auto_wb=False, user_wb=gains + [gains[1]], output_color=rawpy.ColorSpace.raw,
        output_bps=16, half_size=binning == 2, user_flip=0, bright=1.0, highlight_mode=0)
    return rgb16.astype(np.float32) * np.float32(1.0 / 65535.0)


@dataclass(frozen=True)
class RawPath:
    """A raw decoding path: ``decode(raw, mosaic, layout, binning, out, scratch) -> rgb`` and
    ``reach``, how many output pixels a clipped photosite can spill into (its demosaic's
    footprint), over which saturation is flagged."""

    decode: Callable
    reach: int


def _mosaic_path(raw, mosaic, layout, binning, out, scratch):
    linear = _linear_mosaic(mosaic, layout, scratch)
    if binning == 2:
        return bin2x2(linear, layout["colours"])
    return bilinear_demosaic(linear, layout["colours"], out=out, scratch=scratch)


def _postprocess_path(raw, mosaic, layout, binning, out, scratch):
    return _postprocess(raw, layout, binning)


METHODS.register("mosaic", RawPath(_mosaic_path, 1))
METHODS.register("postprocess", RawPath(_postprocess_path, 2))


def bin_rgb(rgb, saturated):
    """2x2 mean of an RGB image (H, W, C); a bin is saturated when any of its pixels is.
    An odd last row or column is dropped."""
    height, width = (rgb.shape[0] // 2) * 2, (rgb.shape[1] // 2) * 2
    cells = rgb[:height, :width].reshape(height // 2, 2, width // 2, 2, rgb.shape[2])
    flags = saturated[:height, :width].reshape(height // 2, 2, width // 2, 2)
    return cells.mean(axis=(1, 3), dtype=np.float32), flags.any(axis=(1, 3))


def _other_layout(raw, mosaic, layout, binning):
    """X-Trans, linear DNG or monochrome: LibRaw's linear postprocess, (H, W, 3) and saturation.

    The recipe is the postprocess path's (gamma 1, no auto brightness, raw colour space, per
    colour gains that put each colour's white at 1.0), with LibRaw's linear interpolation for
    X-Trans: linear in the data like the Bayer mosaic path, while LibRaw's default X-Trans
    demosaic (Markesteijn) is not, and fails on frames under about 600 x 900 photosites.
    """
    white = layout["white"]
    black = layout["black"].ravel()
    colours = 1 if layout["sensor"] == "monochrome" else 3
    common = white - black[:colours].min()
    gains = [common / (white - black[min(c, colours - 1)]) for c in range(3)]
    rgb16 = raw.postprocess(
        gamma=(1, 1), no_auto_bright=True, adjust_maximum_thr=0.0, use_camera_wb=False,
        use_auto_wb=False, user_wb=gains + [gains[1]], output_color=rawpy.ColorSpace.raw,
        output_bps=16, user_flip=0, bright=1.0, highlight_mode=0,
        demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR)
    rgb = rgb16.astype(np.float32) * np.float32(1.0 / 65535.0)
    if rgb.shape[2] == 1:
        rgb = np.repeat(rgb, 3, axis=2)
    clipped = mosaic >= white
    if clipped.ndim == 3:            # linear DNG: (H, W, 4) values per pixel
        saturated = clipped[:, :, :colours].any(axis=2)
    elif layout["sensor"] == "x-trans" and clipped.any():   # linear interpolation: 3 x 3
        saturated = cv2.dilate(clipped.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    else:
        saturated = clipped
    height, width = min(rgb.shape[0], saturated.shape[0]), min(rgb.shape[1], saturated.shape[1])
    rgb, saturated = rgb[:height, :width], saturated[:height, :width]
    return bin_rgb(rgb, saturated) if binning == 2 else (rgb, saturated)


def decode_raw(path, *, method="mosaic", binning=1, out=None, scratch=None):
    """Decode a raw file to linear RGB.

    Parameters
    ----------
    path : str or Path
    method : {'mosaic', 'postprocess'}
        For Bayer sensors; X-Trans, monochrome and linear DNG files always take LibRaw's
        linear postprocess (recorded in ``info``).
    binning : {1, 2}
    out : sequence of 3 ndarray (H, W) float32, optional
        At full size only: R, G, B planes to decode into (e.g. views into an output file's
        bytes, see :class:`pipeline.decode.exr.ExrBuffer`): the mosaic path demosaics
        straight into them, other layouts are copied; (H, W) must be the visible raw size.
    scratch : dict, optional
        Work arrays (mosaic path) kept here and reused by the next call with the same dict,
        e.g. by a worker decoding many frames of one size. Not shared between threads.

    Returns
    -------
    rgb : ndarray (H, W, 3) float32, or ``out``
        Camera RGB, 1.0 = white level minus black; negative values kept on the mosaic path.
    saturated : ndarray (H, W) bool
    info : dict
        ``raw`` True, ``sensor`` ('bayer', 'x-trans', 'linear', 'monochrome'), ``decoded_by``
        ('mosaic' or 'postprocess'), ``cfa``, ``black`` (4 values, DN: in CFA order for
        Bayer, per channel otherwise), ``white`` (DN).
    """
    chosen = METHODS[method]
    if out is not None and binning != 1:
        raise ValueError("decode_raw: out is only for the mosaic path at full size")
    with open_raw(path) as raw:
        try:
            # rawpy reads the data lazily: a truncated file fails on first access, here.
            layout = raw_layout(raw, path)
            if out is not None and method != "mosaic" and layout["sensor"] == "bayer":
                raise ValueError("decode_raw: out is only for the mosaic path at full size")
            mosaic = raw.raw_image_visible
            if out is not None and tuple(mosaic.shape[:2]) != tuple(out[0].shape):
                raise ImageFileError(f"{path}: decoded to {tuple(mosaic.shape[:2])}, expected "
                                     f"{tuple(out[0].shape)} like the other frames")
            if layout["sensor"] != "bayer":
                rgb, saturated = _other_layout(raw, mosaic, layout, binning)
                decoded_by = "postprocess"
            else:
                # Judged on the raw values, before LibRaw's postprocess touches anything (and
                # while the file is open: no copy of the mosaic needed).
                saturated = _saturation(mosaic, layout["white"], binning, chosen.reach)
                rgb = chosen.decode(raw, mosaic, layout, binning, out, scratch)
                decoded_by = method
        except _RAW_ERRORS as exc:
            raise ImageFileError(f"{path}: cannot decode raw data ({_reason(exc)})") from None
    info = {"raw": True, "sensor": layout["sensor"], "decoded_by": decoded_by, "cfa": layout["cfa"],
            "black": layout["black"].ravel().tolist(), "white": layout["white"]}
    if out is not None:
        if rgb is not out:
            for channel, plane in enumerate(out):
                plane[...] = rgb[:, :, channel]
        return out, saturated, info
    height, width = min(rgb.shape[0], saturated.shape[0]), min(rgb.shape[1], saturated.shape[1])
    return rgb[:height, :width], saturated[:height, :width], info
