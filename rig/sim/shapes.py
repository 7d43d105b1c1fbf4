"""Geometry of the simulated scenes: height fields, spheres and cast shadows.

Units: one scene unit is one sensor pixel (orthographic camera). Camera frame: x right, y up,
z toward the camera; image row 0 is the top row, so y = (H - 1) / 2 - row.
"""

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["Geometry", "pixel_grid", "blob_object", "spheres", "cast_shadow", "cast_shadow_directional"]


@dataclass
class Geometry:
    """What the camera sees, per pixel.

    Attributes
    ----------
    normals : ndarray (H, W, 3) float64
        Unit normals, camera frame; (0, 0, 0) outside ``mask``.
    mask : ndarray (H, W) bool
        Pixels whose centre lies on a surface.
    depth : ndarray (H, W) float64
        z of the surface (scene units = pixels), NaN outside ``mask``.
    coverage : ndarray (H, W) float64
        Fraction of each pixel covered by a surface (anti-aliased silhouettes), 0..1.
    label : ndarray (H, W) int
        Which part a pixel belongs to (-1 background; sphere index for the sphere scene).
    """

    normals: np.ndarray
    mask: np.ndarray
    depth: np.ndarray
    coverage: np.ndarray
    label: np.ndarray


def pixel_grid(shape):
    """Camera-frame x, y (H, W) of pixel centres, origin at the image centre, y up."""
    h, w = shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    return x - (w - 1) / 2.0, (h - 1) / 2.0 - y


def _gauss(x, y, x0, y0, amp, sigma):
    """A Gaussian bump and its gradient (value, d/dx, d/dy), all (H, W)."""
    g = amp * np.exp(-((x - x0) ** 2 + (y - y0) ** 2) / (2 * sigma * sigma))
    return g, -g * (x - x0) / sigma ** 2, -g * (y - y0) / sigma ** 2


def _groove(x, y, angle_deg, offset, amp, sigma):
    """A straight Gaussian valley (amp < 0) across the surface, with its gradient."""
    a = np.radians(angle_deg)
    nx, ny = -np.sin(a), np.cos(a)
    d = nx * x + ny * y - offset
    g = amp * np.exp(-d * d / (2 * sigma * sigma))
    return g, -g * d / sigma ** 2 * nx, -g * d / sigma ** 2 * ny


