"""Compiled per-pixel kernels (numba) for biquadratic photometric stereo.

:func:`fit_pixels_jit` does the work of :func:`pipeline.photometric.pixel_fit.fit_pixels_numpy`
(each pixel's normal and 9 coefficients by Levenberg-Marquardt, the same mathematics and
stopping rule), pixel by pixel: a pixel's used observations are copied into one row per
quantity, and each sum over them (the 25 moments, the basis sums, the cost) is one loop with
scalar accumulators, which the compiler vectorises (:data:`pipeline.core.jit.VECTORISE`; the
speed-ups are in docs/photometric-stereo.md, "Speed").
Lights may be shared (K, 3) or per pixel (N, K, 3). Everything is float64; each pixel's result
depends on that pixel alone, so it is the same whatever chunk it is computed in.

The three families (the fit, the selection, the shared shape's terms) share their helpers and
stay in this one file on purpose: numba's on-disk cache checks only the file a function is
defined in, so a kernel calling a helper from another file would load stale compiled code
after that file changed.

Nothing is compiled at import: the kernels are compiled (or loaded from numba's on-disk cache)
at the first call through :class:`pipeline.core.jit.Compiled`, under a lock, so concurrent chunk
threads wait for one compilation. The kernels release the GIL (``nogil``), so the chunk
threads of the engine run them on all cores. If numba is missing or compiling fails,
:func:`kernels` warns once and returns None, and callers use numpy (``PSRIG_NO_JIT=1`` selects
numpy too).
"""

import math

import numpy as np

from ..core.jit import ENV_NO_JIT, VECTORISE, Compiled, njit

__all__ = ["jit_enabled", "kernels", "fit_pixels_jit", "select_robust_jit", "shape_terms_jit", "compile_seconds",
           "ENV_NO_JIT", "KERNELS"]

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
    compiled = {name: njit(func, fastmath=VECTORISE) for name, func in _PY.items()}
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
        for blocks in (False, True):
            shape_terms_jit(obs, np.ones((2, 4)), np.array([[0.0, 0.0, 1.0]] * 2), np.eye(3), lt, ht,
                            np.sum(lt * ht, axis=-1), blocks, compiled)


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
    ypow = _y_powers(y)
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


