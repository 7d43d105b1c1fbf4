"""Biquadratic photometric stereo kernels (paper Sec. 5, Eq. 2, 8, 9), batched over pixels.

Notation: for pixel n and light k, x = n . h_k, y = l_k . h_k, shading s = b . l_k with
b = albedo * n, and the relaxed biquadratic rho(x, y) = sum_{a, c <= 2} C[a, c] x^a y^c. Image
model: obs = rho(x, y) * s (light intensities divided out beforehand).

Internally coefficients are kept as C (..., 3, 3) indexed [power of x, power of y]; the paper's
order A..I (x^2 y^2, x^2 y, x^2, x y^2, x y, x, y^2, y, 1) is :func:`to_paper_order`.

Two refinements over the paper's alternation, both measured on DiLiGenT (docs/photometric-stereo.md):

* The normal update is a Gauss-Newton step on the exact objective, including d rho / d n
  (the paper freezes rho at the previous normal; that step barely moves along the
  tilt-versus-falloff direction that a narrow light cone leaves nearly ambiguous).
* Each pixel's 9 parameters are pulled (ridge, strength ``shape_prior``) toward albedo x one
  shape shared by the object, fitted jointly with the normals of a pixel subsample. With one
  material this resolves the ambiguity; with several, the per-pixel term still adapts.

Speed: with lights shared by all pixels (the usual case), :func:`alternate_shared` runs the
same alternation as :func:`fit_pixel_shapes` + :func:`gauss_newton_normals` with fewer passes
over the (N, K) arrays, and the shared-shape fit builds its blocks from (N, K) @ (K, m)
moment products instead of (N, K, 9) arrays; tests/pipeline/photometric/test_fast.py checks
both against the general code, which per-pixel (near) lights still use.
"""

import numpy as np

from .kernels import alternate_shared_jit, jit_enabled
from .lambert import solve3

__all__ = ["half_vectors", "to_paper_order", "shape_and_slope", "fit_pixel_shapes", "gauss_newton_normals",
           "alternate_shared", "alternate_numpy", "alternate_per_pixel", "unit", "powers", "cosines",
           "normal_system", "X_POWER", "Y_POWER"]

#: powers of x and of y of the flat coefficient index 3a + c (C[a, c] multiplies x^a y^c)
X_POWER = np.repeat(np.arange(3), 3)
Y_POWER = np.tile(np.arange(3), 3)


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


def _project(weighted, ypow):
    """sum_k weighted[n, k] * ypow[(n,) k, j] -> (N, J) for shared or per-pixel y."""
    return weighted @ ypow if ypow.ndim == 2 else np.einsum("nk,nkj->nj", weighted, ypow)


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


def fit_pixel_shapes(obs, weights, b, lights, h, y, prior=None, shape_prior=0.0):
    """Per-pixel biquadratic coefficients for fixed normals (the linear half of Eq. 9).

    Parameters
    ----------
    obs, weights : ndarray (N, K)
    b : ndarray (N, 3)
        Albedo-scaled normals.
    lights, h : ndarray (K, 3) or (N, K, 3)
    y : ndarray (K,) or (N, K)
    prior : ndarray (3, 3), optional
        Shared shape; each pixel is pulled toward albedo * prior.
    shape_prior : float
        Ridge strength relative to the mean diagonal of each pixel's normal matrix.

    Returns
    -------
    ndarray (N, 3, 3)
    """
    albedo = np.linalg.norm(b, axis=1)
    n = b / np.maximum(albedo, 1e-300)[:, None]
    x, s = cosines(n, lights, h)
    y5 = powers(np.asarray(y, float), 4)                  # (K, 5) or (N, K, 5)
    # Normal-matrix entries are moments sum_k w s^2 x^i y^j (i, j <= 4): 5 products with y^j.
    term = weights * s * s
    moments = np.empty((len(obs), 5, 5))
    for i in range(5):
        moments[:, i, :] = _project(term, y5)
        term = term * x
    term = weights * s * obs
    rhs = np.empty((len(obs), 3, 3))
    for a in range(3):
        rhs[:, a, :] = _project(term, y5[..., :3])
        term = term * x
    normal = moments[:, X_POWER[:, None] + X_POWER[None, :], Y_POWER[:, None] + Y_POWER[None, :]]            # (N, 9, 9)
    rhs = rhs.reshape(-1, 9)
    scale = np.trace(normal, axis1=1, axis2=2)[:, None] / 9.0 + 1e-300
    ridge = max(shape_prior, 1e-10)
    target = 0.0 if prior is None else albedo[:, None] * prior.reshape(1, 9)
    normal = normal + (ridge * scale)[..., None] * np.eye(9)
    coeffs = np.linalg.solve(normal, (rhs + ridge * scale * target)[..., None])[..., 0]
    return coeffs.reshape(-1, 3, 3) / np.maximum(albedo, 1e-300)[:, None, None]


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