def blob_object(shape):
    """The default object: a paraboloid dome with bumps, dents and a groove.

    The dents and the groove are concavities that cast shadows on themselves; the bumps cast
    shadows on the dome. Features scale with the image size.

    Parameters
    ----------
    shape : (H, W)

    Returns
    -------
    Geometry
    """
    x, y = pixel_grid(shape)
    s = min(shape) / 360.0
    a, b = 0.40 * shape[1], 0.43 * shape[0]
    r2 = (x / a) ** 2 + (y / b) ** 2
    top = 0.6 * min(a, b)
    z, zx, zy = top * (1 - r2), -2 * top * x / a ** 2, -2 * top * y / b ** 2
    features = [_gauss(x, y, -70 * s, 45 * s, 38 * s, 20 * s),
                _gauss(x, y, 95 * s, 55 * s, 30 * s, 16 * s),
                _gauss(x, y, 60 * s, -45 * s, -34 * s, 24 * s),
                _gauss(x, y, -95 * s, -40 * s, -26 * s, 18 * s),
                _groove(x, y, 20.0, -5 * s, -20 * s, 9 * s)]
    for g, gx, gy in features:
        z, zx, zy = z + g, zx + gx, zy + gy
    normals = np.stack([-zx, -zy, np.ones_like(z)], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    # exact silhouette distance is not needed: a linearised distance to the ellipse in pixels
    edge = (1 - np.sqrt(r2)) * min(a, b)
    coverage = np.clip(edge + 0.5, 0.0, 1.0)
    mask = r2 < 1.0
    normals[~mask] = 0.0
    depth = np.where(mask, z, np.nan)
    return Geometry(normals, mask, depth, coverage, np.where(mask, 0, -1))


def spheres(shape, circles):
    """Spheres seen by the orthographic camera.

    Parameters
    ----------
    shape : (H, W)
    circles : sequence of (cx, cy, r)
        Centre column, centre row and radius in pixels (0-based pixel centres).

    Returns
    -------
    Geometry
        ``label`` holds the index of the sphere under each pixel; depth is z relative to the
        sphere centres' plane.
    """
    h, w = shape
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    normals = np.zeros((h, w, 3))
    depth = np.full((h, w), np.nan)
    coverage = np.zeros((h, w))
    label = np.full((h, w), -1)
    for i, (cx, cy, r) in enumerate(circles):
        dx, dy = (cols - cx) / r, (cy - rows) / r
        d2 = dx * dx + dy * dy
        inside = d2 < 1.0
        nz = np.sqrt(np.clip(1.0 - d2, 0.0, None))
        normals[inside] = np.stack([dx, dy, nz], axis=-1)[inside]
        depth[inside] = (r * nz)[inside]
        coverage = np.maximum(coverage, np.clip(r - np.sqrt(d2) * r + 0.5, 0.0, 1.0))
        label[inside] = i
    return Geometry(normals, label >= 0, depth, coverage, label)


def _sample(height, rows, cols):
    """Bilinear samples of ``height`` (H, W) at fractional (rows, cols) inside the image."""
    r0 = np.floor(rows).astype(np.intp)
    c0 = np.floor(cols).astype(np.intp)
    fr, fc = rows - r0, cols - c0
    top = height[r0, c0] * (1 - fc) + height[r0, c0 + 1] * fc
    bottom = height[r0 + 1, c0] * (1 - fc) + height[r0 + 1, c0 + 1] * fc
    return top * (1 - fr) + bottom * fr


def cast_shadow(depth, mask, lights, eps=0.5):
    """Which surface pixels a light cannot see, by marching the height field toward it.

    Parameters
    ----------
    depth : ndarray (H, W)
        Surface height (pixels), NaN outside ``mask``.
    mask : ndarray (H, W) bool
    lights : ndarray (3,) or (N, 3)
        Unit direction toward the light: one for all pixels, or one per masked pixel (near
        lights), in ``mask`` order.
    eps : float
        Height tolerance (pixels) so the surface does not shadow itself through interpolation.

    Returns
    -------
    ndarray (N,) bool
        True for masked pixels (in ``mask`` order) in cast shadow.
    """
    h, w = depth.shape
    height = np.where(mask, depth, -1e9)
    rows, cols = np.nonzero(mask)
    z0 = depth[mask]
    l = np.broadcast_to(np.asarray(lights, float), (len(z0), 3))
    lxy = np.hypot(l[:, 0], l[:, 1])
    # one pixel per step in the image plane; the ray rises l_z / |l_xy| per step
    ok = lxy > 1e-6
    step_c = np.where(ok, l[:, 0] / np.maximum(lxy, 1e-12), 0.0)
    step_r = np.where(ok, -l[:, 1] / np.maximum(lxy, 1e-12), 0.0)
    rise = np.where(ok, l[:, 2] / np.maximum(lxy, 1e-12), np.inf)
    shadow = np.zeros(len(z0), bool)
    active = np.nonzero(ok)[0]
    top = np.nanmax(depth) if mask.any() else 0.0
    step = 0
    while active.size:
        step += 1
        r = rows[active] + step * step_r[active]
        c = cols[active] + step * step_c[active]
        ray = z0[active] + step * rise[active]
        alive = (r >= 0) & (r <= h - 2) & (c >= 0) & (c <= w - 2) & (ray < top)
        active, r, c, ray = active[alive], r[alive], c[alive], ray[alive]
        blocked = _sample(height, r, c) > ray + eps
        shadow[active[blocked]] = True
        active = active[~blocked]
    return shadow


def cast_shadow_directional(depth, mask, light, eps=0.5, gap=2):
    """Cast shadows of one directional light by a horizon scan (fast path of :func:`cast_shadow`).

    The height field is resampled on a grid whose rows run along the light's azimuth; along
    each such line a pixel at abscissa u is in shadow when max_{u' > u} (z(u') - u' t) exceeds
    z(u) - u t, with t = l_z / |l_xy| the ray's rise per pixel: one reverse running maximum.

    Parameters
    ----------
    depth, mask : as for :func:`cast_shadow`
    light : ndarray (3,)
        Unit direction toward the light.
    eps : float
        Height tolerance, pixels.
    gap : int
        Grid samples next to a pixel that are ignored, so interpolation does not make the
        surface shadow itself.

    Returns
    -------
    ndarray (N,) bool
        True for masked pixels (in ``mask`` order) in cast shadow.
    """
    h, w = depth.shape
    l = np.asarray(light, float)
    lxy = np.hypot(l[0], l[1])
    rows, cols = np.nonzero(mask)
    if lxy < 1e-6:
        return np.zeros(len(rows), bool)
    du = np.array([-l[1], l[0]]) / lxy            # (row, col) step toward the light
    dw = np.array([du[1], -du[0]])
    half = 0.5 * np.hypot(h, w) + 2
    centre = np.array([(h - 1) / 2.0, (w - 1) / 2.0])
    n = int(np.ceil(2 * half)) + 1
    t = np.arange(n) - half
    grid = centre[:, None, None] + du[:, None, None] * t[None, None, :] + dw[:, None, None] * t[None, :, None]
    height = np.where(mask, depth, -1e9)
    z = ndimage.map_coordinates(height, grid, order=1, cval=-1e9, prefilter=False)
    rise = l[2] / lxy
    f = z - t[None, :] * rise                    # (w index, u index)
    horizon = np.maximum.accumulate(f[:, ::-1], axis=1)[:, ::-1]
    horizon = np.concatenate([horizon[:, gap:], np.full((n, gap), -np.inf)], axis=1)
    rel = np.stack([rows - centre[0], cols - centre[1]], axis=1)
    u = rel @ du + half
    v = rel @ dw + half
    seen = ndimage.map_coordinates(horizon, np.stack([v, u]), order=1, cval=-np.inf, prefilter=False)
    own = depth[mask] - (u - half) * rise
    return seen > own + eps
