"""Ashikhmin's general diffuse term (paper Eq. 6), linear in its one parameter R."""

import numpy as np

from .base import LinearModel, register_model

__all__ = ["Ashikhmin"]


@register_model
class Ashikhmin(LinearModel):
    """Params (..., 1) = (R,); rho = R (1 - (1 - n.l/2)^5) (1 - (1 - n.v/2)^5)."""

    name = "ashikhmin"
    n_params = 1
    description = "Ashikhmin general diffuse term, paper Eq. 6 (R)"

    def basis(self, geometry):
        nl = np.clip(np.asarray(geometry.nl, float), 0.0, 1.0)
        nv = np.clip(np.asarray(geometry.nv, float), 0.0, 1.0)
        term = (1.0 - (1.0 - nl / 2.0) ** 5) * (1.0 - (1.0 - nv / 2.0) ** 5)
        return term[..., None]
