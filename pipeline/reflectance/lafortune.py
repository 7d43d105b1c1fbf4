"""Lafortune's general diffuse term (paper Eq. 5): rho = C_d (n.l)^k (n.v)^k.

Fitted as the paper does: logarithms of both sides make it linear in (log C_d, k), solved by
weighted linear least squares, batched over all leading dimensions.
"""

import numpy as np

from .base import ReflectanceModel, register_model, solve_batched

__all__ = ["Lafortune"]

#: Cosines are clipped here so that log() and the power stay finite at grazing angles.
_COS_MIN = 1e-4
#: Exponent range kept by the fit; beyond it the term is numerically a spike or a constant.
_K_RANGE = (-2.0, 20.0)


@register_model
class Lafortune(ReflectanceModel):
    """Params (..., 2) = (C_d, k); rho = C_d ((n.l)(n.v))^k."""

    name = "lafortune"
    n_params = 2
    description = "Lafortune general diffuse term, paper Eq. 5 (C_d, k)"

    @staticmethod
    def _log_cosines(geometry):
        nl = np.clip(np.asarray(geometry.nl, float), _COS_MIN, 1.0)
        nv = np.clip(np.asarray(geometry.nv, float), _COS_MIN, 1.0)
        return np.log(nl) + np.log(nv)

    def evaluate(self, params, geometry):
        params = np.asarray(params, float)
        return params[..., :1] * np.exp(params[..., 1:2] * self._log_cosines(geometry))

    def fit(self, geometry, values, shading=None, weights=None):
        """Log-linear least squares; observations <= 0 (no logarithm) get weight 0."""
        values = np.asarray(values, float)
        rho = values if shading is None else values / np.where(np.abs(shading) > 1e-12, shading, np.inf)
        usable = rho > 0
        w = usable.astype(float) if weights is None else np.asarray(weights, float) * usable
        log_rho = np.log(np.where(usable, rho, 1.0))
        t = np.broadcast_to(self._log_cosines(geometry), log_rho.shape)
        design = np.stack([np.ones_like(t), t], axis=-1)
        log_c, k = np.moveaxis(solve_batched(design, log_rho, w, ridge=1e-9), -1, 0)
        k = np.clip(k, *_K_RANGE)
        return np.stack([np.exp(np.clip(log_c, -50.0, 50.0)), k], axis=-1)
