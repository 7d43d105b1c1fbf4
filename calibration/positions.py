"""Near point lights: positions triangulated from several spheres, per-pixel directions.

Positions are in the frame of :func:`calibration.geometry.sphere_points`: orthographic, pixel
units with x = column, y = -row, z toward the camera (0 at the sphere centres' plane);
perspective, camera frame in sphere radii.
"""

import numpy as np

from pipeline.core.errors import InputError

__all__ = ["triangulate", "light_directions_at", "frame_offset", "near_decision"]


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


def frame_offset(shape):
    """Offset (3,) from :func:`calibration.geometry.sphere_points`' orthographic frame (x =
    column, y = -row) to the session frame with the origin at the image centre: subtract it.

    shape : (H, W) of the frames.
    """
    h, w = shape
    return np.array([(w - 1) / 2.0, -(h - 1) / 2.0, 0.0])


def near_decision(positions, starts, rays, parallax_deg, uncertainty_deg, baseline, *,
                  max_baselines=50.0, min_parallax_deg=0.5):
    """Decide whether the lights are near point lights or directional.

    A light's triangulation is well conditioned when its rays from the spheres converge ahead
    of every sphere, with a parallax (angle between the spheres' rays) well above the
    direction noise (``max(min_parallax_deg, 4 * uncertainty)``) and a distance under
    ``max_baselines`` times the sphere baseline. The lights are near when most calibrated
    lights are well conditioned.

    Parameters
    ----------
    positions : ndarray (K, 3)
    starts, rays : ndarray (S, K, 3)
        Highlight points and unit reflected rays per sphere.
    parallax_deg, uncertainty_deg : ndarray (K,)
    baseline : float
        Largest distance between sphere centres, same unit as the positions.

    Returns
    -------
    near : bool
    conditioned : ndarray (K,) bool
    reason : str
    """
    positions = np.asarray(positions, float)
    ahead = ((positions[None] - starts) * rays).sum(-1) > 0
    dist = np.linalg.norm(positions - starts.mean(0), axis=-1)
    with np.errstate(invalid="ignore"):
        conditioned = (np.isfinite(positions).all(-1) & ahead.all(0)
                       & (parallax_deg > np.maximum(min_parallax_deg, 4 * np.nan_to_num(uncertainty_deg)))
                       & (dist < max_baselines * baseline))
    usable = np.isfinite(parallax_deg)
    share = conditioned[usable].mean() if usable.any() else 0.0
    near = bool(share > 0.5)
    median = float(np.nanmedian(np.where(conditioned, dist, np.nan))) if conditioned.any() else float("nan")
    reason = (f"{int(conditioned.sum())} of {int(usable.sum())} lights triangulate well "
              f"(parallax > max({min_parallax_deg}, 4 sigma) deg, ahead of both spheres, distance < "
              f"{max_baselines:g} baselines of {baseline:.1f}); median distance {median:.1f}")
    return near, conditioned, reason
