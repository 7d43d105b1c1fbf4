"""Relative light intensities from a matte white target (a Lambertian sphere or a plane)."""

import numpy as np

from pipeline.core.errors import InputError

from .geometry import sphere_points

__all__ = ["target_intensities", "normalise_intensities"]

MIN_SHADING = 0.2    # pixels with n.l below this are too dim / too grazing to trust


def normalise_intensities(values):
    """Scale (K, C) intensities so the mean over lights of the mean over channels is 1."""
    values = np.asarray(values, float)
    scale = np.nanmean(values) if np.isfinite(values).any() else np.nan
    if not np.isfinite(scale) or scale <= 0:
        raise InputError("target intensities: no light lit the target")
    return values / scale


def target_intensities(images, directions, *, circle=None, mask=None, plane_normal=None,
                       saturation=None, K=None, positions=None, offset=None):
    """Per-light, per-channel intensities from frames of a matte white target.

    Each light's pixels are fitted as ``pixel = I * shading + a`` by least squares over the
    well-lit, unsaturated target pixels (away from the rim), with ``shading`` = max(n.l, 0)
    times the near-light falloff; the offset ``a`` absorbs ambient light. The target's albedo
    is taken to be white and uniform, so only the ratios between lights and channels mean
    anything.

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
    K : ndarray (3, 3) or None
        Intrinsics (perspective target-sphere normals).
    positions : ndarray (K, 3) or None
        Near light positions (orthographic: pixels, origin at the image centre); per-pixel
        directions and the (|p| / |p - X|)^2 falloff then replace ``directions``, so the result
        is the irradiance at the frame origin. Sphere targets only.
    offset : (3,) or None
        What to subtract from :func:`calibration.geometry.sphere_points` points to reach the
        positions' frame (:func:`calibration.positions.frame_offset`).

    Returns
    -------
    ndarray (K, C)
        Relative intensities (mean 1); NaN for a light that lit too few target pixels.
    """
    images = np.asarray(images, np.float32)
    if images.ndim == 3:
        images = images[..., None]
    n_lights, h, w, _ = images.shape
    directions = np.asarray(directions, float)
    if directions.shape != (n_lights, 3):
        raise InputError(f"target intensities: {directions.shape} directions for {n_lights} frames")
    inside, normals, points = _target(h, w, circle, mask, plane_normal, K)
    shading = _shading(normals, points, directions, positions, offset)       # (K, N)
    pixels = images[:, inside]                                               # (K, N, C)
    usable = (shading > MIN_SHADING)[..., None] & np.isfinite(pixels)
    if saturation is not None:
        usable &= ~np.asarray(saturation, bool)[:, inside][..., None]
    return normalise_intensities(_fit_gain(shading[..., None], pixels, usable))


def _target(h, w, circle, mask, plane_normal, K):
    """Target pixels (H, W) bool, their normals (N, 3) and points (N, 3) or None."""
    if circle is not None:
        rows, cols = np.mgrid[0:h, 0:w]
        # the rim is partly background and its normals are the least certain
        inside = np.hypot(cols - circle[0], rows - circle[1]) < 0.92 * circle[2]
        if mask is not None:
            inside &= np.asarray(mask, bool)
        normals, _, points = sphere_points(cols[inside], rows[inside], circle, K)
    elif mask is not None:
        inside = np.asarray(mask, bool)
        n = np.asarray(plane_normal if plane_normal is not None else (0.0, 0.0, 1.0), float)
        normals, points = np.broadcast_to(n / np.linalg.norm(n), (int(inside.sum()), 3)), None
    else:
        raise InputError("target intensities: give the target's circle or its mask")
    if not inside.any():
        raise InputError("target intensities: the target region is empty")
    return inside, normals, points


def _shading(normals, points, directions, positions, offset):
    """max(n.l, 0) times the near-light falloff, (K, N)."""
    if positions is None:
        return np.clip(directions @ normals.T, 0, None)
    if points is None:
        raise InputError("target intensities: near lights need a sphere target (its surface points)")
    pts = points - (0 if offset is None else np.asarray(offset, float))
    to_light = np.asarray(positions, float)[:, None, :] - pts[None]           # (K, N, 3)
    dist2 = (to_light ** 2).sum(-1)
    cos = (to_light * normals[None]).sum(-1) / np.sqrt(dist2)
    falloff = (np.asarray(positions, float) ** 2).sum(-1)[:, None] / dist2
    return np.clip(cos, 0, None) * falloff


def _fit_gain(shading, pixels, usable):
    """Slope I of pixel = I * shading + a per (light, channel) by weighted least squares.

    shading (K, N, 1), pixels (K, N, C), usable (K, N, C) -> (K, C); NaN with < 20 pixels.
    """
    u = usable.astype(np.float64)
    count = u.sum(1)
    s = np.where(usable, shading, 0.0)
    p = np.where(usable, pixels, 0.0).astype(np.float64)
    ms, mp = s.sum(1) / np.maximum(count, 1), p.sum(1) / np.maximum(count, 1)
    cov = (u * (s - ms[:, None]) * (p - mp[:, None])).sum(1)
    var = (u * (s - ms[:, None]) ** 2).sum(1)
    gain = cov / np.where(var > 0, var, np.nan)
    return np.where(count >= 20, gain, np.nan)
