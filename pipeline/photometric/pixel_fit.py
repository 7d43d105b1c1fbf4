"""Each pixel's normal and 9 biquadratic coefficients, fitted jointly (paper Eq. 2, 8, 9).

The paper alternates: fix the normal and fit the coefficients, fix rho and solve the normal.
Under a narrow cone of lights the tilt of the normal and the falloff of rho are nearly
interchangeable (on DiLiGenT cat the tilt columns lie almost inside the span of the shape
columns, squared canonical correlation 0.998), so that alternation creeps: on cat it moved
the error from 5.33 to 4.97 degrees between its 3rd and 100th iteration. Here both are one
Levenberg-Marquardt problem in 11 unknowns per pixel: a rotation of the normal in its tangent
plane (2) and the 9 coefficients c, with the data term sum_k w (obs - R(x, y) s)^2, R = the
biquadratic with coefficients c (albedo included), so it converges in a few steps and a pixel
stops when its Gauss-Newton step would turn the normal by less than ``tol_deg`` (that step
estimates the distance to the minimum whatever the damping; it is not tried).

c is linear, so it is eliminated (variable projection): every iterate holds the best c for
its normal, each step is the damped Gauss-Newton step of the reduced problem in the normal's
two tangent angles (the Schur complement of the joint (n, c) system), and the trial takes the
best c for the turned normal, so the iterate stays on the floor of the tilt/shape valley. The
damping follows the ratio of the actual to the predicted decrease (Nielsen's rule) rather than
x10 / /10, which on hard pixels alternated accepted and rejected steps (docs/photometric-stereo.md).

The prior is scale-free: with the object's shared shape P (from
:mod:`pipeline.photometric.shared_shape`) it penalises only the part of c that is not a
multiple of P, ``shape_prior * scale * |Q c|^2`` with Q the projector orthogonal to P and
scale the mean diagonal of the pixel's coefficient normal matrix, so the albedo is free and
the albedo/shape gauge cannot drift. Without a prior a tiny ridge on c keeps the solves
defined. The albedo reported is the mean of R over the used observations, and the shape
C = c / albedo has mean 1 there.

:func:`fit_pixels` runs the compiled kernel (:mod:`pipeline.photometric.kernels`) unless it
is unavailable or ``PSRIG_NO_JIT`` is set; :func:`fit_pixels_numpy` is the reference.
"""

import numpy as np

from ..settings.normals import MAX_ITER, TOL_DEG
from .kernels import fit_pixels_jit, jit_enabled
from .model import MOMENT_INDEX, cosines, powers, unit

__all__ = ["fit_pixels", "fit_pixels_numpy", "penalty_matrix", "TOL_DEG", "MAX_ITER", "MIN_RIDGE"]

#: the ridge on c without a prior (keeps the 9 x 9 block positive definite)
MIN_RIDGE = 1e-10
#: damping: start, and the bound past which a pixel that finds no better step stops
_MU0, _MU_MAX = 1e-6, 1e8


def penalty_matrix(prior, shape_prior):
    """(9, 9) matrix of the prior's penalty per unit of scale: ``shape_prior`` x the projector
    orthogonal to ``prior`` (3, 3), or ``MIN_RIDGE`` x I without a prior."""
    if prior is None:
        return MIN_RIDGE * np.eye(9)
    p = np.asarray(prior, float).reshape(9)
    return max(shape_prior, MIN_RIDGE) * (np.eye(9) - np.outer(p, p) / max(p @ p, 1e-300))


def fit_pixels(obs, weights, b, lights, h, y, prior=None, shape_prior=0.0, max_iter=MAX_ITER, tol_deg=TOL_DEG,
               dof_below=np.inf):
    """Fit every pixel's normal and coefficients; see the module docstring.

    Parameters
    ----------
    obs, weights : ndarray (N, K)
        Observations (light intensities divided out) and 0/1 weights of the used ones.
    b : ndarray (N, 3)
        Starting albedo-scaled normals (camera frame), e.g. the Lambertian fit.
    lights, h : ndarray (K, 3) or (N, K, 3)
        Unit light directions and half vectors, shared or per pixel.
    y : ndarray (K,) or (N, K)
        l . h.
    prior : ndarray (3, 3), optional
        The object's shared shape.
    shape_prior : float
        Strength of the pull toward multiples of ``prior``.
    max_iter : int
    tol_deg : float

    Returns
    -------
    b : ndarray (N, 3)
        Albedo-scaled unit normals.
    coeffs : ndarray (N, 3, 3)
        Shapes C with mean 1 over the pixel's used observations.
    rss : ndarray (N,)
        Weighted residual sum of squares (the data term).
    moving : ndarray (N,) bool
        Pixels whose Gauss-Newton step would still turn the normal by ``tol_deg`` or more
        after ``max_iter`` steps.
    dof : ndarray (N,)
        Effective number of parameters: 2 for the normal plus the trace of the coefficients'
        hat matrix (9 without a prior, about 1 with a strong one); 11, their most, for pixels
        with ``dof_below`` observations or more (not computed there).
    """
    penalty = penalty_matrix(prior, shape_prior)
    fast = fit_pixels_jit(obs, weights, b, lights, h, y, penalty, max_iter, tol_deg, dof_below) if jit_enabled() \
        else None
    if fast is not None:
        return fast
    return fit_pixels_numpy(obs, weights, b, lights, h, y, penalty, max_iter, tol_deg, dof_below)


