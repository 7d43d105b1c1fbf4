"""Compiled per-pixel kernels (numba) for biquadratic photometric stereo.

:func:`fit_pixels_jit` does the work of :func:`pipeline.photometric.pixel_fit.fit_pixels_numpy`
(each pixel's normal and 9 coefficients by Levenberg-Marquardt, the same mathematics and
stopping rule), pixel by pixel in one pass over each pixel's used observations per step
instead of many passes over (N, K) arrays. Lights may be shared (K, 3) or per pixel
(N, K, 3). Everything is float64; each pixel's result depends on that pixel alone, so it is the
same whatever chunk it is computed in.

Nothing is compiled at import: the kernels are compiled (or loaded from numba's on-disk cache)
at the first call through :class:`pipeline.jit.Compiled`, under a lock, so concurrent chunk
threads wait for one compilation. The kernels release the GIL (``nogil``), so the chunk
threads of the engine run them on all cores. If numba is missing or compiling fails,
:func:`kernels` warns once and returns None, and callers use numpy (``PSRIG_NO_JIT=1`` selects
numpy too).
"""

import math

import numpy as np

from ..jit import ENV_NO_JIT, Compiled, njit

__all__ = ["jit_enabled", "kernels", "fit_pixels_jit", "select_robust_jit", "compile_seconds", "ENV_NO_JIT",
           "KERNELS"]

_MU0, _MU_MAX = 1e-6, 1e8   # as pipeline.photometric.pixel_fit
_K_IN, _MIN_DET, _SCORED = 2.5, 1e-3, 32  # as pipeline.photometric.selection.consensus_weights


def jit_enabled():
    """True unless ``PSRIG_NO_JIT`` is set (to anything but '' or '0') or compiling failed."""
    return KERNELS.enabled()


def compile_seconds():
    """Seconds the first :func:`kernels` call spent compiling or loading from cache (None before)."""
    return KERNELS.seconds


def kernels():
    """The compiled kernels (a dict of numba dispatchers), or None when they are unavailable."""
    return KERNELS.get()


def _build():
    """Decorate the kernel functions with numba.njit and compile them on a tiny problem."""
    # The kernels call each other through module globals: those must name the dispatchers
    # while numba compiles (and the pure-Python originals are kept for a later rebuild).
    compiled = {name: njit(func) for name, func in _PY.items()}
    globals().update(compiled)
    _warm_up(compiled)
    return compiled


def _warm_up(compiled):
    """Compile for the argument types the entry points always pass (shared and per-pixel lights)."""
    rng = np.random.default_rng(0)
    lights = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 0.866], [0.0, 0.5, 0.866], [-0.5, 0.0, 0.866]])
    h = _unit(lights + np.array([0.0, 0.0, 1.0]))
    obs = rng.random((2, 4)) + 0.5
    for per_pixel in (False, True):
        lt = np.broadcast_to(lights, (2, 4, 3)).copy() if per_pixel else lights
        ht = np.broadcast_to(h, (2, 4, 3)).copy() if per_pixel else h
        fit_pixels_jit(obs, np.ones((2, 4)), np.array([[0.0, 0.0, 1.0]] * 2), lt, ht, np.sum(lt * ht, axis=-1),
                       1e-10 * np.eye(9), 2, 0.01, compiled=compiled)
        select_robust_jit(obs, lt, np.ones((2, 4)), 2.5, 2.5, 1, 3, np.array([[0, 1, 2], [1, 2, 3]]), 0.02,
                          compiled)


