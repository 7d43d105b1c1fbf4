"""Compiled per-pixel kernels (numba) for biquadratic photometric stereo with shared lights.

:func:`alternate_shared_jit` does the work of :func:`pipeline.photometric.alternation.alternate_numpy`
(fit the 9 shape parameters -> one Gauss-Newton normal step -> residual -> keep or stop), with
the same mathematics and stopping rule, pixel by pixel in one pass over each pixel's used
observations instead of many passes over (N, K) arrays. Everything is float64; each pixel's
result depends on that pixel alone, so it is the same whatever chunk it is computed in.

Nothing is compiled at import: numba is imported and the kernels are compiled (or loaded from
numba's on-disk cache, ``cache=True``) at the first call, under a lock, so concurrent chunk
threads wait for one compilation. The kernels release the GIL (``nogil``), so the chunk
threads of :func:`pipeline.photometric.estimate_normals` run them on all cores.

The numpy implementation stays the reference: ``PSRIG_NO_JIT=1`` in the environment selects it,
and if numba is missing or compiling/caching fails, :func:`kernels` warns once and returns None,
and callers use numpy.
"""

import math

import numpy as np

from ..jit import ENV_NO_JIT, Compiled, njit

__all__ = ["jit_enabled", "kernels", "alternate_shared_jit", "compile_seconds", "ENV_NO_JIT", "KERNELS"]


def jit_enabled():
    """True unless ``PSRIG_NO_JIT`` is set (to anything but '' or '0') or compiling failed."""
    return KERNELS.enabled()


def compile_seconds():
    """Seconds the first :func:`kernels` call spent compiling or loading from cache (None before)."""
    return KERNELS.seconds


def kernels():
    """The compiled kernels (a dict of numba dispatchers), or None when they are unavailable.

    The first call imports numba and compiles, or loads from numba's cache; a failure there
    (numba missing, an unwritable cache, a compiler error) gives one RuntimeWarning and None
    from then on (:class:`pipeline.jit.Compiled`).
    """
    return KERNELS.get()


def _build():
    """Decorate the kernel functions with numba.njit and compile them on a tiny problem."""
    # The kernels call each other through module globals: those must name the dispatchers
    # while numba compiles (and the pure-Python originals are kept for a later rebuild).
    compiled = {name: njit(func) for name, func in _PY.items()}
    globals().update(compiled)
    _warm_up(compiled["_alternate_kernel"])
    return compiled


def _warm_up(kernel):
    """Compile for the argument types :func:`alternate_shared_jit` always passes."""
    rng = np.random.default_rng(0)
    lights = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 0.866], [0.0, 0.5, 0.866], [-0.5, 0.0, 0.866]])
    obs = rng.random((2, 4)) + 0.5
    args = _arguments(obs, np.ones((2, 4)), np.array([[0.0, 0.0, 1.0]] * 2), lights,
                      _unit(lights + np.array([0.0, 0.0, 1.0])), None, 1e-10)
    outputs = _outputs(2)
    kernel(*args, 2, 1e-6, *outputs)


# ----------------------------------------------------------------------------- Python entry
def alternate_shared_jit(obs, weights, b, lights, h, y, prior=None, shape_prior=0.0, max_iter=10, tol=1e-6):
    """The compiled :func:`pipeline.photometric.alternation.alternate_numpy`; None if kernels are unavailable.

    Parameters and the first four results are those of
    :func:`pipeline.photometric.alternation.alternate_shared`; the fifth result, iterations (N,) int,
    is the number of shape fits done per pixel. ``y`` is recomputed from ``lights`` and ``h``
    only through its powers, passed as given.
    """
    compiled = kernels()
    if compiled is None:
        return None
    n = len(b)
    args = _arguments(obs, weights, b, lights, h, prior, max(shape_prior, 1e-10), y)
    outputs = _outputs(n)
    compiled["_alternate_kernel"](*args, int(max_iter), float(tol), *outputs)
    b_out, c_out, rss, moving, iterations = outputs
    return b_out, c_out.reshape(n, 3, 3), rss, moving.astype(bool), iterations


def _arguments(obs, weights, b, lights, h, prior, ridge, y=None):
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731 - one fixed signature
    lights, h = f64(lights), f64(h)
    y = np.sum(lights * h, axis=1) if y is None else f64(y)
    ypow = np.stack([np.ones_like(y), y, y * y, y * y * y, y * y * y * y], axis=1)
    prior9 = np.zeros(9) if prior is None else f64(prior).reshape(9)
    return f64(obs), f64(weights), f64(b), lights, h, ypow, prior9, float(ridge)


def _outputs(n):
    return np.empty((n, 3)), np.empty((n, 9)), np.empty(n), np.empty(n, np.uint8), np.empty(n, np.int64)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- kernels
# Written in plain Python over scalars so that numba compiles them; each loops over one
# pixel's K observations at most a few times per iteration.