def fit_pixels_numpy(obs, weights, b, lights, h, y, penalty, max_iter=MAX_ITER, tol_deg=TOL_DEG, dof_below=np.inf):
    """:func:`fit_pixels` in numpy, batched over pixels (``penalty`` from :func:`penalty_matrix`)."""
    obs, weights = np.asarray(obs, float), np.asarray(weights, float)
    n = unit(np.asarray(b, float))
    y5 = powers(np.asarray(y, float), 4)
    x, s = cosines(n, lights, h)
    data = _coefficient_matrix(weights, s, x, y5)
    scale = np.trace(data, axis1=1, axis2=2) / 9.0 + 1e-300
    pen = scale[:, None, None] * penalty
    c = np.linalg.solve(data + pen, _coefficient_rhs(weights, s, x, y5, obs)[..., None])[..., 0]
    cost = _cost(obs, weights, n, c, lights, h, y5, pen)
    mu, nu = np.full(len(obs), _MU0), np.full(len(obs), 2.0)
    active = np.flatnonzero(np.isfinite(cost))
    tan2_tol = np.tan(np.radians(tol_deg)) ** 2
    for _ in range(max_iter):
        if active.size == 0:
            break
        sub = _rows(active, lights, h, y5)
        step, t1, t2, predicted, newton = _lm_step(obs[active], weights[active], n[active], c[active], *sub,
                                                   pen[active], mu[active])
        # converged when the undamped (Gauss-Newton) step would turn the normal by less than the
        # tolerance: the step to the reduced problem's minimum, whatever the damping; not tried
        small = np.sum(newton**2, axis=1) <= tan2_tol
        active = active[~small]
        step, t1, t2, predicted = step[~small], t1[~small], t2[~small], predicted[~small]
        if active.size == 0:
            break
        sub = _rows(active, lights, h, y5)
        n_try = unit(n[active] + step[:, :1] * t1 + step[:, 1:2] * t2)
        # variable projection: c is linear, so the trial takes the best c for the trial normal
        c_try = _best_coefficients(obs[active], weights[active], n_try, *sub, pen[active])
        cost_try = _cost(obs[active], weights[active], n_try, c_try, *sub, pen[active])
        better = np.isfinite(cost_try) & (cost_try <= cost[active])
        gain = (cost[active] - cost_try) / np.maximum(predicted, 1e-300)
        keep = active[better]
        n[keep], c[keep], cost[keep] = n_try[better], c_try[better], cost_try[better]
        # Nielsen's damping rule: follow the gain ratio; double the increase after each rejection
        shrink = np.maximum(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
        mu[active] = np.where(better, np.maximum(mu[active] * shrink, 1e-12), mu[active] * nu[active])
        nu[active] = np.where(better, 2.0, nu[active] * 2.0)
        done = mu[active] > _MU_MAX
        active = active[~done]
    moving = np.zeros(len(obs), bool)
    moving[active] = True
    return _results(obs, weights, n, c, lights, h, y5, pen, moving, dof_below)


def _best_coefficients(obs, weights, n, lights, h, y5, pen):
    """The coefficients (N, 9) that minimise the cost at normals n (a linear solve)."""
    x, s = cosines(n, lights, h)
    data = _coefficient_matrix(weights, s, x, y5)
    with np.errstate(invalid="ignore"):
        return np.linalg.solve(data + pen, _coefficient_rhs(weights, s, x, y5, obs)[..., None])[..., 0]


def _rows(idx, lights, h, y5):
    if lights.ndim == 2:
        return lights, h, y5
    return lights[idx], h[idx], y5[idx]


def _project(weighted, ypow):
    """sum_k weighted[n, k] ypow[(n,) k, j] -> (N, J) for shared or per-pixel y powers."""
    return weighted @ ypow if ypow.ndim == 2 else np.einsum("nk,nkj->nj", weighted, ypow)


def _coefficient_matrix(weights, s, x, y5):
    """sum_k w s^2 x^(a+a') y^(c+c') as (N, 9, 9), from the 25 moments."""
    term = weights * s * s
    moments = np.empty((len(x), 5, 5))
    for i in range(5):
        moments[:, i, :] = _project(term, y5)
        term = term * x
    return np.take(moments.reshape(-1, 25), MOMENT_INDEX, axis=1).reshape(-1, 9, 9)


def _coefficient_rhs(weights, s, x, y5, values):
    """sum_k w s values x^a y^c as (N, 9)."""
    term = weights * s * values
    out = np.empty((len(x), 3, 3))
    for a in range(3):
        out[:, a, :] = _project(term, y5[..., :3])
        term = term * x
    return out.reshape(-1, 9)


def _surface(n, c, lights, h, y5):
    """x, s, R and dR/dx, each (N, K), for normals n (N, 3) and coefficients c (N, 9)."""
    x, s = cosines(n, lights, h)
    q = [_project_coefficients(c[:, 3 * a:3 * a + 3], y5) for a in range(3)]
    r = q[0] + x * (q[1] + x * q[2])
    return x, s, r, q[1] + 2.0 * x * q[2]


def _project_coefficients(c3, y5):
    """sum_c c3[n, c] y^c -> (N, K)."""
    return c3 @ y5[:, :3].T if y5.ndim == 2 else np.einsum("nc,nkc->nk", c3, y5[..., :3])


def _cost(obs, weights, n, c, lights, h, y5, pen):
    _, s, r, _ = _surface(n, c, lights, h, y5)
    resid = obs - r * s
    return np.sum(weights * resid * resid, axis=1) + np.einsum("ni,nij,nj->n", c, pen, c)


def _tangents(n):
    """Two unit vectors (N, 3) spanning the plane orthogonal to each normal."""
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    t1 = unit(np.cross(n, axis))
    return t1, np.cross(n, t1)


def _lm_step(obs, weights, n, c, lights, h, y5, pen, mu):
    """The damped Gauss-Newton step (N, 2) of the normal's tangent angles with c eliminated (the
    Schur complement of the joint system; c is the best c for n, so its gradient is zero), the
    tangents, the decrease the damped model predicts (N,), and the undamped step (N, 2) (inf
    where the reduced system is singular)."""
    x, s, r, slope = _surface(n, c, lights, h, y5)
    resid = obs - r * s
    t1, t2 = _tangents(n)
    g = [slope * s * cosines(t, lights, h)[0] + r * cosines(t, lights, h)[1] for t in (t1, t2)]
    a_nn = np.empty((len(obs), 2, 2))
    a_nc = np.empty((len(obs), 2, 9))
    grad = np.empty((len(obs), 2))
    for i in range(2):
        wg = weights * g[i]
        for j in range(i, 2):
            a_nn[:, i, j] = a_nn[:, j, i] = np.sum(wg * g[j], axis=1)
        a_nc[:, i] = _coefficient_rhs(wg, s, x, y5, 1.0)
        grad[:, i] = np.sum(wg * resid, axis=1)
    with np.errstate(invalid="ignore"):
        z = np.linalg.solve(_coefficient_matrix(weights, s, x, y5) + pen, a_nc.transpose(0, 2, 1))
    schur = a_nn - a_nc @ z
    newton = _solve2(schur[:, 0, 0], schur[:, 0, 1], schur[:, 1, 1], grad, np.inf)
    d0, d1 = mu * schur[:, 0, 0] + 1e-300, mu * schur[:, 1, 1] + 1e-300
    step = _solve2(schur[:, 0, 0] + d0, schur[:, 0, 1], schur[:, 1, 1] + d1, grad, np.nan)
    # the decrease the damped quadratic model predicts: step . (grad + damping step)
    predicted = step[:, 0] * (grad[:, 0] + d0 * step[:, 0]) + step[:, 1] * (grad[:, 1] + d1 * step[:, 1])
    return step, t1, t2, predicted, newton


def _solve2(a00, a01, a11, rhs, singular):
    """The solutions (N, 2) of the symmetric 2 x 2 systems [[a00, a01], [a01, a11]] x = rhs (N, 2),
    ``singular`` where a system is not positive definite."""
    det = a00 * a11 - a01 * a01
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.stack([(a11 * rhs[:, 0] - a01 * rhs[:, 1]) / det, (a00 * rhs[:, 1] - a01 * rhs[:, 0]) / det], 1)
    x[~(det > 0)] = singular
    return x


def _results(obs, weights, n, c, lights, h, y5, pen, moving, dof_below):
    x, s, r, _ = _surface(n, c, lights, h, y5)
    resid = obs - r * s
    rss = np.sum(weights * resid * resid, axis=1)
    data = _coefficient_matrix(weights, s, x, y5)
    hat = np.linalg.solve(data + pen + 1e-300 * np.eye(9), data)
    dof = np.where(np.sum(weights > 0, axis=1) < dof_below, 2.0 + np.trace(hat, axis1=1, axis2=2), 11.0)
    albedo = np.sum(weights * r, axis=1) / np.maximum(np.sum(weights, axis=1), 1e-300)
    albedo = np.where(np.isfinite(albedo) & (albedo > 0), albedo, 1.0)
    coeffs = (c / albedo[:, None]).reshape(-1, 3, 3)
    return n * albedo[:, None], coeffs, rss, moving, dof
