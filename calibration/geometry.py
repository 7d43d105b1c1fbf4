"""Sphere geometry: normals, view directions and mirror directions at image pixels.

Camera frame: x right, y up, z toward the camera. Orthographic (v = (0, 0, 1)) unless an
intrinsics matrix K (3, 3, OpenCV convention: pixel rows downward, optical axis forward) is
given; then each pixel has its own view ray and the sphere has unit radius.
"""

import numpy as np

from pipeline.core.errors import InputError

__all__ = ["sphere_points", "mirror", "pixel_rays", "check_K", "sphere_centre"]


def check_K(K):
    """Validate intrinsics (3, 3); returns float ndarray or None."""
    if K is None:
        return None
    K = np.asarray(K, float)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"K: expected a 3x3 intrinsics matrix with positive focal lengths, got {K.tolist()}")
    return K


def pixel_rays(K, x, y):
    """Unit rays from the camera into the scene through pixels (x, y), camera frame (N, 3)."""
    pix = np.stack([np.asarray(x, float), np.asarray(y, float), np.ones(np.shape(x))], -1)
    cv = pix @ np.linalg.inv(K).T
    ray = cv * np.array([1.0, -1.0, -1.0])  # OpenCV (y down, z forward) -> x right, y up, z back
    return ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def sphere_centre(circle, K):
    """Centre (3,) of a unit sphere whose image outline is ``circle`` (cx, cy, r) under K (3, 3),
    camera frame."""
    cx, cy, r = circle
    axis = pixel_rays(K, cx, cy)
    edge = pixel_rays(K, cx + r, cy)
    half_angle = np.arccos(np.clip(axis @ edge, -1, 1))
    return axis / np.sin(half_angle)


def sphere_points(x, y, circle, K=None):
    """Normals, view directions and surface points of the sphere at pixels (x, y).

    Parameters
    ----------
    x, y : ndarray (N,)
        Pixel coordinates (x = column, y = row), 0-based.
    circle : (3,)
        (cx, cy, r) pixels.
    K : (3, 3) or None

    Returns
    -------
    normals, views, points : ndarray (N, 3)
        Unit normals, unit vectors toward the camera, and surface points (orthographic: pixel
        units, x = column, y = -row, z = 0 at the sphere centre; perspective: camera frame,
        sphere radius 1). Pixels off the sphere get NaN.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    cx, cy, r = map(float, circle)
    if K is None:
        nx, ny = (x - cx) / r, -(y - cy) / r
        nz = np.sqrt(np.where(nx ** 2 + ny ** 2 <= 1, 1 - nx ** 2 - ny ** 2, np.nan))
        normals = np.stack([nx, ny, nz], -1)
        views = np.broadcast_to([0.0, 0.0, 1.0], normals.shape).copy()
        points = np.array([cx, -cy, 0.0]) + r * normals
        return normals, views, points
    centre = sphere_centre((cx, cy, r), K)
    ray = pixel_rays(K, x, y)
    b = ray @ centre
    disc = b ** 2 - (centre @ centre - 1.0)
    t = b - np.sqrt(np.where(disc >= 0, disc, np.nan))
    points = t[..., None] * ray
    return points - centre, -ray, points


def mirror(normals, views):
    """Mirror directions l = 2 (n.v) n - v, (N, 3) unit vectors."""
    ndv = (normals * views).sum(-1, keepdims=True)
    out = 2 * ndv * normals - views
    return out / np.linalg.norm(out, axis=-1, keepdims=True)