def _alternate_kernel(obs, weights, b0, lights, h, ypow, prior, ridge, max_iter, tol,
                      b_out, c_out, rss_out, moving_out, iter_out):
    """Every pixel of obs (N, K): compact its used observations, then :func:`_pixel_alternation`."""
    n_pix, k = obs.shape
    o, w = np.empty(k), np.empty(k)
    lt, ht, yp = np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 5))
    xs, cs = np.empty(k), np.empty(k)
    for p in range(n_pix):
        m = 0
        # Zero-weight observations add exact zeros to every sum: leave them out.
        for j in range(k):
            if weights[p, j] != 0.0:
                o[m], w[m] = obs[p, j], weights[p, j]
                for i in range(3):
                    lt[m, i], ht[m, i] = lights[j, i], h[j, i]
                for i in range(5):
                    yp[m, i] = ypow[j, i]
                m += 1
        for i in range(3):
            b_out[p, i] = b0[p, i]
        rss, moving, iterations = _pixel_alternation(o, w, lt, ht, yp, xs, cs, m, b_out[p], prior, ridge,
                                                     max_iter, tol, c_out[p])
        rss_out[p], moving_out[p], iter_out[p] = rss, moving, iterations


def _pixel_alternation(o, w, lt, ht, yp, xs, cs, m, b, prior, ridge, max_iter, tol, coef):
    """One pixel's alternation; updates b (3,) and coef (9,) in place; returns (rss, moving, iterations)."""
    scale = 1e-300
    for j in range(m):
        scale += w[j] * o[j] * o[j]
    for i in range(9):
        coef[i] = 0.0
    coef[0] = 1.0
    albedo = _geometry(b, lt, ht, xs, cs, m)
    rss = np.nan
    trial = np.empty(9)
    b_new = np.empty(3)
    t, u = np.empty(m), np.empty(m)
    for it in range(max_iter):
        _fit_shape(o, w, yp, xs, cs, m, albedo, prior, ridge, trial, t, u)
        before = _normal_step(o, w, lt, ht, yp, xs, cs, m, b, albedo, trial, b_new)
        albedo_new = _geometry(b_new, lt, ht, xs, cs, m)
        after = _residual(o, w, yp, xs, cs, m, albedo_new, trial)
        better = math.isfinite(after) and after <= before * (1 + 1e-9)
        if better:
            for i in range(3):
                b[i] = b_new[i]
        for i in range(9):
            coef[i] = trial[i]
        rss = after if better else before
        if not (better and abs(before - after) > tol * scale):
            return rss, 0, it + 1
        albedo = albedo_new
    return rss, 1, max_iter


def _geometry(b, lt, ht, xs, cs, m):
    """Fill xs = n . h and cs = n . l for n = b / |b|; return |b|."""
    albedo = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    d = max(albedo, 1e-300)
    n0, n1, n2 = b[0] / d, b[1] / d, b[2] / d
    for j in range(m):
        xs[j] = n0 * ht[j, 0] + n1 * ht[j, 1] + n2 * ht[j, 2]
        cs[j] = n0 * lt[j, 0] + n1 * lt[j, 1] + n2 * lt[j, 2]
    return albedo