# ----------------------------------------------------------------------------- Python entry
def fit_pixels_jit(obs, weights, b, lights, h, y, penalty, max_iter, tol_deg, dof_below=np.inf, compiled=None):
    """The compiled :func:`pipeline.photometric.pixel_fit.fit_pixels_numpy`; None if unavailable.

    Parameters and results are those of :func:`pipeline.photometric.pixel_fit.fit_pixels`,
    ``penalty`` (9, 9) from :func:`pipeline.photometric.pixel_fit.penalty_matrix`; the effective
    parameters are computed only for pixels with fewer than ``dof_below`` observations (11
    elsewhere, their most).
    """
    compiled = compiled or kernels()
    if compiled is None:
        return None
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731 - one fixed signature
    n = len(b)
    y = np.asarray(y, float)
    ypow = np.stack([np.ones_like(y), y, y * y, y * y * y, y * y * y * y], axis=-1)
    b_out, c_out, rss, moving, dof = np.empty((n, 3)), np.empty((n, 9)), np.empty(n), np.empty(n, np.uint8), \
        np.empty(n)
    kernel = compiled["_fit_per_pixel" if np.ndim(lights) == 3 else "_fit_shared"]
    kernel(f64(obs), f64(weights), f64(b), f64(lights), f64(h), f64(ypow), f64(penalty), int(max_iter),
           math.cos(math.radians(tol_deg)), float(min(dof_below, 1e9)), b_out, c_out, rss, moving, dof)
    return b_out, c_out.reshape(n, 3, 3), rss, moving.astype(bool), dof


def select_robust_jit(obs, lights, base, k_high, k_low, iterations, min_obs, triplets, scale_floor, compiled=None):
    """The compiled :func:`pipeline.photometric.selection.select_robust` (its start and its MAD
    rounds for every pixel in one pass); returns (weights (N, K), b (N, 3)), or None when the
    kernels are unavailable."""
    compiled = compiled or kernels()
    if compiled is None:
        return None
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731 - one fixed signature
    weights, b = np.empty(obs.shape), np.empty((len(obs), 3))
    kernel = compiled["_select_per_pixel" if np.ndim(lights) == 3 else "_select_shared"]
    kernel(f64(obs), f64(lights), f64(base), float(k_high), float(k_low), int(iterations), int(min_obs),
           np.ascontiguousarray(triplets, dtype=np.int64), float(scale_floor), weights, b)
    return weights, b


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- kernels
# Written in plain Python over scalars so that numba compiles them; each loops over one
# pixel's K observations a few times per step.

def _fit_shared(obs, weights, b0, lights, h, ypow, penalty, max_iter, cos_tol, dof_below, b_out, c_out, rss_out,
                moving_out, dof_out):
    """Every pixel of obs (N, K) under shared lights (K, 3): compact its used observations, fit."""
    n_pix, k = obs.shape
    o, w, lt, ht, yp = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 5))
    work, mats, a11, vecs = np.empty((4, k)), np.empty((3, 9, 9)), np.empty((11, 11)), np.empty((9, 11))
    for p in range(n_pix):
        m = _compact(obs[p], weights[p], lights, h, ypow, o, w, lt, ht, yp)
        _fit_one(o, w, lt, ht, yp, m, b0[p], penalty, max_iter, cos_tol, dof_below, work, mats, a11, vecs, b_out[p],
                 c_out[p], rss_out, moving_out, dof_out, p)


def _fit_per_pixel(obs, weights, b0, lights, h, ypow, penalty, max_iter, cos_tol, dof_below, b_out, c_out,
                   rss_out, moving_out, dof_out):
    """:func:`_fit_shared` for per-pixel lights (N, K, 3), half vectors and y powers."""
    n_pix, k = obs.shape
    o, w, lt, ht, yp = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 5))
    work, mats, a11, vecs = np.empty((4, k)), np.empty((3, 9, 9)), np.empty((11, 11)), np.empty((9, 11))
    for p in range(n_pix):
        m = _compact(obs[p], weights[p], lights[p], h[p], ypow[p], o, w, lt, ht, yp)
        _fit_one(o, w, lt, ht, yp, m, b0[p], penalty, max_iter, cos_tol, dof_below, work, mats, a11, vecs, b_out[p],
                 c_out[p], rss_out, moving_out, dof_out, p)


def _compact(obs, weights, lights, h, ypow, o, w, lt, ht, yp):
    """Copy one pixel's used observations (weight != 0) to the front of the scratch; their count."""
    m = 0
    for j in range(len(obs)):
        if weights[j] != 0.0:
            o[m], w[m] = obs[j], weights[j]
            for i in range(3):
                lt[m, i], ht[m, i] = lights[j, i], h[j, i]
            for i in range(5):
                yp[m, i] = ypow[j, i]
            m += 1
    return m