def shape_terms_jit(obs, weights, b, coeffs, lights, h, y, blocks=True, compiled=None, executor=None, parts=1):
    """The per-pixel terms of :func:`pipeline.photometric.shared_shape.fit_shared_shape`'s
    Levenberg-Marquardt step at (b (N, 3), coeffs (3, 3)), compiled; None when unavailable.

    ``y`` (K,) or (N, K) is l . h. Returns a dict of per-pixel arrays: ``cost`` (N,) the
    weighted residual sums of squares and, with ``blocks``, ``u`` (N, 3, 3) = J_b' W J_b,
    ``cross`` (N, 3, 9) = J_b' W J_c, ``moments`` (N, 25) (the 9 x 9 J_c' W J_c from them),
    ``e_b`` (N, 3), ``e_c`` (N, 9) and ``basis`` (N, 9) = sum_k w x^a y^c. With an ``executor``
    the rows are split into ``parts`` run on its threads (the kernel releases the GIL).
    """
    compiled = compiled or kernels()
    if compiled is None:
        return None
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731 - one fixed signature
    n = len(b)
    size = n if blocks else 0
    out = {"cost": np.empty(n), "u": np.empty((size, 3, 3)), "cross": np.empty((size, 3, 9)),
           "moments": np.empty((size, 25)), "e_b": np.empty((size, 3)), "e_c": np.empty((size, 9)),
           "basis": np.empty((size, 9))}
    per_pixel = np.ndim(lights) == 3
    kernel = compiled["_shape_per_pixel" if per_pixel else "_shape_shared"]
    obs, weights, b, coeffs, lights, h, ypow = (f64(a) for a in (obs, weights, b, coeffs, lights, h, _y_powers(y)))

    def run(lo, hi):
        rows = (lambda a: a[lo:hi]) if per_pixel else (lambda a: a)
        span = (lambda a: a[lo:hi]) if blocks else (lambda a: a)
        kernel(obs[lo:hi], weights[lo:hi], b[lo:hi], coeffs.reshape(9), rows(lights), rows(h), rows(ypow),
               bool(blocks), out["cost"][lo:hi], *(span(out[key]) for key in ("u", "cross", "moments", "e_b", "e_c",
                                                                              "basis")))

    bounds = np.linspace(0, n, max(1, min(parts, n // 64)) + 1).astype(int)
    if executor is None or len(bounds) <= 2:
        run(0, n)
    else:
        for future in [executor.submit(run, lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:])]:
            future.result()
    return out if blocks else {"cost": out["cost"]}


def _y_powers(y):
    """y^0..y^4 (..., 5) of y (K,) or (N, K)."""
    y = np.asarray(y, float)
    return np.stack([np.ones_like(y), y, y * y, y * y * y, y * y * y * y], axis=-1)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- kernels
# Written in plain Python over scalars so that numba compiles them; each loops over one
# pixel's K observations a few times per step.

def _scratch(k):
    """Per-call scratch of the fit kernels (allocated once per call, not once per pixel).

    ``soa`` (12, K) holds a pixel's used observations, one quantity per row so that the passes
    over them vectorise: obs, weight, l (3 rows), h (3 rows), y^1..y^4. ``work`` (7, K) holds
    per-observation terms: x, s at the current and the trial normal, then three weighted terms.
    ``vecs`` (11, 9) holds the small vectors (its rows: see :func:`_fit_one` and :func:`_iterate`).
    """
    return np.empty((12, k)), np.empty((7, k)), np.empty((3, 9, 9)), np.empty((11, 9)), np.empty(25), \
        np.empty((2, 9))


def _fit_shared(obs, weights, b0, lights, h, ypow, penalty, max_iter, cos_tol, dof_below, b_out, c_out, rss_out,
                moving_out, dof_out):
    """Every pixel of obs (N, K) under shared lights (K, 3): compact its used observations, fit."""
    n_pix, k = obs.shape
    soa, work, mats, vecs, mom, cols = _scratch(k)
    for p in range(n_pix):
        m = _compact(obs[p], weights[p], lights, h, ypow, soa)
        _fit_one(soa, m, b0[p], penalty, max_iter, cos_tol, dof_below, work, mats, vecs, mom, cols, b_out[p],
                 c_out[p], rss_out, moving_out, dof_out, p)


def _fit_per_pixel(obs, weights, b0, lights, h, ypow, penalty, max_iter, cos_tol, dof_below, b_out, c_out,
                   rss_out, moving_out, dof_out):
    """:func:`_fit_shared` for per-pixel lights (N, K, 3), half vectors and y powers."""
    n_pix, k = obs.shape
    soa, work, mats, vecs, mom, cols = _scratch(k)
    for p in range(n_pix):
        m = _compact(obs[p], weights[p], lights[p], h[p], ypow[p], soa)
        _fit_one(soa, m, b0[p], penalty, max_iter, cos_tol, dof_below, work, mats, vecs, mom, cols, b_out[p],
                 c_out[p], rss_out, moving_out, dof_out, p)


def _compact(obs, weights, lights, h, ypow, soa):
    """Copy one pixel's used observations (weight != 0) into the rows of ``soa``; their count."""
    m = 0
    for j in range(len(obs)):
        if weights[j] != 0.0:
            soa[0, m], soa[1, m] = obs[j], weights[j]
            for i in range(3):
                soa[2 + i, m], soa[5 + i, m] = lights[j, i], h[j, i]
            for i in range(4):
                soa[8 + i, m] = ypow[j, 1 + i]
            m += 1
    return m


def _fit_one(soa, m, b0, penalty, max_iter, cos_tol, dof_below, work, mats, vecs, mom, cols, b_out, c_out,
             rss_out, moving_out, dof_out, p):
    """One pixel: the linear start for c, then Levenberg-Marquardt steps; writes its results."""
    norm = math.sqrt(b0[0] * b0[0] + b0[1] * b0[1] + b0[2] * b0[2])
    n, c, rhs = vecs[0, :3], vecs[1], vecs[2]
    for i in range(3):
        n[i] = b0[i] / max(norm, 1e-300)
    xs, cs = work[0], work[1]
    _geometry(n, soa, xs, cs, m)
    data, pen, a9 = mats[0], mats[1], mats[2]
    _coefficient_system(soa, xs, cs, m, work, mom, data, rhs)
    scale = 1e-300
    for i in range(9):
        scale += data[i, i] / 9.0
    for i in range(9):
        for j in range(9):
            pen[i, j] = scale * penalty[i, j]
            a9[i, j] = data[i, j] + pen[i, j]
    _cholesky_solve(a9, rhs, c, 9)
    cost = _cost(soa, xs, cs, m, c, pen)
    moving = 1
    if not math.isfinite(cost):
        moving = 0
    else:
        moving = _iterate(soa, m, n, c, pen, cost, max_iter, cos_tol, work, mom, a9, data, vecs)
    rss, albedo = _rss_albedo(soa, xs, cs, m, c)   # xs, cs: the geometry of the final n
    if m < dof_below:
        _coefficient_system(soa, xs, cs, m, work, mom, data, rhs)
        dof_out[p] = 2.0 + _hat_trace(data, pen, a9, cols)
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


def _iterate(soa, m, n, c, pen, cost, max_iter, cos_tol, work, mom, factor, spare, vecs):
    """Levenberg-Marquardt steps on the normal, c eliminated (variable projection); in place.

    c is linear: at every iterate it is the best c for n, so the step is the damped Gauss-Newton
    step of the reduced problem in the normal's two tangent angles (the joint system's Schur
    complement on the normal), the trial takes the best c for the trial normal, and the damping
    follows the gain ratio (Nielsen's rule). ``factor`` holds the Cholesky factor of
    data + pen at n on entry (``spare`` (9, 9) is scratch); work[0], work[1] hold the geometry
    (n . h, n . l) of the current n on entry and exit. Returns 0 once the undamped step would
    turn the normal by less than the tolerance (or the damping runs out), 1 if it still would
    after ``max_iter`` steps.
    See :func:`pipeline.photometric.pixel_fit.fit_pixels_numpy`, which does the same in numpy.
    """
    rhs, n_try, c_try, t1, t2 = vecs[2], vecs[3, :3], vecs[4], vecs[5, :3], vecs[6, :3]
    row1, row2, z1, z2 = vecs[7], vecs[8], vecs[9], vecs[10]
    mu = _MU0
    nu = 2.0
    tan2_tol = 1.0 / (cos_tol * cos_tol) - 1.0
    xs, cs, xt, ct = work[0], work[1], work[2], work[3]
    for it in range(max_iter):
        _tangents(n, t1, t2)
        a00, a01, a11, g0, g1 = _normal_terms(soa, xs, cs, m, c, t1, t2, work, row1, row2)
        # the Schur complement on the normal: S = A_nn - A_nc (data + pen)^-1 A_cn (the gradient
        # in c is zero at the best c)
        _cholesky_substitute(factor, row1, z1, 9)
        _cholesky_substitute(factor, row2, z2, 9)
        for i in range(9):
            a00 -= row1[i] * z1[i]
            a01 -= row1[i] * z2[i]
            a11 -= row2[i] * z2[i]
        # converged when the undamped (Gauss-Newton) step would turn the normal by less than the
        # tolerance: the step to the reduced problem's minimum, whatever the damping; not tried
        det0 = a00 * a11 - a01 * a01
        if det0 > 0.0:
            e0, e1 = (a11 * g0 - a01 * g1) / det0, (a00 * g1 - a01 * g0) / det0
            if e0 * e0 + e1 * e1 <= tan2_tol:
                return 0
        d0, d1 = mu * a00 + 1e-300, mu * a11 + 1e-300
        det = (a00 + d0) * (a11 + d1) - a01 * a01
        s0 = ((a11 + d1) * g0 - a01 * g1) / det
        s1 = ((a00 + d0) * g1 - a01 * g0) / det
        predicted = s0 * (g0 + d0 * s0) + s1 * (g1 + d1 * s1)
        norm = 0.0
        for i in range(3):
            n_try[i] = n[i] + s0 * t1[i] + s1 * t2[i]
            norm += n_try[i] * n_try[i]
        norm = math.sqrt(norm)
        for i in range(3):
            n_try[i] /= norm
        _geometry(n_try, soa, xt, ct, m)
        _coefficient_system(soa, xt, ct, m, work, mom, spare, rhs)
        for i in range(9):
            for q in range(9):
                spare[i, q] += pen[i, q]
        cost_try = np.nan
        if det > 0.0 and _cholesky_factor(spare, 9):
            _cholesky_substitute(spare, rhs, c_try, 9)
            cost_try = _cost(soa, xt, ct, m, c_try, pen)
        if math.isfinite(cost_try) and cost_try <= cost:
            for i in range(3):
                n[i] = n_try[i]
            for i in range(9):
                c[i] = c_try[i]
            for j in range(m):
                xs[j], cs[j] = xt[j], ct[j]
            factor, spare = spare, factor
            gain = (cost - cost_try) / max(predicted, 1e-300)
            cost = cost_try
            mu = max(mu * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 1e-12)
            nu = 2.0
        else:
            mu *= nu
            nu *= 2.0
            if mu > _MU_MAX:
                return 0
    return 1


def _geometry(n, soa, xs, cs, m):
    """Fill xs = n . h and cs = n . l for the unit normal n."""
    n0, n1, n2 = n[0], n[1], n[2]
    for j in range(m):
        xs[j] = n0 * soa[5, j] + n1 * soa[6, j] + n2 * soa[7, j]
        cs[j] = n0 * soa[2, j] + n1 * soa[3, j] + n2 * soa[4, j]


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


def _moments(t, xs, soa, m, mom):
    """mom[5 a + c] = sum_j t_j x_j^a y_j^c, a, c = 0..4: the 25 moments behind every 9 x 9 block.

    Written out: 25 scalar accumulators stay in registers and the loop vectorises, where an
    array of accumulators is stored and reloaded for every observation.
    """
    m00 = m01 = m02 = m03 = m04 = m10 = m11 = m12 = m13 = m14 = m20 = m21 = m22 = m23 = m24 = 0.0
    m30 = m31 = m32 = m33 = m34 = m40 = m41 = m42 = m43 = m44 = 0.0
    for j in range(m):
        y1, y2, y3, y4 = soa[8, j], soa[9, j], soa[10, j], soa[11, j]
        x = xs[j]
        p0 = t[j]
        p1 = p0 * x
        p2 = p1 * x
        p3 = p2 * x
        p4 = p3 * x
        m00 += p0
        m01 += p0 * y1
        m02 += p0 * y2
        m03 += p0 * y3
        m04 += p0 * y4
        m10 += p1
        m11 += p1 * y1
        m12 += p1 * y2
        m13 += p1 * y3
        m14 += p1 * y4
        m20 += p2
        m21 += p2 * y1
        m22 += p2 * y2
        m23 += p2 * y3
        m24 += p2 * y4
        m30 += p3
        m31 += p3 * y1
        m32 += p3 * y2
        m33 += p3 * y3
        m34 += p3 * y4
        m40 += p4
        m41 += p4 * y1
        m42 += p4 * y2
        m43 += p4 * y3
        m44 += p4 * y4
    mom[0], mom[1], mom[2], mom[3], mom[4] = m00, m01, m02, m03, m04
    mom[5], mom[6], mom[7], mom[8], mom[9] = m10, m11, m12, m13, m14
    mom[10], mom[11], mom[12], mom[13], mom[14] = m20, m21, m22, m23, m24
    mom[15], mom[16], mom[17], mom[18], mom[19] = m30, m31, m32, m33, m34
    mom[20], mom[21], mom[22], mom[23], mom[24] = m40, m41, m42, m43, m44


def _basis_sums(u, xs, soa, m, out):
    """out[3 a + c] = sum_j u_j x_j^a y_j^c, a, c = 0..2 (the biquadratic's 9 basis functions)."""
    s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
    for j in range(m):
        y1, y2 = soa[8, j], soa[9, j]
        p0 = u[j]
        p1 = p0 * xs[j]
        p2 = p1 * xs[j]
        s00 += p0
        s01 += p0 * y1
        s02 += p0 * y2
        s10 += p1
        s11 += p1 * y1
        s12 += p1 * y2
        s20 += p2
        s21 += p2 * y1
        s22 += p2 * y2
    out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7], out[8] = s00, s01, s02, s10, s11, s12, s20, s21, s22


def _coefficient_system(soa, xs, cs, m, work, mom, data, rhs):
    """data (9, 9) = sum_k w s^2 basis basis^T and rhs (9,) = sum_k w s o basis, basis = x^a y^c."""
    t, u = work[4], work[5]
    for j in range(m):
        ws = soa[1, j] * cs[j]
        t[j] = ws * cs[j]
        u[j] = ws * soa[0, j]
    _moments(t, xs, soa, m, mom)
    for r in range(9):
        for q in range(9):
            data[r, q] = mom[5 * (r // 3 + q // 3) + r % 3 + q % 3]
    _basis_sums(u, xs, soa, m, rhs)


def _normal_terms(soa, xs, cs, m, c, t1, t2, work, row1, row2):
    """The Gauss-Newton terms of the normal's tangent angles at (n, c): returns A_nn (a00, a01,
    a11) and the gradient (g0, g1); row1, row2 (9,) := A_nc, their coupling to c."""
    u1, u2 = work[5], work[6]
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8]
    a00 = a01 = a11 = e0 = e1 = 0.0
    for j in range(m):
        x, s, wj = xs[j], cs[j], soa[1, j]
        y1, y2 = soa[8, j], soa[9, j]
        q1 = c3 + c4 * y1 + c5 * y2
        q2 = c6 + c7 * y1 + c8 * y2
        rho = (c0 + c1 * y1 + c2 * y2) + x * (q1 + x * q2)
        slope = q1 + 2.0 * x * q2
        res = soa[0, j] - rho * s
        h1 = t1[0] * soa[5, j] + t1[1] * soa[6, j] + t1[2] * soa[7, j]
        l1 = t1[0] * soa[2, j] + t1[1] * soa[3, j] + t1[2] * soa[4, j]
        h2 = t2[0] * soa[5, j] + t2[1] * soa[6, j] + t2[2] * soa[7, j]
        l2 = t2[0] * soa[2, j] + t2[1] * soa[3, j] + t2[2] * soa[4, j]
        g1 = slope * s * h1 + rho * l1
        g2 = slope * s * h2 + rho * l2
        wg1, wg2 = wj * g1, wj * g2
        a00 += wg1 * g1
        a01 += wg1 * g2
        a11 += wg2 * g2
        e0 += wg1 * res
        e1 += wg2 * res
        u1[j] = wg1 * s
        u2[j] = wg2 * s
    _basis_sums(u1, xs, soa, m, row1)
    _basis_sums(u2, xs, soa, m, row2)
    return a00, a01, a11, e0, e1


def _penalty_value(c, pen):
    total = 0.0
    for i in range(9):
        for q in range(9):
            total += c[i] * pen[i, q] * c[q]
    return total


def _cost(soa, xs, cs, m, c, pen):
    """sum_k w (obs - R s)^2 + c' pen c."""
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8]
    total = 0.0
    for j in range(m):
        x, y1, y2 = xs[j], soa[8, j], soa[9, j]
        rho = (c0 + c1 * y1 + c2 * y2) + x * ((c3 + c4 * y1 + c5 * y2) + x * (c6 + c7 * y1 + c8 * y2))
        r = soa[0, j] - rho * cs[j]
        total += soa[1, j] * r * r
    return total + _penalty_value(c, pen)


def _rss_albedo(soa, xs, cs, m, c):
    """The data term and the mean of R over the used observations."""
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8]
    rss = 0.0
    level = 0.0
    count = 0.0
    for j in range(m):
        x, y1, y2, wj = xs[j], soa[8, j], soa[9, j], soa[1, j]
        rho = (c0 + c1 * y1 + c2 * y2) + x * ((c3 + c4 * y1 + c5 * y2) + x * (c6 + c7 * y1 + c8 * y2))
        r = soa[0, j] - rho * cs[j]
        rss += wj * r * r
        level += wj * rho
        count += wj
    return rss, level / max(count, 1e-300)


