"""The object's one biquadratic shape: fitted jointly with a pixel sample, and checked.

Under a narrow light cone the tilt of a pixel's normal and the falloff of its reflectance are
nearly interchangeable; one shape shared by the object (one material) resolves that. This
module fits it (:func:`fit_shared_shape`, Levenberg-Marquardt with the per-pixel unknowns
eliminated by a Schur complement) and tests whether one shape is credible for the object
(:func:`single_material_check`). The biquadratic method (:mod:`pipeline.photometric.biquadratic`)
pulls each pixel's parameters toward albedo x this shape.
"""

import concurrent.futures as futures
import contextlib

import numpy as np

from .model import X_POWER, Y_POWER, cosines, normal_system, powers, shape_and_slope
from .kernels import jit_enabled, shape_terms_jit
from .lambert import inverse3
from .pixel_fit import fit_pixels

__all__ = ["fit_shared_shape", "single_material_check", "ONE_MATERIAL_RATIO", "MIN_CHECK_OBS"]


def fit_shared_shape(obs, weights, b, lights, h, y, iterations=15, threads=1, start=None):
    """One biquadratic shape (3, 3) for all given pixels, fitted jointly with their b (N, 3).

    ``b`` is the per-pixel start; the shape starts constant, or at ``start`` (3, 3) (a shape
    fitted before, e.g. under slightly other lights).

    Levenberg-Marquardt over the 9 shared and 3N per-pixel unknowns; the per-pixel 3 x 3 blocks
    are eliminated (Schur complement), so each step solves one 9 x 9 system. The shape is
    normalised to mean 1 over the used observations (albedo carries the scale). The per-pixel
    terms are compiled (:func:`pipeline.photometric.kernels.shape_terms_jit`) unless the kernels
    are unavailable (then numpy, :func:`_numpy_terms`, the reference), on ``threads`` threads.
    """
    with futures.ThreadPoolExecutor(threads) if threads > 1 else contextlib.nullcontext() as executor:
        return _fit(_terms_function(obs, weights, lights, h, y, executor, threads), b, iterations, start)


def _fit(terms, b, iterations, start=None):
    """fit_shared_shape's Levenberg-Marquardt loop over ``terms`` (:func:`_terms_function`)."""
    if start is None:
        coeffs = np.zeros((3, 3))
        coeffs[0, 0] = 1.0
    else:
        coeffs = np.array(start, float).reshape(3, 3)
    cost = terms(b, coeffs, False)
    blocks = None
    damping = 1e-3
    for _ in range(iterations):
        blocks = blocks or terms(b, coeffs, True)   # a rejected step leaves (b, coeffs), so its blocks
        step = _schur_step(b, coeffs, blocks, damping)
        if step is None:
            break
        b_new, c_new = step
        trial = terms(b_new, c_new, False)
        if trial < cost:
            b, coeffs, cost, blocks = b_new, c_new, trial, None
            damping *= 0.3
        else:
            damping *= 10.0
            if damping > 1e6:
                break
    return coeffs, b


def _terms_function(obs, weights, lights, h, y, executor=None, parts=1):
    """``terms(b, coeffs, blocks)``: the data cost (float) at (b, coeffs), or with ``blocks`` the
    summed LM blocks (dict: cost, u (N, 3, 3), cross (N, 3, 9), v (9, 9), e_b (N, 3), e_c (9,),
    basis (9,) = sum w x^a y^c over every pixel)."""
    weight_sum = max(float(np.sum(weights)), 1e-300)

    def compiled(b, coeffs, blocks):
        out = shape_terms_jit(obs, weights, b, coeffs, lights, h, y, blocks, executor=executor, parts=parts)
        if out is None:
            return None
        cost = float(np.sum(out["cost"]))
        if not blocks:
            return cost
        moments = out["moments"].sum(axis=0).reshape(5, 5)
        v = moments[X_POWER[:, None] + X_POWER[None, :], Y_POWER[:, None] + Y_POWER[None, :]]
        return {"cost": cost, "u": out["u"], "cross": out["cross"], "v": v, "e_b": out["e_b"],
                "e_c": out["e_c"].sum(axis=0), "basis": out["basis"].sum(axis=0), "weight_sum": weight_sum}

    def numpy(b, coeffs, blocks):
        return _numpy_terms(obs, weights, b, coeffs, lights, h, y, blocks, weight_sum)

    def terms(b, coeffs, blocks):
        got = compiled(b, coeffs, blocks) if jit_enabled() else None
        return numpy(b, coeffs, blocks) if got is None else got

    return terms


