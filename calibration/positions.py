"""Near point lights: positions triangulated from several spheres, per-pixel directions.

Positions are in the frame of :func:`calibration.geometry.sphere_points`: orthographic, pixel
units with x = column, y = -row, z toward the camera (0 at the sphere centres' plane);
perspective, camera frame in sphere radii.
"""

import numpy as np

from pipeline.errors import InputError

__all__ = ["triangulate", "light_directions_at"]


def triangulate(starts, rays):
    """Least-squares meeting point of the reflected rays of each light.

    Parameters
    ----------
    starts : ndarray (S, K, 3)
        Highlight points on each of S spheres for K lights.
    rays : ndarray (S, K, 3)
        Unit reflected directions (toward the light) from those points.

    Returns
    -------
    positions : ndarray (K, 3)
        The point nearest all rays of each light (NaN when fewer than two finite rays or the
        rays are parallel).
    miss : ndarray (K,)
        RMS distance from the position to the rays, same unit.
    """
    starts, rays = np.asarray(starts, float), np.asarray(rays, float)
    if starts.shape != rays.shape or starts.ndim != 3 or starts.shape[-1] != 3:
        raise InputError(f"triangulate: starts {starts.shape} and rays {rays.shape} must both be (S, K, 3)")
    good = np.isfinite(starts).all(-1) & np.isfinite(rays).all(-1)
    s = np.where(good[..., None], starts, 0.0)
    d = np.where(good[..., None], rays, 0.0)
    proj = np.eye(3) - d[..., :, None] * d[..., None, :]        # (S, K, 3, 3), 0 for bad rays
    proj = proj * good[..., None, None]
    a = proj.sum(0)
    b = (proj @ s[..., None]).sum(0)[..., 0]
    positions = np.full((starts.shape[1], 3), np.nan)
    ok = (good.sum(0) >= 2) & (np.linalg.cond(a) < 1e8)
    positions[ok] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0]
    off = positions[None] - s
    perp = off - (off * d).sum(-1, keepdims=True) * d
    miss = np.sqrt(np.where(good, (perp ** 2).sum(-1), 0).sum(0) / np.maximum(good.sum(0), 1))
    return positions, np.where(ok, miss, np.nan)


def light_directions_at(positions, points):
    """Per-point unit directions toward near lights and their 1/d^2 falloff.

    Parameters
    ----------
    positions : ndarray (K, 3)
        Light positions.
    points : ndarray (H, W, 3) or (N, 3)
        Surface points, same frame and unit.

    Returns
    -------
    directions : ndarray (K, H, W, 3) or (K, N, 3)
        Unit vectors from each point toward each light.
    falloff : ndarray (K, H, W) or (K, N)
        1 / d^2, normalised so that its mean over finite entries of each light is 1.
    """
    positions = np.asarray(positions, float)
    points = np.asarray(points, float)
    if positions.ndim != 2 or positions.shape[1] != 3 or points.shape[-1] != 3:
        raise InputError(f"light_directions_at: positions {positions.shape} must be (K, 3) and points "
                         f"{points.shape} (..., 3)")
    shape = (len(positions),) + (1,) * (points.ndim - 1) + (3,)
    delta = positions.reshape(shape) - points[None]
    dist2 = (delta ** 2).sum(-1)
    if (dist2 <= 0).any():
        raise InputError("light_directions_at: a light position coincides with a surface point")
    directions = delta / np.sqrt(dist2)[..., None]
    inv = 1.0 / dist2
    axes = tuple(range(1, inv.ndim))
    falloff = inv / np.nanmean(inv, axis=axes, keepdims=True)
    return directions, falloff