def gauss_newton_normals(obs, weights, b, coeffs, lights, h, y, steps=1):
    """Gauss-Newton steps on b = albedo * n for fixed shape coefficients (N, 3, 3) or (3, 3).

    Minimises sum_k w (obs - rho(n . h_k, y_k) * (b . l_k))^2 with the dependence of rho on n
    included. Returns (b (N, 3), residual before the first step (N,), residual after (N,)),
    residuals being weighted sums of squares.
    """
    before = None
    y3 = powers(np.asarray(y, float), 2)
    for _ in range(steps):
        albedo = np.linalg.norm(b, axis=1, keepdims=True)
        n = b / np.maximum(albedo, 1e-300)
        x, cos = cosines(n, lights, h)
        rho, slope = shape_and_slope(coeffs, x, y3)
        resid = obs - rho * cos * albedo
        if before is None:
            before = np.sum(weights * resid**2, axis=1)
        # d x / d b = (h - x n) / |b|; d (b . l) / d b = l
        c = cos * slope
        if lights.ndim == 2:
            normal, grad = normal_system(weights, resid, rho, c, x, n, lights, h)
        else:
            jac = rho[..., None] * lights + c[..., None] * (h - x[..., None] * n[:, None, :])
            wj = jac * weights[..., None]
            normal = np.einsum("nki,nkj->nij", wj, jac)
            grad = np.einsum("nki,nk->ni", wj, resid)
        normal += (1e-12 + 1e-9 * np.trace(normal, axis1=1, axis2=2))[:, None, None] * np.eye(3)
        b = b + np.linalg.solve(normal, grad[..., None])[..., 0]
    albedo = np.linalg.norm(b, axis=1, keepdims=True)
    x, cos = cosines(b / np.maximum(albedo, 1e-300), lights, h)
    rho, _ = shape_and_slope(coeffs, x, y3)
    return b, before, np.sum(weights * (obs - rho * cos * albedo) ** 2, axis=1)


# ----------------------------------------------------------------------------- fast path
def alternate_shared(obs, weights, b, lights, h, y, prior=None, shape_prior=0.0, max_iter=10, tol=1e-6):
    """The alternation (fit shapes, one Gauss-Newton normal step) for lights shared by all pixels.

    Runs the compiled per-pixel kernel (:func:`pipeline.photometric.kernels.alternate_shared_jit`)
    unless ``PSRIG_NO_JIT`` is set or compiling failed, else the numpy reference
    :func:`alternate_numpy`; parameters and results are those of :func:`alternate_numpy`
    (without its iteration counts).
    """
    fast = alternate_shared_jit(obs, weights, b, lights, h, y, prior=prior, shape_prior=shape_prior,
                                max_iter=max_iter, tol=tol) if jit_enabled() else None
    result = fast if fast is not None else alternate_numpy(obs, weights, b, lights, h, y, prior=prior,
                                                           shape_prior=shape_prior, max_iter=max_iter, tol=tol)
    return result[:4]


