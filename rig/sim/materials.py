"""Reflectance lobes of the simulated scene, vectorised over pixels.

Every function takes per-pixel unit vectors ``n``, ``l`` (N, 3) and the view direction
``v = (0, 0, 1)`` (orthographic camera) and returns the lobe's value (N,) *times pi*, so that a
lobe of weight ``ks`` adds ``ks * lobe * (n.l)`` to a Lambertian term ``albedo * (n.l)`` in the
same radiance units (the scene drops the common 1/pi of the Lambertian BRDF).
"""

import numpy as np

__all__ = ["cook_torrance", "ward", "mirror", "half_vector", "VIEW"]

#: View direction of the orthographic camera, camera frame.
VIEW = np.array([0.0, 0.0, 1.0])
_EPS = 1e-6


def half_vector(l):
    """Unit half vectors h = (l + v) / |l + v| for lights ``l`` (N, 3) and v = (0, 0, 1)."""
    h = l + VIEW
    return h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), _EPS)


def _tan2_half(nh):
    """tan^2 of the half-angle, from cos (N,), clipped away from 0."""
    c2 = np.maximum(nh * nh, _EPS)
    return (1.0 - c2) / c2


def cook_torrance(n, l, roughness=0.35, f0=0.04):
    """Cook-Torrance specular lobe (Beckmann D, V-cavity G, Schlick F normalised to F(0) = 1).

    Parameters
    ----------
    n, l : ndarray (N, 3)
        Unit normals and unit light directions, camera frame.
    roughness : float
        Beckmann slope RMS m.
    f0 : float
        Reflectance at normal incidence; only the Fresnel *shape* is kept (F / f0), so the
        lobe's strength is set by its weight alone.

    Returns
    -------
    ndarray (N,)
        pi * D G F / (4 (n.l)(n.v)), 0 where n.l or n.v <= 0.
    """
    h = half_vector(l)
    nh = np.clip(np.einsum("ij,ij->i", n, h), 0.0, 1.0)
    nl = np.einsum("ij,ij->i", n, l)
    nv = n[:, 2]
    vh = np.clip(h[:, 2], _EPS, 1.0)
    m2 = roughness * roughness
    d = np.exp(-_tan2_half(nh) / m2) / (np.pi * m2 * np.maximum(nh, _EPS) ** 4)
    g = np.minimum(1.0, np.minimum(2 * nh * nv / vh, 2 * nh * nl / vh))
    f = (f0 + (1.0 - f0) * (1.0 - vh) ** 5) / f0
    valid = (nl > 0) & (nv > 0)
    out = np.pi * d * np.maximum(g, 0) * f / (4 * np.maximum(nl, _EPS) * np.maximum(nv, _EPS))
    return np.where(valid, out, 0.0)


def ward(n, l, alpha=0.25):
    """Isotropic Ward lobe.

    Parameters
    ----------
    n, l : ndarray (N, 3)
        Unit normals and light directions.
    alpha : float
        Slope spread (radians-like roughness).

    Returns
    -------
    ndarray (N,)
        pi * exp(-tan^2(theta_h) / alpha^2) / (4 pi alpha^2 sqrt((n.l)(n.v))).
    """
    h = half_vector(l)
    nh = np.clip(np.einsum("ij,ij->i", n, h), 0.0, 1.0)
    nl = np.einsum("ij,ij->i", n, l)
    nv = n[:, 2]
    valid = (nl > 0) & (nv > 0) & (nh > 0)
    root = np.sqrt(np.maximum(nl * nv, _EPS))
    out = np.exp(-_tan2_half(nh) / (alpha * alpha)) / (4 * alpha * alpha * root)
    return np.where(valid, out, 0.0)


def mirror(n, l, spread_deg=2.5):
    """A chrome surface seeing a small round light: a Gaussian in the angle between the mirror
    direction r = 2 (n.v) n - v and the light.

    Parameters
    ----------
    n, l : ndarray (N, 3)
    spread_deg : float
        Angular standard deviation of the light source's image, degrees (a finite source, so the
        highlight covers a few pixels and calibration can find its centre to sub-pixel).

    Returns
    -------
    ndarray (N,)
        Peak 1 where r == l (not multiplied by n.l: a mirror has no cosine falloff).
    """
    r = 2 * n[:, 2:3] * n - VIEW
    cos = np.clip(np.einsum("ij,ij->i", r, l), -1.0, 1.0)
    sigma = np.radians(spread_deg)
    # 1 - cos(t) ~ t^2 / 2 keeps this cheap and exact enough near the peak
    return np.exp(-(1.0 - cos) / (sigma * sigma))