def _fit_one(o, w, lt, ht, yp, m, b0, penalty, max_iter, cos_tol, dof_below, work, mats, a11, vecs, b_out, c_out,
             rss_out, moving_out, dof_out, p):
    """One pixel: the linear start for c, then Levenberg-Marquardt steps; writes its results.

    ``work`` (4, K), ``mats`` (3, 9, 9), ``a11`` (11, 11) and ``vecs`` (9, 11) are scratch,
    allocated once per call of the kernel rather than once per pixel.
    """
    norm = math.sqrt(b0[0] * b0[0] + b0[1] * b0[1] + b0[2] * b0[2])
    n, c, rhs = vecs[0, :3], vecs[1, :9], vecs[2, :9]
    for i in range(3):
        n[i] = b0[i] / max(norm, 1e-300)
    xs, cs = work[0], work[1]
    _geometry(n, lt, ht, xs, cs, m)
    data, pen, a9 = mats[0], mats[1], mats[2]
    _coefficient_system(o, w, yp, xs, cs, m, data, rhs)
    scale = 1e-300
    for i in range(9):
        scale += data[i, i] / 9.0
    for i in range(9):
        for j in range(9):
            pen[i, j] = scale * penalty[i, j]
            a9[i, j] = data[i, j] + pen[i, j]
    _cholesky_solve(a9, rhs, c, 9)
    cost = _cost(o, w, yp, xs, cs, m, c, pen)
    moving = 1
    if not math.isfinite(cost):
        moving = 0
    else:
        moving = _iterate(o, w, lt, ht, yp, m, n, c, pen, cost, max_iter, cos_tol, work, a11, vecs)
    rss, albedo = _rss_albedo(o, w, yp, xs, cs, m, c)   # xs, cs: the geometry of the final n
    if m < dof_below:
        _coefficient_system(o, w, yp, xs, cs, m, data, rhs)
        dof_out[p] = 2.0 + _hat_trace(data, pen, a9)
    else:
        dof_out[p] = 11.0
    if not (albedo > 0.0 and math.isfinite(albedo)):
        albedo = 1.0
    for i in range(3):
        b_out[i] = n[i] * albedo
    for i in range(9):
        c_out[i] = c[i] / albedo
    rss_out[p] = rss
    moving_out[p] = moving


def _iterate(o, w, lt, ht, yp, m, n, c, pen, cost, max_iter, cos_tol, work, a, vecs):
    """Levenberg-Marquardt steps on (n, c) in place; returns 1 while the normal still turns.

    On entry and exit work[0], work[1] hold the geometry (n . h, n . l) of the current n.
    """
    e, step = vecs[3], vecs[4]
    n_try, c_try, t1, t2 = vecs[5, :3], vecs[6, :9], vecs[7, :3], vecs[8, :3]
    mu = _MU0
    xs, cs, xt, ct = work[0], work[1], work[2], work[3]
    for it in range(max_iter):
        _tangents(n, t1, t2)
        _step_system(o, w, lt, ht, yp, xs, cs, m, c, t1, t2, pen, a, e)
        for i in range(11):
            a[i, i] += mu * a[i, i] + 1e-300
        _cholesky_solve(a, e, step, 11)
        s0, s1 = step[0], step[1]
        norm = 0.0
        for i in range(3):
            n_try[i] = n[i] + s0 * t1[i] + s1 * t2[i]
            norm += n_try[i] * n_try[i]
        norm = math.sqrt(norm)
        for i in range(3):
            n_try[i] /= norm
        for i in range(9):
            c_try[i] = c[i] + step[2 + i]
        _geometry(n_try, lt, ht, xt, ct, m)
        cost_try = _cost(o, w, yp, xt, ct, m, c_try, pen)
        if math.isfinite(cost_try) and cost_try <= cost:
            turned = n[0] * n_try[0] + n[1] * n_try[1] + n[2] * n_try[2]
            for i in range(3):
                n[i] = n_try[i]
            for i in range(9):
                c[i] = c_try[i]
            for j in range(m):
                xs[j], cs[j] = xt[j], ct[j]
            cost = cost_try
            mu = max(mu / 10.0, 1e-12)
            if turned >= cos_tol:
                return 0
        else:
            mu *= 10.0
            if mu > _MU_MAX:
                return 0
    return 1