def _hat_trace(data, pen, a, cols):
    """trace((data + pen)^-1 data): the coefficients' effective number of parameters (a (9, 9)
    and cols (2, 9) are scratch); data + pen is factored once."""
    for i in range(9):
        for r in range(9):
            a[i, r] = data[i, r] + pen[i, r]
    if not _cholesky_factor(a, 9):
        return np.nan
    col, out = cols[0], cols[1]
    total = 0.0
    for q in range(9):
        for i in range(9):
            col[i] = data[i, q]
        _cholesky_substitute(a, col, out, 9)
        total += out[q]
    return total


def _cholesky_solve(a, rhs, out, size):
    """Solve the symmetric positive definite a (size, size) out = rhs; NaN if not positive definite.

    a is overwritten by its Cholesky factor (see :func:`_cholesky_factor`).
    """
    if _cholesky_factor(a, size):
        _cholesky_substitute(a, rhs, out, size)
    else:
        for i in range(size):
            out[i] = np.nan


def _cholesky_factor(a, size):
    """a's lower triangle := its Cholesky factor L, with 1 / L_jj on the diagonal (the solves
    then multiply: a division per column, not per entry); False if a is not positive definite."""
    for j in range(size):
        d = a[j, j]
        for k in range(j):
            d -= a[j, k] * a[j, k]
        if not d > 0.0:
            return False
        inverse = 1.0 / math.sqrt(d)
        a[j, j] = inverse
        for i in range(j + 1, size):
            v = a[i, j]
            for k in range(j):
                v -= a[i, k] * a[j, k]
            a[i, j] = v * inverse
    return True


