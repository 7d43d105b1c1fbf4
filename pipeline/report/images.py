"""Pictures for the HTML report: tone mapping, thumbnails and colour-mapped maps (8-bit RGB).

All functions take float arrays in the pipeline's conventions and return (h, w, 3) uint8 arrays
ready for :func:`pipeline.imageio.write_image` with ``bits=8``.
"""

import numpy as np

__all__ = ["shrink", "srgb8", "tone_map", "normals_rgb", "colour_map", "status_rgb", "robust_max"]


def shrink(image, max_side):
    """Block-average an (H, W, C) image so that its longer side is at most ``max_side``."""
    image = np.asarray(image, np.float32)
    step = max(1, int(np.ceil(max(image.shape[:2]) / max_side)))
    if step == 1:
        return image
    h, w = (image.shape[0] // step) * step, (image.shape[1] // step) * step
    blocks = image[:h, :w].reshape(h // step, step, w // step, step, image.shape[2])
    # nanmean: depth and masked maps carry NaN outside the object
    with np.errstate(invalid="ignore"):
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
    x = np.clip(np.nan_to_num(np.asarray(linear, np.float64)), 0.0, 1.0)
    encoded = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (encoded * 255 + 0.5).astype(np.uint8)


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


def colour_map(values, top=None, cmap="magma"):
    """Scalar map (H, W) -> uint8 RGB with a matplotlib colormap over 0..``top``; NaN black."""
    from matplotlib import colormaps

    values = np.asarray(values, np.float64)
    top = robust_max(values, 99) if top is None else top
    scaled = np.clip(np.nan_to_num(values) / max(top, 1e-12), 0, 1)
    rgb = (colormaps[cmap](scaled)[..., :3] * 255 + 0.5).astype(np.uint8)
    rgb[~np.isfinite(values)] = 0
    return rgb


def status_rgb(codes):
    """Integer status codes (H, W) -> uint8 RGB (tab10 colours) and {code: (r, g, b)}."""
    from matplotlib import colormaps

    codes = np.asarray(codes).astype(np.int64)
    palette = (np.asarray(colormaps["tab10"].colors) * 255 + 0.5).astype(np.uint8)
    rgb = palette[codes % len(palette)]
    legend = {int(c): tuple(int(v) for v in rgb[codes == c][0]) for c in np.unique(codes)}
    return rgb, legend
