"""Synthetic photometric-stereo data with known normals: lights, a sphere, glossy images.

Used by the tests and the benchmarks (a fixed seed gives the same data everywhere).
"""

import numpy as np

__all__ = ["hemisphere_lights", "sphere_normals", "cook_torrance_images", "angular_error_deg"]


def hemisphere_lights(count, seed=0, min_elevation_deg=20.0):
    """Unit directions (K, 3) spread over the upper hemisphere above an elevation."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(np.sin(np.radians(min_elevation_deg)), 1.0, count)
    phi = rng.uniform(0, 2 * np.pi, count)
    r = np.sqrt(1 - z**2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)

def sphere_normals(size=64):
    """Normals (H, W, 3) of a sphere filling the image, camera frame, and its mask (H, W)."""
    c = (size - 1) / 2
    yy, xx = np.mgrid[0:size, 0:size]
    x, y = (xx - c) / (size / 2), -(yy - c) / (size / 2)
    r2 = x**2 + y**2
    mask = r2 < 0.95**2
    z = np.sqrt(np.clip(1 - r2, 0, None))
    normals = np.where(mask[..., None], np.stack([x, y, z], axis=-1), 0.0)
    return normals, mask

def cook_torrance_images(normals, mask, lights, roughness=0.4, kd=0.7, ks=0.5, noise=0.0, seed=0):
    """Lambertian + Cook-Torrance (Beckmann, Schlick Fresnel, V-cavity G) images (K, H, W)."""
    n = normals[mask]
    v = np.array([0.0, 0.0, 1.0])
    h = lights + v
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    nl = np.clip(n @ lights.T, 0, None)
    nh = np.clip(n @ h.T, 1e-6, 1)
    nv = np.clip(n[:, 2:3], 1e-6, 1)
    vh = np.clip(h @ v, 1e-6, 1)[None]
    m2 = roughness**2
    d = np.exp((nh**2 - 1) / (m2 * nh**2)) / (np.pi * m2 * nh**4)
    f = 0.04 + 0.96 * (1 - vh) ** 5
    g = np.minimum(1, np.minimum(2 * nh * nv / vh, 2 * nh * nl / vh))
    spec = d * f * g / (4 * np.maximum(nl, 1e-6) * nv)
    radiance = (kd / np.pi + ks * spec) * nl
    images = np.zeros((len(lights),) + mask.shape, np.float32)
    images[:, mask] = radiance.T
    if noise:
        images += np.random.default_rng(seed).normal(0, noise, images.shape).astype(np.float32) * mask
    return images

def angular_error_deg(a, b, mask):
    """Angles (deg) between normal maps ``a`` and ``b`` (H, W, 3) over ``mask``, one per pixel."""
    cos = np.clip(np.sum(a[mask] * b[mask], axis=1), -1, 1)
    return np.degrees(np.arccos(cos))