def _fit_shape(o, w, yp, xs, cs, m, albedo, prior, ridge, coef, t, u):
    """fit_pixel_shapes for one pixel: moments, ridge toward albedo x prior, 9 x 9 solve.

    t and u (K,) are scratch.
    """
    for j in range(m):
        s = cs[j]
        t[j] = w[j] * s * s
        u[j] = w[j] * o[j] * s
    # Normal-matrix entries are the moments sum_k w s^2 x^a y^c (a, c <= 4), one power of x
    # per pass with the y powers summed side by side (independent additions pipeline well).
    mom = np.empty((5, 5))
    rhs = np.empty(9)
    for a in range(5):
        _power_sums(t, yp, m, mom[a], 5)
        if a < 3:
            _power_sums(u, yp, m, rhs[3 * a:3 * a + 3], 3)
        for j in range(m):
            t[j] *= xs[j]
            u[j] *= xs[j]
    normal = np.empty((9, 9))
    trace = 0.0
    for r in range(9):
        for c in range(9):
            normal[r, c] = mom[r // 3 + c // 3, r % 3 + c % 3]
        trace += normal[r, r]
    diag = ridge * (trace / 9.0 + 1e-300)
    for r in range(9):
        normal[r, r] += diag
        rhs[r] += diag * (albedo * prior[r])
    _cholesky_solve9(normal, rhs, coef)
    d = max(albedo, 1e-300)
    for r in range(9):
        coef[r] /= d


def _power_sums(t, yp, m, out, count):
    """out[c] = sum_k t_k y_k^c for c < count (3 or 5)."""
    s0 = s1 = s2 = s3 = s4 = 0.0
    for j in range(m):
        v = t[j]
        s0 += v
        s1 += v * yp[j, 1]
        s2 += v * yp[j, 2]
        if count > 3:
            s3 += v * yp[j, 3]
            s4 += v * yp[j, 4]
    out[0], out[1], out[2] = s0, s1, s2
    if count > 3:
        out[3], out[4] = s3, s4


def _cholesky_solve9(a, rhs, out):
    """Solve the symmetric positive definite a (9, 9) out = rhs; NaN if not positive definite.

    a is overwritten by its Cholesky factor (lower triangle).
    """
    for j in range(9):
        d = a[j, j]
        for k in range(j):
            d -= a[j, k] * a[j, k]
        if not d > 0.0:
            for i in range(9):
                out[i] = np.nan
            return
        d = math.sqrt(d)
        a[j, j] = d
        for i in range(j + 1, 9):
            v = a[i, j]
            for k in range(j):
                v -= a[i, k] * a[j, k]
            a[i, j] = v / d
    for i in range(9):
        v = rhs[i]
        for k in range(i):
            v -= a[i, k] * out[k]
        out[i] = v / a[i, i]
    for i in range(8, -1, -1):
        v = out[i]
        for k in range(i + 1, 9):
            v -= a[k, i] * out[k]
        out[i] = v / a[i, i]


def _normal_step(o, w, lt, ht, yp, xs, cs, m, b, albedo, coef, b_new):
    """One Gauss-Newton step on b for shape coef (9,); fills b_new (3,); returns the residual before.

    J_k = rho l_k + n.l_k rho'(x) (h_k - x n) is d(model)/d b, rho' = d rho / d x.
    """
    d = max(albedo, 1e-300)
    n0, n1, n2 = b[0] / d, b[1] / d, b[2] / d
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    g0 = g1 = g2 = 0.0
    before = 0.0
    for j in range(m):
        x, cos = xs[j], cs[j]
        q0, q1, q2 = _shape_polynomials(coef, yp[j, 1], yp[j, 2])
        rho = (q2 * x + q1) * x + q0
        res = o[j] - rho * cos * albedo
        before += w[j] * res * res
        c = cos * (q1 + 2.0 * x * q2)
        j0 = rho * lt[j, 0] + c * (ht[j, 0] - x * n0)
        j1 = rho * lt[j, 1] + c * (ht[j, 1] - x * n1)
        j2 = rho * lt[j, 2] + c * (ht[j, 2] - x * n2)
        wj0, wj1, wj2 = w[j] * j0, w[j] * j1, w[j] * j2
        a00 += wj0 * j0
        a01 += wj0 * j1
        a02 += wj0 * j2
        a11 += wj1 * j1
        a12 += wj1 * j2
        a22 += wj2 * j2
        g0 += wj0 * res
        g1 += wj1 * res
        g2 += wj2 * res
    ridge = 1e-12 + 1e-9 * (a00 + a11 + a22)
    a00 += ridge
    a11 += ridge
    a22 += ridge
    d0, d1, d2 = _solve3(a00, a01, a02, a01, a11, a12, a02, a12, a22, g0, g1, g2)
    b_new[0], b_new[1], b_new[2] = b[0] + d0, b[1] + d1, b[2] + d2
    return before


def _shape_polynomials(coef, y, y2):
    """q_a(y) = sum_c C[a, c] y^c for a = 0, 1, 2."""
    return (coef[0] + coef[1] * y + coef[2] * y2, coef[3] + coef[4] * y + coef[5] * y2,
            coef[6] + coef[7] * y + coef[8] * y2)


def _residual(o, w, yp, xs, cs, m, albedo, coef):
    """sum_k w (obs - rho(x, y) n.l albedo)^2 for the current xs, cs."""
    total = 0.0
    for j in range(m):
        x = xs[j]
        q0, q1, q2 = _shape_polynomials(coef, yp[j, 1], yp[j, 2])
        r = o[j] - ((q2 * x + q1) * x + q0) * cs[j] * albedo
        total += w[j] * r * r
    return total


def _solve3(a00, a01, a02, a10, a11, a12, a20, a21, a22, r0, r1, r2):
    """A 3 x 3 solve by cofactors, as :func:`pipeline.photometric.lambert.solve3` (non-finite if singular)."""
    c00, c01, c02 = a11 * a22 - a12 * a21, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11
    c10, c11, c12 = a12 * a20 - a10 * a22, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12
    c20, c21, c22 = a10 * a21 - a11 * a20, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10
    det = a00 * c00 + a01 * c10 + a02 * c20
    return ((c00 * r0 + c01 * r1 + c02 * r2) / det, (c10 * r0 + c11 * r1 + c12 * r2) / det,
            (c20 * r0 + c21 * r1 + c22 * r2) / det)


_PY = {name: globals()[name] for name in ("_alternate_kernel", "_pixel_alternation", "_geometry", "_fit_shape",
                                         "_power_sums", "_cholesky_solve9", "_normal_step", "_shape_polynomials", "_residual",
                                         "_solve3")}
#: The compiled kernels, built on first use (:func:`kernels`)
KERNELS = Compiled("photometric-stereo kernels", _build)