def _cholesky_substitute(a, rhs, out, size):
    """out = (L L')^-1 rhs for the factor of :func:`_cholesky_factor` in a."""
    for i in range(size):
        v = rhs[i]
        for k in range(i):
            v -= a[i, k] * out[k]
        out[i] = v * a[i, i]
    for i in range(size - 1, -1, -1):
        v = out[i]
        for k in range(i + 1, size):
            v -= a[k, i] * out[k]
        out[i] = v * a[i, i]


# ----------------------------------------------------------------------------- shared-shape kernels
def _shape_shared(obs, weights, b, coeffs, lights, h, ypow, blocks, cost, u, cross, moments, e_b, e_c, basis):
    """:func:`_shape_one` for every pixel under shared lights (K, 3)."""
    n_pix, k = obs.shape
    soa, work = np.empty((12, k)), np.empty((7, k))
    for p in range(n_pix):
        m = _compact(obs[p], weights[p], lights, h, ypow, soa)
        _shape_one(soa, m, b[p], coeffs, blocks, work, cost, u, cross, moments, e_b, e_c, basis, p)


def _shape_per_pixel(obs, weights, b, coeffs, lights, h, ypow, blocks, cost, u, cross, moments, e_b, e_c, basis):
    """:func:`_shape_one` for every pixel under per-pixel lights (N, K, 3)."""
    n_pix, k = obs.shape
    soa, work = np.empty((12, k)), np.empty((7, k))
    for p in range(n_pix):
        m = _compact(obs[p], weights[p], lights[p], h[p], ypow[p], soa)
        _shape_one(soa, m, b[p], coeffs, blocks, work, cost, u, cross, moments, e_b, e_c, basis, p)


