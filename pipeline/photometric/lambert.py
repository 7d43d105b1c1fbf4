"""Weighted Lambertian photometric stereo, batched over pixels with matrix products."""

import numpy as np

__all__ = ["lambert_weighted", "outer_table", "solve3", "inverse3", "ill_conditioned", "facing_away",
           "normal_leverage", "ILL_CONDITIONED"]

#: the weakest direction of a pixel's selected lights, relative to the strongest (eigenvalues of
#: sum_k w l l^T), below which its normal is not determined (:func:`ill_conditioned`)
ILL_CONDITIONED = 1e-3


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
    adjugate, det = _adjugate(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.einsum("nij,nj->ni", adjugate, rhs) / det[:, None]


def inverse3(a):
    """Inverses (N, 3, 3) of a batch of 3 x 3 matrices a (N, 3, 3) by cofactors, as :func:`solve3`
    (the batched LAPACK call costs more than the arithmetic at this size). Singular rows give
    non-finite values."""
    adjugate, det = _adjugate(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        return adjugate / det[:, None, None]


def _adjugate(a):
    """The adjugates (N, 3, 3) of 3 x 3 matrices a (N, 3, 3) and their determinants (N,)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = (a[:, i, j] for i in range(3) for j in range(3))
    cof = np.stack([a11 * a22 - a12 * a21, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11,
                    a12 * a20 - a10 * a22, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12,
                    a10 * a21 - a11 * a20, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10], axis=-1)
    return cof.reshape(-1, 3, 3), a00 * cof[:, 0] + a01 * cof[:, 3] + a02 * cof[:, 6]


def ill_conditioned(weights, lights, ratio=ILL_CONDITIONED):
    """Pixels (N,) bool whose weighted lights span three dimensions too weakly: the smallest
    eigenvalue of sum_k w l l^T under ``ratio`` x the largest (noise amplified over 30x)."""
    if lights.ndim == 2:
        t = weights @ outer_table(lights)
    else:
        t = np.einsum("nk,nki,nkj->nij", weights, lights, lights).reshape(-1, 9)
    trace = t[:, 0] + t[:, 4] + t[:, 8]
    det = _adjugate(t.reshape(-1, 3, 3))[1]
    # det <= smallest x trace^2 and largest <= trace, so det >= ratio trace^3 proves a pixel
    # well conditioned; only the others need their eigenvalues (on DiLiGenT: none)
    doubtful = ~((trace > 0) & (det >= ratio * trace ** 3))
    out = np.zeros(len(t), bool)
    if doubtful.any():
        eig = np.linalg.eigvalsh(t[doubtful].reshape(-1, 3, 3))
        out[doubtful] = eig[:, 0] < ratio * np.maximum(eig[:, 2], 1e-300)
    return out


def facing_away(b):
    """Pixels (N,) bool whose b (N, 3) does not face the camera (n_z <= 0, or not finite): an
    orthographic camera cannot see such a surface, so no observation supports it."""
    return ~(np.isfinite(b).all(axis=1) & (b[:, 2] > 0))


#: the entries (xx, yy, zz, xy, xz, yz) of a symmetric 3 x 3 matrix
_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def normal_leverage(b, weights, lights):
    """How much noise in the observations turns each pixel's normal: the linearised angular
    standard deviation of a Lambertian fit on the pixel's used observations, per unit of noise
    relative to the albedo.

    For b = rho n fitted by least squares on the lights l_k (rows of M = sum_k l_k l_k^T), the
    covariance of b is sigma^2 M^-1; its part across the normal, over rho^2, is the normal's
    angular variance. So the angle's standard deviation in radians is the residual relative to
    the albedo times ``sqrt(trace(M^-1) - n^T M^-1 n)``. It grows as the used lights close in
    on a plane and as they get fewer.

    Parameters
    ----------
    b : ndarray (N, 3)
        Each pixel's fitted albedo-scaled normal (NaN or zero where there is none).
    weights : ndarray (N, K) or None
        The observations each pixel used (> 0); None: every one.
    lights : ndarray (K, 3) or (N, K, 3)
        Unit light directions.

    Returns
    -------
    ndarray (N,) float32
        Radians per unit relative noise; NaN where there is no normal or the used lights
        determine none.
    """
    n_px = len(b)
    used = np.ones((n_px, lights.shape[-2])) if weights is None else (np.asarray(weights) > 0).astype(np.float64)
    if lights.ndim == 2:
        # the six distinct entries of each pixel's M in one product: (N, K) @ (K, 6)
        pairs = np.stack([lights[:, i] * lights[:, j] for i, j in _PAIRS], axis=1)
        m = used @ pairs
    else:
        m = np.stack([np.einsum("nk,nk->n", used, lights[:, :, i] * lights[:, :, j]) for i, j in _PAIRS], axis=1)
    xx, yy, zz, xy, xz, yz = m.T
    # the adjugate of the symmetric 3 x 3 M, entry by entry (numpy's batched inverse costs
    # microseconds per pixel, as much as the fit)
    a_xx, a_yy, a_zz = yy * zz - yz * yz, xx * zz - xz * xz, xx * yy - xy * xy
    a_xy, a_xz, a_yz = xz * yz - xy * zz, xy * yz - xz * yy, xy * xz - xx * yz
    det = xx * a_xx + xy * a_xy + xz * a_xz
    trace = xx + yy + zz
    good = det > 1e-12 * np.maximum(trace, 1e-12) ** 3
    norm = np.linalg.norm(np.nan_to_num(b), axis=1)
    good &= norm > 0
    n = np.nan_to_num(b) / np.where(good, norm, 1.0)[:, None]
    nx, ny, nz = n.T
    quad = (a_xx * nx * nx + a_yy * ny * ny + a_zz * nz * nz
            + 2.0 * (a_xy * nx * ny + a_xz * nx * nz + a_yz * ny * nz))
    across = (a_xx + a_yy + a_zz - quad) / np.where(good, det, 1.0)
    return np.where(good, np.sqrt(np.maximum(across, 0.0)), np.nan).astype(np.float32)