def alternate_numpy(obs, weights, b, lights, h, y, prior=None, shape_prior=0.0, max_iter=10, tol=1e-6):
    """The alternation for shared lights in numpy: the reference for the compiled kernel.

    Same steps and stopping rule as calling :func:`fit_pixel_shapes` then
    :func:`gauss_newton_normals` per iteration, computed with fewer passes over the (N, K)
    arrays: x and n . l carry over from one step's final residual to the next fit, the shape
    polynomials q_a(y) are evaluated once per fit, and the pixels still moving are compacted.

    Parameters
    ----------
    obs, weights : ndarray (N, K)
    b : ndarray (N, 3)
        Starting albedo-scaled normals; not modified.
    lights, h : ndarray (K, 3)
    y : ndarray (K,)
    prior, shape_prior
        As for :func:`fit_pixel_shapes`.
    max_iter : int
    tol : float
        A pixel stops when its residual changes by <= tol x sum_k w obs^2, or rises.

    Returns
    -------
    b : ndarray (N, 3)
    coeffs : ndarray (N, 3, 3)
    rss : ndarray (N,)
        Weighted residual sum of squares of the returned b and coeffs (NaN where never fitted).
    moving : ndarray (N,) bool
        Pixels still changing after ``max_iter`` iterations.
    iterations : ndarray (N,) int
        Shape fits done per pixel.
    """
    b = np.array(b, dtype=float)
    coeffs = np.zeros((len(b), 3, 3))
    coeffs[:, 0, 0] = 1.0
    rss = np.full(len(b), np.nan)
    idx = np.arange(len(b))
    iterations = np.zeros(len(b), np.int64)
    y = np.asarray(y, float)
    tables = _tables(lights, h, y)
    w, wobs = weights, weights * obs
    scale = np.einsum("nk,nk->n", wobs, obs) + 1e-300
    albedo, n, x, cos = _geometry(b, lights, h)
    for _ in range(max_iter):
        if idx.size == 0:
            break
        iterations[idx] += 1
        c = _fit_shapes(x, cos, w, wobs, albedo, tables, prior, shape_prior)
        q = [c[:, a, :] @ tables["y3"].T for a in range(3)]
        b_new, before = _gauss_newton_step(obs, w, b[idx], albedo, n, x, cos, q, lights, h, tables)
        albedo_new, n_new, x_new, cos_new = _geometry(b_new, lights, h)
        rho = q[2] * x_new
        rho += q[1]
        rho *= x_new
        rho += q[0]
        after = _weighted_rss(obs, w, rho, cos_new, albedo_new)
        better = np.isfinite(after) & (after <= before * (1 + 1e-9))
        b[idx[better]] = b_new[better]
        coeffs[idx] = c
        rss[idx] = np.where(better, after, before)
        keep = better & (np.abs(before - after) > tol * scale)
        albedo, n, x, cos = albedo_new, n_new, x_new, cos_new
        if not keep.all():
            idx, obs, w, wobs, scale = idx[keep], obs[keep], w[keep], wobs[keep], scale[keep]
            albedo, n, x, cos = albedo[keep], n[keep], x[keep], cos[keep]
    moving = np.zeros(len(b), bool)
    moving[idx] = True
    return b, coeffs, rss, moving, iterations


def _tables(lights, h, y):
    """Per-light tables used by the fast path: powers of y and outer products of l and h."""
    lh = _outer(lights, h)
    sym = lh + lh.reshape(-1, 3, 3).transpose(0, 2, 1).reshape(-1, 9)
    f32 = np.float32
    return {"y5": powers(y, 4), "y3": powers(y, 2), "ll32": _outer(lights, lights).astype(f32),
            "hh32": _outer(h, h).astype(f32), "sym32": sym.astype(f32), "l32": lights.astype(f32),
            "h32": h.astype(f32)}


def _geometry(b, lights, h):
    albedo = np.linalg.norm(b, axis=1)
    n = b / np.maximum(albedo, 1e-300)[:, None]
    return albedo, n, n @ h.T, n @ lights.T


def _weighted_rss(obs, w, rho, cos, albedo):
    """sum_k w (obs - rho cos albedo)^2 per pixel; overwrites rho."""
    rho *= cos
    rho *= albedo[:, None]
    np.subtract(obs, rho, out=rho)
    return np.einsum("nk,nk,nk->n", w, rho, rho)


def _fit_shapes(x, s, w, wobs, albedo, tables, prior, shape_prior):
    """fit_pixel_shapes from precomputed x = n . h, s = n . l and wobs = w obs."""
    y5 = tables["y5"]
    ws = w * s
    term = ws * s
    moments = np.empty((len(x), 5, 5))
    for i in range(5):
        moments[:, i, :] = term @ y5
        if i < 4:
            term *= x
    np.multiply(wobs, s, out=term)
    rhs = np.empty((len(x), 3, 3))
    for a in range(3):
        rhs[:, a, :] = term @ y5[:, :3]
        if a < 2:
            term *= x
    return _solve_shapes(moments, rhs.reshape(-1, 9), albedo, prior, shape_prior)


_MOMENT_INDEX = ((X_POWER[:, None] + X_POWER[None, :]) * 5 + Y_POWER[:, None] + Y_POWER[None, :]).ravel()  # 9 x 9 -> 5 x 5