def _shape_one(soa, m, b, coeffs, blocks, work, cost, u, cross, moments, e_b, e_c, basis, p):
    """One pixel's terms (see :func:`shape_terms_jit`): model albedo rho(x, y) s, b = albedo n,
    J_b = rho l + s rho' (h - x n), J_c = albedo s x^a y^c."""
    albedo = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    n0, n1, n2 = b[0] / max(albedo, 1e-300), b[1] / max(albedo, 1e-300), b[2] / max(albedo, 1e-300)
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = (coeffs[0], coeffs[1], coeffs[2], coeffs[3], coeffs[4], coeffs[5],
                                          coeffs[6], coeffs[7], coeffs[8])
    if not blocks:   # the cost alone (an LM trial's test): one pass without the Jacobian's terms
        cost[p] = _shape_cost(soa, m, n0, n1, n2, albedo, c0, c1, c2, c3, c4, c5, c6, c7, c8)
        return
    xs, t, v0, v1, v2, vr, wv = work[0], work[1], work[2], work[3], work[4], work[5], work[6]
    u00 = u01 = u02 = u11 = u12 = u22 = g0 = g1 = g2 = total = 0.0
    for j in range(m):
        x, s, q1, q2, rho, r = _shape_residual(soa, j, n0, n1, n2, albedo, c0, c1, c2, c3, c4, c5, c6, c7, c8)
        wj = soa[1, j]
        total += wj * r * r
        d = s * (q1 + 2.0 * x * q2)
        j0 = rho * soa[2, j] + d * (soa[5, j] - x * n0)
        j1 = rho * soa[3, j] + d * (soa[6, j] - x * n1)
        j2 = rho * soa[4, j] + d * (soa[7, j] - x * n2)
        w0, w1, w2 = wj * j0, wj * j1, wj * j2
        u00 += w0 * j0
        u01 += w0 * j1
        u02 += w0 * j2
        u11 += w1 * j1
        u12 += w1 * j2
        u22 += w2 * j2
        g0 += w0 * r
        g1 += w1 * r
        g2 += w2 * r
        xs[j], t[j], wv[j] = x, wj * s * s, wj
        v0[j], v1[j], v2[j], vr[j] = w0 * s, w1 * s, w2 * s, wj * r * s
    cost[p] = total
    u[p, 0, 0], u[p, 0, 1], u[p, 0, 2] = u00, u01, u02
    u[p, 1, 0], u[p, 1, 1], u[p, 1, 2] = u01, u11, u12
    u[p, 2, 0], u[p, 2, 1], u[p, 2, 2] = u02, u12, u22
    e_b[p, 0], e_b[p, 1], e_b[p, 2] = g0, g1, g2
    _moments(t, xs, soa, m, moments[p])
    _basis_sums(v0, xs, soa, m, cross[p, 0])
    _basis_sums(v1, xs, soa, m, cross[p, 1])
    _basis_sums(v2, xs, soa, m, cross[p, 2])
    _basis_sums(vr, xs, soa, m, e_c[p])
    _basis_sums(wv, xs, soa, m, basis[p])
    for i in range(25):
        moments[p, i] *= albedo * albedo
    for i in range(9):
        cross[p, 0, i] *= albedo
        cross[p, 1, i] *= albedo
        cross[p, 2, i] *= albedo
        e_c[p, i] *= albedo


