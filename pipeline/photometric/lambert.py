"""Weighted Lambertian photometric stereo, batched over pixels with matrix products."""

import numpy as np

__all__ = ["lambert_weighted", "outer_table", "solve3"]


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
    return solve3(normal, rhs)


def solve3(a, rhs):
    """Solve a batch of 3 x 3 systems a (N, 3, 3) x = rhs (N, 3) by cofactors (Cramer's rule).

    About twice as fast as :func:`numpy.linalg.solve` for such small matrices, and as accurate
    for the regularised normal matrices solved here. Singular rows give non-finite values.
    """
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = (a[:, i, j] for i in range(3) for j in range(3))
    cof = np.stack([a11 * a22 - a12 * a21, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11,
                    a12 * a20 - a10 * a22, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12,
                    a10 * a21 - a11 * a20, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10], axis=-1)
    det = a00 * cof[:, 0] + a01 * cof[:, 3] + a02 * cof[:, 6]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.einsum("nij,nj->ni", cof.reshape(-1, 3, 3), rhs) / det[:, None]
