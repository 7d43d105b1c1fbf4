"""Test fixture: a small vectorised render of a chrome sphere under directional lights."""

import numpy as np

__all__ = ["render_chrome"]


def render_chrome(directions, shape=(200, 240), circle=(118.3, 97.6, 70.2), sigma_deg=1.5,
                  gain=3.0, sub=3):
    """Frames (K, H, W) of a mirror sphere: Gaussian lobe around each light, dim diffuse,
    clipped at 1.0, anti-aliased by ``sub`` x ``sub`` supersampling."""
    h, w = shape
    cx, cy, r = circle
    off = (np.arange(sub) + 0.5) / sub - 0.5
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    xs = xs[..., None, None] + off[None, None, None, :]
    ys = ys[..., None, None] + off[None, None, :, None]
    xs, ys = np.broadcast_arrays(xs, ys)
    nx, ny = (xs - cx) / r, -(ys - cy) / r
    inside = nx ** 2 + ny ** 2 < 1
    nz = np.sqrt(np.clip(1 - nx ** 2 - ny ** 2, 0, None))
    n = np.stack([nx, ny, nz], -1)
    refl = 2 * nz[..., None] * n - np.array([0, 0, 1.0])
    frames = []
    for d in np.asarray(directions, float):
        ang = np.arccos(np.clip(refl @ d, -1, 1))
        val = gain * np.exp(-ang ** 2 / (2 * np.radians(sigma_deg) ** 2)) + 0.03 * np.clip(n @ d, 0, None) + 0.02
        frames.append(np.where(inside, val, 0.1).mean(axis=(-1, -2)))
    return np.clip(np.stack(frames), 0, 1).astype(np.float32)