def _shape_cost(soa, m, n0, n1, n2, albedo, c0, c1, c2, c3, c4, c5, c6, c7, c8):
    """One pixel's weighted residual sum of squares, summed as :func:`_shape_one` sums it."""
    total = 0.0
    for j in range(m):
        r = _shape_residual(soa, j, n0, n1, n2, albedo, c0, c1, c2, c3, c4, c5, c6, c7, c8)[5]
        total += soa[1, j] * r * r
    return total


def _shape_residual(soa, j, n0, n1, n2, albedo, c0, c1, c2, c3, c4, c5, c6, c7, c8):
    """Observation j's x = n . h, s = n . l, the biquadratic's slope terms q1, q2, its rho and
    the residual obs - albedo rho s, for the unit normal (n0, n1, n2)."""
    x = n0 * soa[5, j] + n1 * soa[6, j] + n2 * soa[7, j]
    s = n0 * soa[2, j] + n1 * soa[3, j] + n2 * soa[4, j]
    y1, y2 = soa[8, j], soa[9, j]
    q1 = c3 + c4 * y1 + c5 * y2
    q2 = c6 + c7 * y1 + c8 * y2
    rho = (c0 + c1 * y1 + c2 * y2) + x * (q1 + x * q2)
    return x, s, q1, q2, rho, soa[0, j] - rho * s * albedo


# ----------------------------------------------------------------------------- selection kernels
def _select_shared(obs, lights, base, k_high, k_low, iterations, min_obs, triplets, floor, w_out, b_out):
    """:func:`_select_one` for every pixel under shared lights (K, 3)."""
    n_pix, k = obs.shape
    scratch, sort32, packed = np.empty(k), np.empty(k, np.float32), np.empty((5, k), np.float32)
    lt, solvers = np.empty((3, k)), np.empty((len(triplets), 10))
    _light_rows(lights, lt)
    _triplet_solvers(lt, triplets, solvers)   # the same for every pixel
    for p in range(n_pix):
        _select_one(obs[p], lt, base[p], k_high, k_low, iterations, min_obs, triplets, solvers, floor, w_out[p],
                    b_out[p], scratch, sort32, packed)


def _select_per_pixel(obs, lights, base, k_high, k_low, iterations, min_obs, triplets, floor, w_out, b_out):
    """:func:`_select_one` for every pixel under per-pixel lights (N, K, 3)."""
    n_pix, k = obs.shape
    scratch, sort32, packed = np.empty(k), np.empty(k, np.float32), np.empty((5, k), np.float32)
    lt, solvers = np.empty((3, k)), np.empty((len(triplets), 10))
    for p in range(n_pix):
        _light_rows(lights[p], lt)
        _triplet_solvers(lt, triplets, solvers)
        _select_one(obs[p], lt, base[p], k_high, k_low, iterations, min_obs, triplets, solvers, floor, w_out[p],
                    b_out[p], scratch, sort32, packed)


def _light_rows(lights, lt):
    """lt (3, K) := lights (K, 3) transposed: one row per component, so that the passes over a
    pixel's observations read contiguous memory and vectorise."""
    for j in range(lights.shape[0]):
        lt[0, j], lt[1, j], lt[2, j] = lights[j, 0], lights[j, 1], lights[j, 2]


