"""Relative light intensities from a matte white target (a Lambertian sphere or a plane)."""

import numpy as np

from pipeline.errors import InputError

from .geometry import sphere_points

__all__ = ["target_intensities", "normalise_intensities"]

MIN_SHADING = 0.25   # pixels with n.l below this are too dim / too grazing to trust


def normalise_intensities(values):
    """Scale (K, C) intensities so the mean over lights of the mean over channels is 1."""
    values = np.asarray(values, float)
    scale = np.nanmean(values)
    if not np.isfinite(scale) or scale <= 0:
        raise InputError("target intensities: no light lit the target")
    return values / scale


def target_intensities(images, directions, *, circle=None, mask=None, plane_normal=None,
                       saturation=None, K=None):
    """Per-light, per-channel intensities from frames of a matte white target.

    Parameters
    ----------
    images : ndarray (K, H, W) or (K, H, W, C)
        Linear frames of the target, one per light.
    directions : ndarray (K, 3)
        Unit light directions, camera frame.
    circle : (cx, cy, r) or None
        Outline of a Lambertian target sphere, pixels.
    mask : ndarray (H, W) bool or None
        Target pixels (a plane target, or to limit the sphere).
    plane_normal : (3,) or None
        Normal of a plane target (default (0, 0, 1), facing the camera).
    saturation : ndarray (K, H, W) bool or None
        Saturated pixels, never used.

    Returns
    -------
    ndarray (K, C)
        Relative intensities (mean 1), the median over well-lit target pixels of I / (n.l).
    """
    images = np.asarray(images, np.float32)
    if images.ndim == 3:
        images = images[..., None]
    n_lights, h, w, _ = images.shape
    directions = np.asarray(directions, float)
    if directions.shape != (n_lights, 3):
        raise InputError(f"target intensities: {directions.shape} directions for {n_lights} frames")
    if circle is not None:
        rows, cols = np.mgrid[0:h, 0:w]
        inside = np.hypot(cols - circle[0], rows - circle[1]) < 0.95 * circle[2]
        if mask is not None:
            inside &= np.asarray(mask, bool)
        normals = sphere_points(cols[inside], rows[inside], circle, K)[0]
    elif mask is not None:
        inside = np.asarray(mask, bool)
        n = np.asarray(plane_normal if plane_normal is not None else (0.0, 0.0, 1.0), float)
        normals = np.broadcast_to(n / np.linalg.norm(n), (int(inside.sum()), 3))
    else:
        raise InputError("target intensities: give the target's circle or its mask")
    if not inside.any():
        raise InputError("target intensities: the target region is empty")
    shading = normals @ directions.T                       # (N, K)
    pixels = images[:, inside]                             # (K, N, C)
    usable = (shading.T > MIN_SHADING)[..., None] & np.isfinite(pixels)
    if saturation is not None:
        usable &= ~np.asarray(saturation, bool)[:, inside][..., None]
    ratio = np.where(usable, pixels / np.maximum(shading.T, MIN_SHADING)[..., None], np.nan)
    return normalise_intensities(np.nanmedian(ratio, axis=1))