def _solve_shapes(moments, rhs, albedo, prior, shape_prior):
    """The ridge-regularised 9 x 9 solve of :func:`fit_pixel_shapes` from moments (N, 5, 5)."""
    normal = np.take(moments.reshape(-1, 25), _MOMENT_INDEX, axis=1)            # (N, 81)
    diagonal = normal[:, ::10]
    scale = diagonal.sum(axis=1)[:, None] / 9.0 + 1e-300
    ridge = max(shape_prior, 1e-10)
    diagonal += ridge * scale                                                   # a view: in place
    if prior is not None:
        rhs = rhs + ridge * scale * (albedo[:, None] * prior.reshape(1, 9))
    coeffs = np.linalg.solve(normal.reshape(-1, 9, 9), rhs[..., None])[..., 0]
    return coeffs.reshape(-1, 3, 3) / np.maximum(albedo, 1e-300)[:, None, None]


def _gauss_newton_step(obs, w, b, albedo, n, x, cos, q, lights, h, tables):
    """One step of :func:`gauss_newton_normals` given the shape polynomials q_a(y) (3 x (N, K)).

    The residual (and so the convergence test) is float64; the normal equations of the step
    are accumulated in float32, which only perturbs the step by ~1e-6 of its length: the
    float64 residual after the step still decides whether it is kept. Returns (b, residual
    before the step).
    """
    slope = q[2] * x
    rho = slope + q[1]
    slope += rho                                   # q1 + 2 x q2
    rho *= x
    rho += q[0]
    res = rho * cos
    res *= albedo[:, None]
    np.subtract(obs, res, out=res)
    before = np.einsum("nk,nk,nk->n", w, res, res)
    slope *= cos
    f32 = np.float32
    w, rho, c, x, res = w.astype(f32), rho.astype(f32), slope.astype(f32), x.astype(f32), res.astype(f32)
    res *= w
    wr, wc = w * rho, w * c
    normal = (wr * rho) @ tables["ll32"]
    t = wr * c
    normal += t @ tables["sym32"]
    t *= x
    cross = t @ tables["l32"]
    np.multiply(wc, c, out=t)
    normal += t @ tables["hh32"]
    t *= x
    cross += t @ tables["h32"]
    normal = normal.astype(float).reshape(-1, 3, 3)
    outer = cross[:, :, None] * n[:, None, :]
    normal = normal - outer - outer.transpose(0, 2, 1)
    normal += np.einsum("nk,nk->n", t, x)[:, None, None] * (n[:, :, None] * n[:, None, :])
    np.multiply(res, c, out=c)
    grad = ((res * rho) @ tables["l32"] + c @ tables["h32"]).astype(float) \
        - np.einsum("nk,nk->n", c, x)[:, None] * n
    normal += (1e-12 + 1e-9 * np.trace(normal, axis1=1, axis2=2))[:, None, None] * np.eye(3)
    return b + solve3(normal, grad), before


def alternate_per_pixel(obs, weights, b, coeffs, rss, active, lights, h, y, prior, ridge, max_iter, tol):
    """The general alternation (per-pixel lights, e.g. near lights; shared ones too), in place.

    Parameters
    ----------
    obs, weights : ndarray (N, K)
    b : ndarray (N, 3)
        Albedo-scaled normals, updated in place.
    coeffs : ndarray (N, 3, 3)
        Shape coefficients, updated in place; ``rss`` (N,) likewise.
    active : ndarray (M,) int
        Rows to fit.
    lights, h : ndarray (N, K, 3) or (K, 3); y : ndarray (N, K) or (K,)
    prior, ridge, max_iter, tol
        As for :func:`alternate_numpy` (``ridge`` is its ``shape_prior``).

    Returns
    -------
    ndarray (M',) int
        The rows still moving after ``max_iter`` iterations.
    """
    scale = np.sum(weights * obs**2, axis=1) + 1e-300
    for _ in range(max_iter):
        if active.size == 0:
            break
        sub = (lights, h, y) if lights.ndim == 2 else (lights[active], h[active], y[active])
        c = fit_pixel_shapes(obs[active], weights[active], b[active], *sub, prior=prior, shape_prior=ridge)
        b_new, before, after = gauss_newton_normals(obs[active], weights[active], b[active], c, *sub)
        better = np.isfinite(after) & (after <= before * (1 + 1e-9))
        b[active[better]] = b_new[better]
        coeffs[active] = c
        rss[active] = np.where(better, after, before)
        done = ~better | (np.abs(before - after) <= tol * scale[active])
        active = active[~done]
    return active
