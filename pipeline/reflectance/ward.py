"""Isotropic Ward model with a Lambertian term (paper Eq. 7)."""

import numpy as np

from .base import register_model
from .cook_torrance import LambertSpecular

__all__ = ["Ward"]

_COS_MIN = 1e-3


@register_model
class Ward(LambertSpecular):
    """Ward: S = exp(-tan^2(theta_h) / m^2) / (4 pi m^2 sqrt((n.l)(n.v))); params (k_d, k_s, m)."""

    name = "ward"
    description = "Lambertian + isotropic Ward specular, paper Eq. 7 (k_d, k_s, m)"

    def parts(self, geometry):
        nh2 = np.clip(np.asarray(geometry.nh, float), _COS_MIN, 1.0) ** 2
        nl = np.clip(np.asarray(geometry.nl, float), _COS_MIN, 1.0)
        nv = np.clip(np.asarray(geometry.nv, float), _COS_MIN, 1.0)
        return 1.0 / (4.0 * np.pi * np.sqrt(nl * nv)), (1.0 - nh2) / nh2