def _triplet_solvers(lt, triplets, solvers):
    """solvers (T, 10): each triplet's 3 x 3 light matrix as its 9 cofactors and determinant
    (:func:`_cofactors3`), so that b = cofactors . obs / det, the arithmetic of :func:`_solve3`."""
    for t in range(len(triplets)):
        i0, i1, i2 = triplets[t, 0], triplets[t, 1], triplets[t, 2]
        cof = _cofactors3(lt[0, i0], lt[1, i0], lt[2, i0], lt[0, i1], lt[1, i1], lt[2, i1],
                          lt[0, i2], lt[1, i2], lt[2, i2])
        for i in range(10):
            solvers[t, i] = cof[i]


def _select_one(o, lt, lit, k_high, k_low, iterations, min_obs, triplets, solvers, floor, w, b, scratch, sort32,
                packed):
    """One pixel's consensus start and MAD rounds (see pipeline.photometric.selection)."""
    k = len(o)
    m = 0
    for j in range(k):
        w[j] = lit[j]
        if lit[j] > 0.0:
            m += 1
    b0, b1, b2, best, scored = _consensus(o, lt, lit, m, triplets, solvers, sort32, packed)
    if math.isfinite(best):
        scale = max(1.4826 * (1.0 + 5.0 / max(scored - 3, 1)) * math.sqrt(best),
                    floor * math.sqrt(b0 * b0 + b1 * b1 + b2 * b2))
        kept = 0
        for j in range(k):
            inside = lit[j] > 0.0 and abs(o[j] - (b0 * lt[0, j] + b1 * lt[1, j] + b2 * lt[2, j])) <= _K_IN * scale
            w[j] = 1.0 if inside else 0.0
            kept += inside
        if kept < 3:
            for j in range(k):
                w[j] = lit[j]
    _lambert(o, lt, w, b)
    # The rounds' passes are branch-free (stores and counts, never a jump on an observation): the
    # kept/rejected pattern is irregular, and branches on it mispredict
    for _ in range(iterations):
        c = 0
        for j in range(k):
            r = o[j] - (b[0] * lt[0, j] + b[1] * lt[1, j] + b[2] * lt[2, j])
            scratch[j] = r
            sort32[c] = np.float32(abs(r))
            c += w[j] > 0.0
        scale = 1.4826 * np.float64(_kth_by_bits(sort32, sort32.view(np.int32), c, c // 2)) + 1e-9 if c > 0 else 1e-9
        scale = max(scale, floor * math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]))
        high, low = k_high * scale, -k_low * scale
        kept = 0
        for j in range(k):
            inside = (lit[j] > 0.0) & (scratch[j] < high) & (scratch[j] > low)
            sort32[j] = np.float32(inside)   # free once the median is read: the keep flags
            kept += inside
        changed = 0
        if kept >= min_obs:
            for j in range(k):
                keep = np.float64(sort32[j])
                changed += keep != w[j]
                w[j] = keep
        else:
            for j in range(k):
                changed += lit[j] != w[j]
                w[j] = lit[j]
        if changed == 0:   # a fixed point: the later rounds would repeat this one exactly
            break
        _lambert(o, lt, w, b)