def _numpy_terms(obs, weights, b, coeffs, lights, h, y, blocks, weight_sum):
    """:func:`_terms_function`'s terms in numpy."""
    y3 = powers(np.asarray(y, float), 2)
    state = _shared_state(obs, weights, b, coeffs, lights, h, y3)
    if not blocks:
        return state[0]
    lights_b = lights if lights.ndim == 3 else np.broadcast_to(lights, (len(b),) + lights.shape)
    half_b = h if h.ndim == 3 else np.broadcast_to(h, (len(b),) + h.shape)
    u, cross, v, e_b, e_c = _schur_blocks(weights, state, lights_b, half_b, y3)
    x = state[3]
    ypow = np.broadcast_to(y3, x.shape + (3,))
    basis = np.einsum("nk,nka->a", weights, (powers(x, 2)[..., X_POWER] * ypow[..., Y_POWER]))
    return {"cost": state[0], "u": u, "cross": cross, "v": v, "e_b": e_b, "e_c": e_c, "basis": basis,
            "weight_sum": weight_sum}


def _shared_state(obs, weights, b, coeffs, lights, h, y3):
    albedo = np.linalg.norm(b, axis=1, keepdims=True)
    n = b / np.maximum(albedo, 1e-300)
    x, cos = cosines(n, lights, h)
    rho, slope = shape_and_slope(coeffs, x, y3)
    resid = obs - rho * cos * albedo
    return float(np.sum(weights * resid**2)), albedo, n, x, cos, rho, slope, resid


def _schur_step(b, coeffs, blocks, damping):
    """The damped step from the summed blocks: (b_new (N, 3), coeffs_new (3, 3)), or None."""
    u, cross, v, e_b, e_c = (blocks[key] for key in ("u", "cross", "v", "e_b", "e_c"))
    u = u + (damping * np.trace(u, axis1=1, axis2=2) / 3 + 1e-12)[:, None, None] * np.eye(3)
    u_inv = inverse3(u)
    u_cross = u_inv @ cross
    u_e = np.einsum("nij,nj->ni", u_inv, e_b)
    schur = v - cross.reshape(-1, 9).T @ u_cross.reshape(-1, 9)     # sum_n cross_n' U_n^-1 cross_n
    schur += (damping * np.trace(schur) / 9 + 1e-12 * abs(np.trace(schur)) + 1e-300) * np.eye(9)
    rhs = e_c - cross.reshape(-1, 9).T @ u_e.reshape(-1)
    try:
        d_c = np.linalg.solve(schur, rhs)
    except np.linalg.LinAlgError:
        return None
    b_new = b + u_e - u_cross @ d_c
    c_new = coeffs + d_c.reshape(3, 3)
    # Albedo and shape share one scale: keep the mean shape at 1 over the used observations
    # (sum_k w rho = c . sum_k w x^a y^c at the current normals).
    mean = float(c_new.reshape(9) @ blocks["basis"]) / blocks["weight_sum"]
    if not np.isfinite(mean) or abs(mean) < 1e-12:
        return None
    return b_new * mean, c_new / mean

def _schur_blocks(weights, state, lights_b, half_b, y3):
    """LM blocks: U (N, 3, 3), cross (N, 3, 9), V (9, 9), e_b (N, 3), e_c (9,), undamped."""
    _, albedo, n, x, cos, rho, slope, resid = state
    if lights_b.ndim == 3 and lights_b.strides[0] == 0:
        return _schur_blocks_shared(weights, state, lights_b[0], half_b[0], y3)
    jac_b = rho[..., None] * lights_b + (cos * slope)[..., None] * (half_b - x[..., None] * n[:, None, :])
    xpow = powers(x, 2)
    ypow = np.broadcast_to(y3, x.shape + (3,))
    basis = (xpow[..., X_POWER] * ypow[..., Y_POWER])                       # (N, K, 9)
    jac_c = basis * (cos * albedo[:, :1])[..., None]
    wjb = jac_b * weights[..., None]
    wjc = jac_c * weights[..., None]
    u = np.einsum("nki,nkj->nij", wjb, jac_b)
    cross = np.einsum("nki,nkj->nij", wjb, jac_c)
    v = wjc.reshape(-1, 9).T @ jac_c.reshape(-1, 9)
    e_b = np.einsum("nki,nk->ni", wjb, resid)
    e_c = np.einsum("nki,nk->i", wjc, resid)
    return u, cross, v, e_b, e_c

