"""Pictures for the HTML report: tone mapping, thumbnails, colour-mapped maps on stated scales,
colour bars, and the status map in the one status palette (8-bit RGB).

All functions take float arrays in the pipeline's conventions and return (h, w, 3) uint8 arrays
ready for :func:`pipeline.core.imageio.write_image` with ``bits=8``.
"""

import warnings
from dataclasses import dataclass

import numpy as np

from ..core.gamma import encode_gamma

__all__ = ["shrink", "srgb8", "tone_map", "normals_rgb", "colour_map", "colour_bar", "status_rgb",
           "status_legend", "robust_max", "Scale"]


@dataclass(frozen=True)
class Scale:
    """A stated colour scale: ``bottom`` .. ``top`` in ``unit`` through a matplotlib colormap.

    Values beyond either end take the end's colour (the colour bar says so).
    """

    name: str
    bottom: float
    top: float
    unit: str = ""
    cmap: str = "viridis"

    def label(self, value):
        """A tick label: the value with its unit."""
        text = f"{value:.3g}"
        return f"{text} {self.unit}".strip()


def shrink(image, max_side):
    """Block-average an (H, W, C) image so that its longer side is at most ``max_side``."""
    image = np.asarray(image, np.float32)
    step = max(1, int(np.ceil(max(image.shape[:2]) / max_side)))
    if step == 1:
        return image
    h, w = (image.shape[0] // step) * step, (image.shape[1] // step) * step
    colours = image.shape[2]
    if not np.isnan(image[:h, :w]).any():
        # frames: OpenCV's area resampling at a whole step is the block mean (to float32
        # rounding), 25 x faster than numpy's strided mean over 4 MP frames
        import cv2

        if colours <= 4:
            small = cv2.resize(image[:h, :w], (w // step, h // step), interpolation=cv2.INTER_AREA)
            return small.reshape(h // step, w // step, colours)
        return image[:h, :w].reshape(h // step, step, w // step, step, colours).mean(axis=(1, 3))
    blocks = image[:h, :w].reshape(h // step, step, w // step, step, colours)
    # nanmean: depth and masked maps carry NaN outside the object; an all-NaN block stays NaN
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(blocks, axis=(1, 3))


def robust_max(values, percentile=99.5):
    """A high percentile of the finite positive values (1.0 when there are none)."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values) & (values > 0)]
    return float(np.percentile(values, percentile)) if values.size else 1.0


def _rgb(image):
    image = np.asarray(image, np.float32)
    if image.ndim == 2:
        image = image[:, :, None]
    return np.repeat(image[:, :, :1], 3, axis=2) if image.shape[2] < 3 else image[:, :, :3]


def srgb8(linear):
    """Linear 0..1 values -> sRGB-encoded uint8 (values outside 0..1 clipped, NaN black)."""
    return (encode_gamma(np.nan_to_num(np.asarray(linear, np.float32)), "srgb") * 255 + 0.5).astype(np.uint8)


def tone_map(linear, white):
    """Linear image (H, W[, C]) -> uint8 RGB, ``white`` mapped to display white."""
    return srgb8(_rgb(linear) / max(float(white), 1e-12))


def normals_rgb(normals, mask=None):
    """Normals (H, W, 3) -> uint8 RGB = (n + 1) / 2, black outside ``mask``."""
    normals = np.nan_to_num(np.asarray(normals, np.float64)[:, :, :3])
    rgb = (np.clip((normals + 1) / 2, 0, 1) * 255 + 0.5).astype(np.uint8)
    if mask is None:
        mask = (normals != 0).any(axis=2)
    rgb[~np.asarray(mask, bool)] = 0
    return rgb


def colour_map(values, scale):
    """Scalar map (H, W) -> uint8 RGB on ``scale`` (a :class:`Scale`); NaN black."""
    from matplotlib import colormaps

    values = np.asarray(values, np.float64)
    span = max(scale.top - scale.bottom, 1e-12)
    scaled = np.clip((np.nan_to_num(values, nan=scale.bottom) - scale.bottom) / span, 0, 1)
    rgb = (colormaps[scale.cmap](scaled)[..., :3] * 255 + 0.5).astype(np.uint8)
    rgb[~np.isfinite(values)] = 0
    return rgb


def colour_bar(scale, height=256, width=14):
    """The colour bar of ``scale``: (height, width, 3) uint8, the top value at the top."""
    ramp = np.linspace(scale.top, scale.bottom, height)[:, None] * np.ones((1, width))
    return colour_map(ramp, scale)


def status_rgb(codes, colours):
    """Integer status codes (H, W) -> uint8 RGB through ``colours`` (256, 3), the normals
    stage's table (:data:`pipeline.photometric.stage.STATUS_COLOURS`)."""
    return np.asarray(colours, np.uint8)[np.clip(np.asarray(codes).astype(np.int64), 0, 255)]


def status_legend(codes, names, colours):
    """Rows of a status legend: (code, name, (r, g, b), pixels, share of the object's pixels).

    Every code present but background (0) is listed, known or not (an unknown one is named
    'code N'); shares are of the non-background pixels, as the normals stage counts them.
    """
    codes = np.asarray(codes).astype(np.int64)
    inside = codes != 0
    total = max(int(inside.sum()), 1)
    rows = []
    for code in np.unique(codes[inside]) if inside.any() else []:
        pixels = int(np.sum(codes[inside] == code))
        rows.append((int(code), names.get(int(code), f"code {int(code)}"),
                     tuple(int(v) for v in colours[int(code)]), pixels, pixels / total))
    return rows