def _geometry(n, lt, ht, xs, cs, m):
    """Fill xs = n . h and cs = n . l for the unit normal n."""
    for j in range(m):
        xs[j] = n[0] * ht[j, 0] + n[1] * ht[j, 1] + n[2] * ht[j, 2]
        cs[j] = n[0] * lt[j, 0] + n[1] * lt[j, 1] + n[2] * lt[j, 2]


def _tangents(n, t1, t2):
    """t1, t2: unit vectors orthogonal to n and to each other."""
    ax, ay, az = abs(n[0]), abs(n[1]), abs(n[2])
    e0, e1, e2 = (1.0, 0.0, 0.0) if ax <= ay and ax <= az else ((0.0, 1.0, 0.0) if ay <= az else (0.0, 0.0, 1.0))
    u0, u1, u2 = n[1] * e2 - n[2] * e1, n[2] * e0 - n[0] * e2, n[0] * e1 - n[1] * e0
    norm = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    t1[0], t1[1], t1[2] = u0 / norm, u1 / norm, u2 / norm
    t2[0] = n[1] * t1[2] - n[2] * t1[1]
    t2[1] = n[2] * t1[0] - n[0] * t1[2]
    t2[2] = n[0] * t1[1] - n[1] * t1[0]


def _coefficient_system(o, w, yp, xs, cs, m, data, rhs):
    """data (9, 9) = sum_k w s^2 basis basis^T and rhs (9,) = sum_k w s o basis, basis = x^a y^c."""
    mom = np.zeros((5, 5))
    for i in range(9):
        rhs[i] = 0.0
    for j in range(m):
        x, s = xs[j], cs[j]
        t = w[j] * s * s
        u = w[j] * s * o[j]
        xp = 1.0
        for a in range(5):
            for cc in range(5):
                mom[a, cc] += t * xp * yp[j, cc]
            if a < 3:
                for cc in range(3):
                    rhs[3 * a + cc] += u * xp * yp[j, cc]
            xp *= x
    for r in range(9):
        for q in range(9):
            data[r, q] = mom[r // 3 + q // 3, r % 3 + q % 3]


def _step_system(o, w, lt, ht, yp, xs, cs, m, c, t1, t2, pen, a, e):
    """The Gauss-Newton normal equations a (11, 11), e (11,) at (n, c), the penalty included."""
    mom = np.zeros((5, 5))
    for i in range(11):
        e[i] = 0.0
        for q in range(11):
            a[i, q] = 0.0
    for j in range(m):
        x, s = xs[j], cs[j]
        y1, y2 = yp[j, 1], yp[j, 2]
        q0 = c[0] + c[1] * y1 + c[2] * y2
        q1 = c[3] + c[4] * y1 + c[5] * y2
        q2 = c[6] + c[7] * y1 + c[8] * y2
        rho = q0 + x * (q1 + x * q2)
        slope = q1 + 2.0 * x * q2
        res = o[j] - rho * s
        h1 = t1[0] * ht[j, 0] + t1[1] * ht[j, 1] + t1[2] * ht[j, 2]
        l1 = t1[0] * lt[j, 0] + t1[1] * lt[j, 1] + t1[2] * lt[j, 2]
        h2 = t2[0] * ht[j, 0] + t2[1] * ht[j, 1] + t2[2] * ht[j, 2]
        l2 = t2[0] * lt[j, 0] + t2[1] * lt[j, 1] + t2[2] * lt[j, 2]
        g1 = slope * s * h1 + rho * l1
        g2 = slope * s * h2 + rho * l2
        wj = w[j]
        a[0, 0] += wj * g1 * g1
        a[0, 1] += wj * g1 * g2
        a[1, 1] += wj * g2 * g2
        e[0] += wj * g1 * res
        e[1] += wj * g2 * res
        t = wj * s * s
        u1, u2, ur = wj * g1 * s, wj * g2 * s, wj * res * s
        xp = 1.0
        for aa in range(5):
            for cc in range(5):
                mom[aa, cc] += t * xp * yp[j, cc]
            if aa < 3:
                for cc in range(3):
                    v = xp * yp[j, cc]
                    a[0, 2 + 3 * aa + cc] += u1 * v
                    a[1, 2 + 3 * aa + cc] += u2 * v
                    e[2 + 3 * aa + cc] += ur * v
            xp *= x
    a[1, 0] = a[0, 1]
    for r in range(9):
        a[2 + r, 0] = a[0, 2 + r]
        a[2 + r, 1] = a[1, 2 + r]
        penalty_c = 0.0
        for q in range(9):
            a[2 + r, 2 + q] = mom[r // 3 + q // 3, r % 3 + q % 3] + pen[r, q]
            penalty_c += pen[r, q] * c[q]
        e[2 + r] -= penalty_c


def _rho(c, x, y1, y2):
    """The biquadratic reflectance at x = n.h, y = l.h (y1 = y, y2 = y^2) for coefficients c (9,)."""
    return (c[0] + c[1] * y1 + c[2] * y2) + x * ((c[3] + c[4] * y1 + c[5] * y2) + x * (c[6] + c[7] * y1 + c[8] * y2))


def _cost(o, w, yp, xs, cs, m, c, pen):
    """sum_k w (obs - R s)^2 + c' pen c."""
    total = 0.0
    for j in range(m):
        rho = _rho(c, xs[j], yp[j, 1], yp[j, 2])
        r = o[j] - rho * cs[j]
        total += w[j] * r * r
    for i in range(9):
        for q in range(9):
            total += c[i] * pen[i, q] * c[q]
    return total


def _rss_albedo(o, w, yp, xs, cs, m, c):
    """The data term and the mean of R over the used observations."""
    rss = 0.0
    level = 0.0
    count = 0.0
    for j in range(m):
        rho = _rho(c, xs[j], yp[j, 1], yp[j, 2])
        r = o[j] - rho * cs[j]
        rss += w[j] * r * r
        level += w[j] * rho
        count += w[j]
    return rss, level / max(count, 1e-300)


def _hat_trace(data, pen, a):
    """trace((data + pen)^-1 data): the coefficients' effective number of parameters (a (9, 9)
    is scratch)."""
    col = np.empty(9)
    out = np.empty(9)
    total = 0.0
    for q in range(9):
        for i in range(9):
            col[i] = data[i, q]
        for i in range(9):
            for r in range(9):
                a[i, r] = data[i, r] + pen[i, r]
        _cholesky_solve(a, col, out, 9)
        total += out[q]
    return total


def _cholesky_solve(a, rhs, out, size):
    """Solve the symmetric positive definite a (size, size) out = rhs; NaN if not positive definite.

    a is overwritten by its Cholesky factor (lower triangle).
    """
    for j in range(size):
        d = a[j, j]
        for k in range(j):
            d -= a[j, k] * a[j, k]
        if not d > 0.0:
            for i in range(size):
                out[i] = np.nan
            return
        d = math.sqrt(d)
        a[j, j] = d
        for i in range(j + 1, size):
            v = a[i, j]
            for k in range(j):
                v -= a[i, k] * a[j, k]
            a[i, j] = v / d
    for i in range(size):
        v = rhs[i]
        for k in range(i):
            v -= a[i, k] * out[k]
        out[i] = v / a[i, i]
    for i in range(size - 1, -1, -1):
        v = out[i]
        for k in range(i + 1, size):
            v -= a[k, i] * out[k]
        out[i] = v / a[i, i]


# ----------------------------------------------------------------------------- selection kernels
def _select_shared(obs, lights, base, k_high, k_low, iterations, min_obs, triplets, floor, w_out, b_out):
    """:func:`_select_one` for every pixel under shared lights (K, 3)."""
    n_pix, k = obs.shape
    scratch, sort32, packed = np.empty(k), np.empty(k, np.float32), np.empty((4, k))
    for p in range(n_pix):
        _select_one(obs[p], lights, base[p], k_high, k_low, iterations, min_obs, triplets, floor, w_out[p], b_out[p],
                    scratch, sort32, packed)


def _select_per_pixel(obs, lights, base, k_high, k_low, iterations, min_obs, triplets, floor, w_out, b_out):
    """:func:`_select_one` for every pixel under per-pixel lights (N, K, 3)."""
    n_pix, k = obs.shape
    scratch, sort32, packed = np.empty(k), np.empty(k, np.float32), np.empty((4, k))
    for p in range(n_pix):
        _select_one(obs[p], lights[p], base[p], k_high, k_low, iterations, min_obs, triplets, floor, w_out[p],
                    b_out[p], scratch, sort32, packed)


def _select_one(o, lt, lit, k_high, k_low, iterations, min_obs, triplets, floor, w, b, scratch, sort32, packed):
    """One pixel's consensus start and MAD rounds (see pipeline.photometric.selection)."""
    k = len(o)
    m = 0
    for j in range(k):
        w[j] = lit[j]
        if lit[j] > 0.0:
            m += 1
    b0, b1, b2, best, scored = _consensus(o, lt, lit, m, triplets, scratch, packed)
    if math.isfinite(best):
        scale = max(1.4826 * (1.0 + 5.0 / max(scored - 3, 1)) * math.sqrt(best),
                    floor * math.sqrt(b0 * b0 + b1 * b1 + b2 * b2))
        kept = 0
        for j in range(k):
            inside = lit[j] > 0.0 and abs(o[j] - (b0 * lt[j, 0] + b1 * lt[j, 1] + b2 * lt[j, 2])) <= _K_IN * scale
            w[j] = 1.0 if inside else 0.0
            kept += inside
        if kept < 3:
            for j in range(k):
                w[j] = lit[j]
    _lambert(o, lt, w, b)
    for _ in range(iterations):
        c = 0
        for j in range(k):
            scratch[j] = o[j] - (b[0] * lt[j, 0] + b[1] * lt[j, 1] + b[2] * lt[j, 2])
            if w[j] > 0.0:
                sort32[c] = np.float32(abs(scratch[j]))
                c += 1
        scale = 1.4826 * np.float64(_kth_smallest(sort32, c, c // 2)) + 1e-9 if c > 0 else 1e-9
        scale = max(scale, floor * math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]))
        kept = 0
        for j in range(k):
            if lit[j] > 0.0 and scratch[j] < k_high * scale and scratch[j] > -k_low * scale:
                kept += 1
        for j in range(k):
            if kept >= min_obs:
                w[j] = 1.0 if (lit[j] > 0.0 and scratch[j] < k_high * scale and scratch[j] > -k_low * scale) else 0.0
            else:
                w[j] = lit[j]
        _lambert(o, lt, w, b)


def _consensus(o, lt, lit, m, triplets, scratch, packed):
    """The least-median-of-squares triplet: its b and median squared residual (inf if none)."""
    k = len(o)
    # the lit observations, contiguous: every triplet's residuals are a branch-free pass
    # (at most _SCORED of them, evenly spread: the median of a spread subset ranks triplets as well)
    oc, l0, l1, l2 = packed[0], packed[1], packed[2], packed[3]
    scored = min(m, _SCORED)
    c = 0
    rank = 0
    for j in range(k):
        if lit[j] > 0.0:
            if c < scored and rank == (c * m) // scored:
                oc[c], l0[c], l1[c], l2[c] = o[j], lt[j, 0], lt[j, 1], lt[j, 2]
                c += 1
            rank += 1
    m = scored
    half = m // 2
    best = np.inf
    b0 = b1 = b2 = 0.0
    for t in range(len(triplets)):
        i0, i1, i2 = triplets[t, 0], triplets[t, 1], triplets[t, 2]
        if not (lit[i0] > 0.0 and lit[i1] > 0.0 and lit[i2] > 0.0):
            continue
        det = (lt[i0, 0] * (lt[i1, 1] * lt[i2, 2] - lt[i1, 2] * lt[i2, 1])
               - lt[i0, 1] * (lt[i1, 0] * lt[i2, 2] - lt[i1, 2] * lt[i2, 0])
               + lt[i0, 2] * (lt[i1, 0] * lt[i2, 1] - lt[i1, 1] * lt[i2, 0]))
        if not abs(det) > _MIN_DET:
            continue
        x0, x1, x2 = _solve3(lt[i0, 0], lt[i0, 1], lt[i0, 2], lt[i1, 0], lt[i1, 1], lt[i1, 2],
                             lt[i2, 0], lt[i2, 1], lt[i2, 2], o[i0], o[i1], o[i2])
        if not (math.isfinite(x0) and math.isfinite(x1) and math.isfinite(x2) and x2 > 0.0):
            continue
        below = 0
        for j in range(m):
            r = oc[j] - (x0 * l0[j] + x1 * l1[j] + x2 * l2[j])
            r = r * r
            scratch[j] = r
            below += r < best
        if below <= half:     # the median cannot be below the best: no selection needed
            continue
        med = _kth_smallest(scratch, m, half)
        if med < best:
            best, b0, b1, b2 = med, x0, x1, x2
    return b0, b1, b2, best, m


def _lambert(o, lt, w, b):
    """b = the weighted Lambertian least squares (as pipeline.photometric.lambert.lambert_weighted)."""
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    r0 = r1 = r2 = 0.0
    for j in range(len(o)):
        if w[j] != 0.0:
            l0, l1, l2 = lt[j, 0], lt[j, 1], lt[j, 2]
            wj = w[j]
            a00 += wj * l0 * l0
            a01 += wj * l0 * l1
            a02 += wj * l0 * l2
            a11 += wj * l1 * l1
            a12 += wj * l1 * l2
            a22 += wj * l2 * l2
            r0 += wj * o[j] * l0
            r1 += wj * o[j] * l1
            r2 += wj * o[j] * l2
    ridge = 1e-12 + 1e-9 * (a00 + a11 + a22)
    b[0], b[1], b[2] = _solve3(a00 + ridge, a01, a02, a01, a11 + ridge, a12, a02, a12, a22 + ridge, r0, r1, r2)


def _solve3(a00, a01, a02, a10, a11, a12, a20, a21, a22, r0, r1, r2):
    """A 3 x 3 solve by cofactors, as :func:`pipeline.photometric.lambert.solve3` (non-finite if singular)."""
    c00, c01, c02 = a11 * a22 - a12 * a21, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11
    c10, c11, c12 = a12 * a20 - a10 * a22, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12
    c20, c21, c22 = a10 * a21 - a11 * a20, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10
    det = a00 * c00 + a01 * c10 + a02 * c20
    return ((c00 * r0 + c01 * r1 + c02 * r2) / det, (c10 * r0 + c11 * r1 + c12 * r2) / det,
            (c20 * r0 + c21 * r1 + c22 * r2) / det)


def _kth_smallest(a, n, kth):
    """The kth smallest of a[:n] (a is reordered): Hoare's selection."""
    lo, hi = 0, n - 1
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if kth <= j:
            hi = j
        elif kth >= i:
            lo = i
        else:
            break
    return a[kth]


_PY = {name: globals()[name] for name in ("_fit_shared", "_fit_per_pixel", "_compact", "_fit_one", "_iterate", "_geometry",
                                         "_tangents", "_coefficient_system", "_step_system", "_rho", "_cost", "_rss_albedo",
                                         "_hat_trace", "_cholesky_solve", "_select_shared", "_select_per_pixel",
                                         "_select_one", "_consensus", "_lambert", "_solve3", "_kth_smallest")}
#: The compiled kernels, built on first use (:func:`kernels`)
KERNELS = Compiled("photometric-stereo kernels", _build)