def _schur_blocks_shared(weights, state, lights, h, y3):
    """:func:`_schur_blocks` for shared lights (K, 3), from (N, K) @ (K, m) moment products.

    With jc_(a,c) = albedo cos x^a y^c and jb = rho l + c' (h - x n) (c' = cos slope), every
    block is a sum over lights of w cos x^a times a per-light table (y^c, l y^c, h y^c).
    """
    _, albedo, n, x, cos, rho, slope, resid = state
    albedo = albedo[:, 0]
    c = cos * slope
    u, e_b = normal_system(weights, resid, rho, c, x, n, lights, h)
    y5 = powers(y3[:, 1], 4)
    ly = (lights[:, :, None] * y3[:, None, :]).reshape(-1, 9)       # [k, 3 i + c] = l_i y^c
    hy = (h[:, :, None] * y3[:, None, :]).reshape(-1, 9)
    wcos = weights * cos
    term = wcos * cos
    moments = np.empty((5, 5))
    for i in range(5):
        moments[i] = albedo**2 @ (term @ y5)
        term *= x
    v = moments[X_POWER[:, None] + X_POWER[None, :], Y_POWER[:, None] + Y_POWER[None, :]]
    p, q = wcos * rho, wcos * c
    r = wcos * resid
    cross = np.empty((len(x), 3, 3, 3))                               # [n, i, a, c]
    e_c = np.empty((3, 3))
    q_next = q * x
    for a in range(3):
        cross[:, :, a, :] = ((p @ ly + q @ hy).reshape(-1, 3, 3) - n[:, :, None] * (q_next @ y3)[:, None, :])
        e_c[a] = albedo @ (r @ y3)
        if a < 2:
            p, q, r = p * x, q_next, r * x
            q_next = q * x
    cross *= albedo[:, None, None, None]
    return u, cross.reshape(-1, 3, 9), v, e_b, e_c.reshape(9)


#: The shared-shape prior assumes one material. It is used only when one shape leaves at most
#: this many times the residual that free per-pixel shapes leave, over what their extra
#: parameters alone explain: between what one-material objects and two-material ones give
#: (docs/photometric-stereo.md, "Constants").
ONE_MATERIAL_RATIO = 4.0
#: ... and only tested when pixels have this many selected observations (median): three times
#: the 12 unknowns of a free pixel, so its fit leaves residual to compare (DiLiGenT: 85-91).
MIN_CHECK_OBS = 36
#: steps of the free per-pixel fits the check compares with (they leave most of their residual
#: after a few; DiLiGenT ratios / expected with 10 and 50 steps: reading 1.94 / 2.03, cat 1.96 / 1.97)
CHECK_ITERATIONS = 10


def single_material_check(obs, weights, b, b_shared, shape, lights, h, y):
    """Whether one biquadratic shape explains the sampled pixels about as well as free ones.

    Parameters
    ----------
    obs, weights : ndarray (N, K)
        A sample of pixels and their selected observations.
    b : ndarray (N, 3)
        Their initial albedo-scaled normals; ``b_shared`` the ones fitted with ``shape`` (3, 3).
    lights, h, y
        As for :func:`pipeline.photometric.pixel_fit.fit_pixels` (or per pixel).

    Returns
    -------
    dict
        ``ratio``: residual with the shared shape over the residual with free per-pixel shapes;
        ``expected``: that ratio from the parameter counts alone (3 vs 12 per pixel) under pure
        noise; ``one_material``: ratio <= :data:`ONE_MATERIAL_RATIO` x expected, or True with
        ``tested`` False when the pixels have fewer than :data:`MIN_CHECK_OBS` observations.
    """
    y_arr = np.asarray(y, float)
    shared = _terms_function(obs, weights, lights, h, y_arr)(b_shared, shape, False)
    # free shapes fitted with their normals (at the initial normals alone they leave more
    # residual: on the two-material object of tests/pipeline/photometric/test_shape_check.py
    # the ratio read 3.47 there, 6.24 fitted)
    free = float(np.nansum(fit_pixels(obs, weights, b, lights, h, y_arr, max_iter=CHECK_ITERATIONS)[2]))
    used = np.sum(weights > 0, axis=1)
    expected = float(np.sum(np.maximum(used - 3, 1)) / np.sum(np.maximum(used - 12, 1)))
    ratio = shared / max(free, 1e-300)
    check = {"ratio": round(ratio, 4), "expected": round(expected, 4),
             "one_material": bool(ratio <= ONE_MATERIAL_RATIO * expected)}
    if np.median(used) < MIN_CHECK_OBS:
        # free shapes all but interpolate so few observations: the ratio then measures how far
        # the material is from biquadratic, not how many materials there are; keep the prior
        check.update(one_material=True, tested=False)
    return check
