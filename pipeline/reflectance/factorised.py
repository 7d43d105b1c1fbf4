"""The factorised biquadratic model (paper Eq. 1), fitted by alternating linear least squares.

rho = (A1 x^2 + B1 x + C1) (A2 y^2 + B2 y + C2) with x = n.h, y = l.h. The fit starts from the
relaxed biquadratic (Eq. 2): its 3 x 3 coefficient matrix is factorised by its best rank-one
approximation (SVD), then each quadratic is solved linearly with the other fixed, in turn,
until the residual stops changing (the paper: "no more than 10 iterations").
"""

import numpy as np

from .base import ReflectanceModel, register_model, solve_batched
from .polynomial import Biquadratic

__all__ = ["FactorisedBiquadratic", "fit_factorised"]


def _powers(t):
    """(..., K, 3): t^2, t, 1."""
    t = np.asarray(t, float)
    return np.stack([t * t, t, np.ones_like(t)], axis=-1)


def _rank_one(relaxed):
    """Best rank-one split of relaxed params (..., 9) (row-major A..I) -> p1 (..., 3), p2 (..., 3)."""
    u, s, vt = np.linalg.svd(relaxed.reshape(relaxed.shape[:-1] + (3, 3)))
    root = np.sqrt(s[..., 0])[..., None]
    return u[..., :, 0] * root, vt[..., 0, :] * root


def fit_factorised(geometry, values, shading=None, weights=None, max_iter=10, tol=1e-6):
    """Alternating least squares for Eq. 1, started from the relaxed fit of Eq. 2.

    Parameters
    ----------
    geometry : Geometry
        Cosines (..., K).
    values, shading, weights : ndarray (..., K)
        As in :meth:`ReflectanceModel.fit`.
    max_iter : int
        Number of alternations (one alternation solves both quadratics once).
    tol : float
        Stop when every batch item's residual changes by less than ``tol`` relative.

    Returns
    -------
    params : ndarray (..., 6)
        (A1, B1, C1, A2, B2, C2).
    iterations : int
        Alternations run.
    """
    values = np.asarray(values, float)
    scale = 1.0 if shading is None else np.asarray(shading, float)
    w = np.ones_like(values) if weights is None else np.broadcast_to(weights, values.shape)
    px, py = np.broadcast_arrays(_powers(geometry.nh), _powers(geometry.lh))
    px = np.broadcast_to(px, values.shape + (3,))
    py = np.broadcast_to(py, values.shape + (3,))
    relaxed = Biquadratic().basis(geometry)
    relaxed = relaxed if shading is None else relaxed * scale[..., None]
    # A tiny ridge: the x, y powers are nearly collinear, and a biased relaxed fit would
    # leave the alternation a long way to crawl back.
    p1, p2 = _rank_one(solve_batched(relaxed, values, w, ridge=1e-14))
    previous = None
    for iteration in range(1, max_iter + 1):
        g = np.einsum("...kp,...p->...k", py, p2) * scale
        p1 = solve_batched(px * g[..., None], values, w, ridge=1e-12)
        f = np.einsum("...kp,...p->...k", px, p1) * scale
        p2 = solve_batched(py * f[..., None], values, w, ridge=1e-12)
        residual = np.sum(w * (values - f * np.einsum("...kp,...p->...k", py, p2)) ** 2, -1)
        floor = 1e-20 * np.sum(w * values * values, -1)
        settled = (residual <= floor) | ((previous is not None) & (np.abs(
            (residual if previous is None else previous) - residual)
            <= tol * np.maximum(residual, 1e-300)))
        if np.all(settled):
            break
        previous = residual
    # The split is defined up to a scale and sign: balance the norms, make rho2(1) >= 0.
    sign = np.where(np.sum(p2, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    p1, p2 = p1 * sign, p2 * sign
    n1 = np.linalg.norm(p1, axis=-1, keepdims=True)
    n2 = np.linalg.norm(p2, axis=-1, keepdims=True)
    balance = np.sqrt(np.where(n2 > 0, n2, 1.0) / np.where(n1 > 0, n1, 1.0))
    return np.concatenate([p1 * balance, p2 / balance], axis=-1), iteration


@register_model
class FactorisedBiquadratic(ReflectanceModel):
    """Eq. 1; params (..., 6) = (A1, B1, C1, A2, B2, C2)."""

    name = "biquadratic-factorised"
    n_params = 6
    description = "factorised biquadratic, paper Eq. 1, alternating LS from the relaxed fit"
    max_iter = 10

    def evaluate(self, params, geometry):
        params = np.asarray(params, float)
        rho1 = np.einsum("...kp,...p->...k", _powers(geometry.nh), params[..., :3])
        rho2 = np.einsum("...kp,...p->...k", _powers(geometry.lh), params[..., 3:])
        return rho1 * rho2

    def fit(self, geometry, values, shading=None, weights=None):
        return fit_factorised(geometry, values, shading, weights, self.max_iter)[0]
