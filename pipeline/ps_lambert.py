"""Weighted Lambertian photometric stereo, batched over pixels with matrix products."""

import numpy as np

__all__ = ["lambert_weighted", "outer_table"]


def outer_table(vectors):
    """(K, 3) vectors -> (K, 9) table of their outer products, row-major."""
    return (vectors[:, :, None] * vectors[:, None, :]).reshape(len(vectors), 9)


def lambert_weighted(obs, lights, weights=None, factor=None):
    """Least-squares b = albedo * n per pixel from obs ~ factor * (b . l).

    Parameters
    ----------
    obs : ndarray (N, K)
    lights : ndarray (K, 3) or (N, K, 3)
        Unit light directions, shared or per pixel (near lights).
    weights : ndarray (N, K), optional
    factor : ndarray (N, K), optional
        A per-observation multiplier of the shading (a fixed BRDF value).

    Returns
    -------
    ndarray (N, 3)
        b; its norm is the albedo and its direction the normal.
    """
    w = np.ones_like(obs) if weights is None else weights
    if factor is not None:
        w_design = w * factor * factor
        w_rhs = w * factor
    else:
        w_design, w_rhs = w, w
    if lights.ndim == 2:
        normal = (w_design @ outer_table(lights)).reshape(-1, 3, 3)
        rhs = (w_rhs * obs) @ lights
    else:
        normal = np.einsum("nk,nki,nkj->nij", w_design, lights, lights)
        rhs = np.einsum("nk,nki->ni", w_rhs * obs, lights)
    normal += (1e-12 + 1e-9 * np.trace(normal, axis1=1, axis2=2))[:, None, None] * np.eye(3)
    return np.linalg.solve(normal, rhs[..., None])[..., 0]
