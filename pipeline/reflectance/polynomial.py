"""Lambertian and bi-polynomial models in x = n . h and y = l . h (paper Eq. 2 and Sec. 3.3).

The relaxed bi-polynomial of degree d is rho(x, y) = sum_{a, b <= d} c_ab x^a y^b: degree 1 is
bilinear (4 parameters), 2 the relaxed biquadratic of Eq. 2 (9), 3 bicubic (16).
"""

import numpy as np

from .base import LinearModel, register_model

__all__ = ["Lambert", "Bilinear", "Biquadratic", "Bicubic", "BiPolynomial"]


@register_model
class Lambert(LinearModel):
    """Constant BRDF: rho = albedo (1 parameter)."""

    name = "lambert"
    n_params = 1
    description = "Lambertian, rho = constant"

    def basis(self, geometry):
        shape = np.broadcast_shapes(np.shape(geometry.nh), np.shape(geometry.lh))
        return np.ones(shape + (1,))


class BiPolynomial(LinearModel):
    """rho = sum_{a, b <= degree} c_ab x^a y^b with x = n . h, y = l . h.

    Parameters are ordered as in the paper's Eq. 2 (A..I for degree 2): highest power of x
    first, and within it highest power of y first.
    """

    degree = 2

    def __init__(self):
        self.n_params = (self.degree + 1) ** 2
        powers = range(self.degree, -1, -1)
        self.exponents = [(a, b) for a in powers for b in powers]

    def basis(self, geometry):
        x, y = np.broadcast_arrays(np.asarray(geometry.nh, float), np.asarray(geometry.lh, float))
        xp = [np.ones_like(x), x]
        yp = [np.ones_like(y), y]
        for _ in range(2, self.degree + 1):
            xp.append(xp[-1] * x)
            yp.append(yp[-1] * y)
        return np.stack([xp[a] * yp[b] for a, b in self.exponents], axis=-1)


@register_model
class Bilinear(BiPolynomial):
    name = "bilinear"
    degree = 1
    description = "relaxed bilinear in n.h and l.h (4 parameters)"


@register_model
class Biquadratic(BiPolynomial):
    name = "biquadratic"
    degree = 2
    description = "relaxed biquadratic, paper Eq. 2 (9 parameters A..I)"


@register_model
class Bicubic(BiPolynomial):
    name = "bicubic"
    degree = 3
    description = "relaxed bicubic in n.h and l.h (16 parameters)"