def _consensus(o, lt, lit, m, triplets, solvers, scratch, packed):
    """The least-median-of-squares triplet: its b and median squared residual (inf if none), the
    median over the scored residuals the triplet does not fit (its own are zero), as
    :func:`pipeline.photometric.selection.consensus_weights`.

    The triplets are ranked in float32 (``scratch`` and ``packed`` are float32): twice the
    residuals per vector instruction, and a ranking needs no more (the winner's b is float64).
    """
    k = len(o)
    # the lit observations, contiguous: every triplet's residuals are a branch-free pass
    # (at most _SCORED of them, evenly spread: the median of a spread subset ranks triplets as well)
    oc, l0, l1, l2, in_scored = packed[0], packed[1], packed[2], packed[3], packed[4]
    scored = min(m, _SCORED)
    c = 0
    rank = 0
    for j in range(k):
        in_scored[j] = 0.0
        if lit[j] > 0.0:
            if c < scored and rank == (c * m) // scored:
                oc[c], l0[c], l1[c], l2[c] = o[j], lt[0, j], lt[1, j], lt[2, j]
                in_scored[j] = 1.0
                c += 1
            rank += 1
    m = scored
    best = np.float32(np.inf)
    b0 = b1 = b2 = 0.0
    for t in range(len(triplets)):
        i0, i1, i2 = triplets[t, 0], triplets[t, 1], triplets[t, 2]
        if not (lit[i0] > 0.0 and lit[i1] > 0.0 and lit[i2] > 0.0):
            continue
        det = solvers[t, 9]
        if not abs(det) > _MIN_DET:
            continue
        r0, r1, r2 = o[i0], o[i1], o[i2]
        x0 = (solvers[t, 0] * r0 + solvers[t, 1] * r1 + solvers[t, 2] * r2) / det
        x1 = (solvers[t, 3] * r0 + solvers[t, 4] * r1 + solvers[t, 5] * r2) / det
        x2 = (solvers[t, 6] * r0 + solvers[t, 7] * r1 + solvers[t, 8] * r2) / det
        if not (math.isfinite(x0) and math.isfinite(x1) and math.isfinite(x2) and x2 > 0.0):
            continue
        y0, y1, y2 = np.float32(x0), np.float32(x1), np.float32(x2)
        # the median of the residuals the triplet does not fit: its own scored ones are zero
        fitted = int(in_scored[i0] + in_scored[i1] + in_scored[i2])
        half = min(fitted + (m - fitted) // 2, m - 1)
        below = 0
        for j in range(m):
            r = oc[j] - (y0 * l0[j] + y1 * l1[j] + y2 * l2[j])
            r = r * r
            scratch[j] = r
            below += r < best
        if below <= half:     # the median cannot be below the best: no selection needed
            continue
        med = _kth_by_rank(scratch, m, half, best)
        if med < best:
            best, b0, b1, b2 = med, x0, x1, x2
    return b0, b1, b2, np.float64(best), m


def _lambert(o, lt, w, b):
    """b = the weighted Lambertian least squares (as pipeline.photometric.lambert.lambert_weighted)."""
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    r0 = r1 = r2 = 0.0
    for j in range(len(o)):
        if w[j] != 0.0:
            l0, l1, l2 = lt[0, j], lt[1, j], lt[2, j]
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


def _cofactors3(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    """The adjugate of a 3 x 3 matrix, row-major (9 values), and its determinant."""
    c00, c01, c02 = a11 * a22 - a12 * a21, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11
    c10, c11, c12 = a12 * a20 - a10 * a22, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12
    c20, c21, c22 = a10 * a21 - a11 * a20, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10
    return c00, c01, c02, c10, c11, c12, c20, c21, c22, a00 * c00 + a01 * c10 + a02 * c20


def _solve3(a00, a01, a02, a10, a11, a12, a20, a21, a22, r0, r1, r2):
    """A 3 x 3 solve by cofactors, as :func:`pipeline.photometric.lambert.solve3` (non-finite if singular)."""
    c00, c01, c02, c10, c11, c12, c20, c21, c22, det = _cofactors3(a00, a01, a02, a10, a11, a12, a20, a21, a22)
    return ((c00 * r0 + c01 * r1 + c02 * r2) / det, (c10 * r0 + c11 * r1 + c12 * r2) / det,
            (c20 * r0 + c21 * r1 + c22 * r2) / det)


def _kth_by_rank(a, n, kth, bound):
    """The kth smallest (0-based) of a[:n] (unchanged), known to be below ``bound``.

    The value with at most kth values below it and more than kth at or below it, found by
    branch-free counting passes over the candidates below ``bound``; for the start's 32
    squared residuals faster than a quickselect, whose data-dependent branches mispredict.
    """
    for i in range(n):
        v = a[i]
        if not v < bound:
            continue
        below = 0
        at_or_below = 0
        for j in range(n):
            below += a[j] < v
            at_or_below += a[j] <= v
        if below <= kth < at_or_below:
            return v
    return a[kth]


def _kth_by_bits(a, bits, n, kth):
    """The kth smallest (0-based) of the non-negative, non-NaN float32 values a[:n] (unchanged);
    ``bits`` is ``a`` viewed as int32.

    By bisection on the values' bit patterns, which non-negative floats order as integers:
    each of its at most 31 steps is one branch-free counting pass, which vectorises. For the
    MAD's median of some 80 values faster than a quickselect (whose data-dependent branches
    mispredict); for the start's 32 values :func:`_kth_by_rank`, which skips the values above
    the best median so far, is faster (docs/photometric-stereo.md, "Speed").
    """
    lo, hi = bits[0], bits[0]
    for j in range(1, n):
        lo, hi = min(lo, bits[j]), max(hi, bits[j])
    # below: values under lo; upto: values at or under hi. Once one value lies in [lo, hi] it is
    # the kth: 9 steps on average for 80 normal residuals, where narrowing to one bit pattern took 26
    below, upto = 0, n
    while lo < hi and upto - below > 1:
        mid = lo + (hi - lo) // 2
        count = 0
        for j in range(n):
            count += bits[j] <= mid
        if count > kth:
            hi, upto = mid, count
        else:
            lo, below = mid + 1, count
    out = a[0]
    for j in range(n):
        if lo <= bits[j] <= hi:
            out = a[j]
    return out


_PY = {name: globals()[name] for name in (
    "_scratch", "_fit_shared", "_fit_per_pixel", "_compact", "_fit_one", "_iterate", "_geometry", "_tangents",
    "_moments", "_basis_sums", "_coefficient_system", "_normal_terms", "_penalty_value", "_cost", "_rss_albedo",
    "_hat_trace", "_cholesky_solve", "_cholesky_factor", "_cholesky_substitute", "_select_shared",
    "_select_per_pixel", "_light_rows", "_triplet_solvers", "_select_one", "_consensus", "_lambert", "_cofactors3",
    "_solve3", "_kth_by_rank", "_kth_by_bits", "_shape_shared", "_shape_per_pixel", "_shape_one", "_shape_cost",
    "_shape_residual")}
#: The compiled kernels, built on first use (:func:`kernels`)
KERNELS = Compiled("photometric-stereo kernels", _build)
