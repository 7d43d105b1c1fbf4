"""The biquadratic model's building blocks (paper Eq. 2), batched over pixels.

Notation: for pixel n and light k, x = n . h_k, y = l_k . h_k, shading s = n . l_k, and the
relaxed biquadratic rho(x, y) = sum_{a, c <= 2} C[a, c] x^a y^c. Image model: obs = albedo *
rho(x, y) * s (light intensities divided out beforehand). Coefficients are kept as C
(..., 3, 3) indexed [power of x, power of y]; the paper's order A..I (x^2 y^2, x^2 y, x^2,
x y^2, x y, x, y^2, y, 1) is :func:`to_paper_order`.
"""

import numpy as np

__all__ = ["unit", "half_vectors", "to_paper_order", "powers", "shape_and_slope", "cosines", "normal_system",
           "X_POWER", "Y_POWER", "MOMENT_INDEX"]

#: powers of x and of y of the flat coefficient index 3a + c (C[a, c] multiplies x^a y^c)
X_POWER = np.repeat(np.arange(3), 3)
Y_POWER = np.tile(np.arange(3), 3)
#: flat (9 x 9) -> flat (5 x 5) index: the normal matrix of the 9 coefficients is made of the
#: 25 moments sum_k w s^2 x^i y^j (i, j <= 4)
MOMENT_INDEX = ((X_POWER[:, None] + X_POWER[None, :]) * 5 + Y_POWER[:, None] + Y_POWER[None, :]).ravel()


def unit(v):
    """Normalise vectors along the last axis (zero stays zero)."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(norm, 1e-300)

def half_vectors(lights, view=(0.0, 0.0, 1.0)):
    """Half vectors h and y = l . h for lights (K, 3) or (N, K, 3); returns (h, y)."""
    h = unit(lights + np.asarray(view, float))
    return h, np.sum(lights * h, axis=-1)

def to_paper_order(coeffs):
    """C (..., 3, 3) [x power, y power] -> (..., 9) in the paper's order A..I."""
    return coeffs[..., ::-1, ::-1].reshape(coeffs.shape[:-2] + (9,))

def powers(v, top):
    """Stack v^0..v^top along a new last axis."""
    out = [np.ones_like(v), v]
    for _ in range(2, top + 1):
        out.append(out[-1] * v)
    return np.stack(out[: top + 1], axis=-1)

def shape_and_slope(coeffs, x, y3):
    """rho and d rho / dx, each (N, K), for coefficients C (N, 3, 3) or (3, 3).

    ``y3`` holds y^0..y^2, (K, 3) shared or (N, K, 3) per pixel.
    """
    if coeffs.ndim == 2:
        q = [np.broadcast_to(coeffs[a] @ y3.T, x.shape) if y3.ndim == 2 else y3 @ coeffs[a] for a in range(3)]
    elif y3.ndim == 2:
        q = [coeffs[:, a, :] @ y3.T for a in range(3)]
    else:
        q = [np.einsum("nc,nkc->nk", coeffs[:, a, :], y3) for a in range(3)]
    rho = q[0] + x * (q[1] + x * q[2])
    return rho, q[1] + 2.0 * x * q[2]

def cosines(n, lights, h):
    if lights.ndim == 2:
        return n @ h.T, n @ lights.T
    return np.einsum("ni,nki->nk", n, h), np.einsum("ni,nki->nk", n, lights)

def _outer(u, v):
    """(K, 3), (K, 3) -> (K, 9) table of u v^T, row-major."""
    return (u[:, :, None] * v[:, None, :]).reshape(len(u), 9)

def normal_system(weights, resid, rho, c, x, n, lights, h):
    """J^T W J (N, 3, 3) and J^T W r (N, 3) for J = rho l + c (h - x n), shared lights.

    Expanded into (N, K) @ (K, 9) products with outer-product tables so that no (N, K, 3)
    array is formed.
    """
    wr, wc = weights * rho, weights * c
    lh = _outer(lights, h)
    sym = lh + lh.reshape(-1, 3, 3).transpose(0, 2, 1).reshape(-1, 9)
    normal = (wr * rho) @ _outer(lights, lights) + (wr * c) @ sym + (wc * c) @ _outer(h, h)
    normal = normal.reshape(-1, 3, 3)
    # Terms in n: -x (rho c (l n^T + n l^T) + c^2 (h n^T + n h^T)) + c^2 x^2 n n^T.
    cross = (wr * c * x) @ lights + (wc * c * x) @ h                       # (N, 3)
    outer = cross[:, :, None] * n[:, None, :]
    normal = normal - outer - outer.transpose(0, 2, 1)
    normal = normal + np.sum(wc * c * x * x, axis=1)[:, None, None] * (n[:, :, None] * n[:, None, :])
    grad = (wr * resid) @ lights + (wc * resid) @ h - np.sum(wc * resid * x, axis=1)[:, None] * n
    return normal, grad
