"""Choosing which observations of each pixel photometric stereo uses.

Two rules, both vectorised over pixels:

* :func:`select_robust` (default): drop shadows (below ``t_shadow`` of the pixel's 90th
  percentile), then reweight a Lambertian fit iteratively, rejecting observations whose residual
  exceeds ``k`` robust standard deviations (MAD) above (specular highlights) or below (cast
  shadows, inter-reflection deficits) the fit.
* :func:`select_darkest`: the paper's rule (Sec. 5.1): drop shadows, keep the darkest ``t_low``
  fraction of the remaining observations.

Which rule a run uses, and with which knobs, is the policy of :func:`resolve_selection` (from
the light geometry, ``selection='auto'``); :func:`select_observations` applies it to a chunk.
The measurements behind the defaults are in docs/photometric-stereo.md.
"""

import functools
import itertools
import math

import numpy as np

from ..core.errors import InputError
from ..settings.normals import CONSENSUS, REJECT_K, SCALE_FLOOR, T_SHADOW, WIDE_SPREAD_DEG, WIDE_T_LOW, WIDE_T_SHADOW
from .kernels import jit_enabled, select_robust_jit
from .lambert import facing_away, ill_conditioned, lambert_weighted, normal_leverage, solve3

__all__ = ["shadow_weights", "select_robust", "select_darkest", "select_observations", "reuse_selection",
           "widen_undetermined", "resolve_selection", "darkest_leverage", "DARKEST_LEVERAGE_MAX", "SURROUND_SAMPLE",
           "consensus_triplets", "consensus_weights", "light_spread_deg", "WIDE_SPREAD_DEG", "WIDE_T_LOW",
           "WIDE_T_SHADOW", "T_SHADOW", "REJECT_K", "CONSENSUS", "MIN_DET", "SCALE_FLOOR", "SCORED"]

#: at most this many of a pixel's lit observations rank its triplets (the cost of the start
#: grows with them; scoring all of them is no more accurate: docs, "Constants")
SCORED = 32
#: triplets whose three directions are closer to coplanar than this (|det|) are not tried
MIN_DET = 1e-3


def shadow_weights(obs, valid=None, t_shadow=T_SHADOW):
    """Weights (N, K): 1 where an observation is above ``t_shadow`` x the pixel's 90th percentile.

    Parameters
    ----------
    obs : ndarray (N, K)
        Linear intensities of N pixels under K lights.
    valid : ndarray (N, K) bool, optional
        False for observations that must not be used (saturated).
    """
    k = obs.shape[1]
    ref = np.partition(obs, int(0.9 * (k - 1)), axis=1)[:, int(0.9 * (k - 1))][:, None]
    # A pixel lit by few lights has a dark 90th percentile; its brightest observation then sets
    # the scale, so that its few lit observations are not all called shadows.
    ref = np.maximum(ref, 0.25 * obs.max(axis=1, keepdims=True))
    weights = (obs > t_shadow * ref) & (ref > 0)
    if valid is not None:
        weights &= valid
    return weights.astype(obs.dtype)


def select_robust(obs, lights, base, k_high=REJECT_K, k_low=REJECT_K, iterations=3, min_obs=3, consensus=CONSENSUS,
                  scale_floor=SCALE_FLOOR):
    """Robust Lambertian selection: a high-breakdown start, then MAD reweighting.

    The start (``consensus`` triplets of lights, :func:`consensus_weights`) is a least-median
    fit, which tolerates up to half of a pixel's observations being wrong (shadowed,
    interreflected, specular); a least-squares start on all of them breaks down well before
    that on hard objects (DiLiGenT reading: about 20 % of the observations). Then
    ``iterations`` rounds refit Lambert on the kept observations and keep those within
    ``k_high`` robust standard deviations above and ``k_low`` below it (MAD over the kept ones).

    Parameters
    ----------
    obs, base : ndarray (N, K)
        Intensities and the non-shadowed 0/1 weights (:func:`shadow_weights`).
    lights : ndarray (K, 3) or (N, K, 3)
        Unit light directions, shared or per pixel.
    consensus : int
        Triplets tried by the start (0: start from every non-shadowed observation).
    scale_floor : float
        The robust scale is at least this fraction of the pixel's albedo (|b|): residuals that
        small are model error, not outliers, and rejecting them would make the selection follow
        the model's last details (noise-free or nearly Lambertian data).

    Returns
    -------
    weights : ndarray (N, K)
        0/1 weights, a subset of ``base``.
    b : ndarray (N, 3)
        Albedo-scaled normals of the last Lambertian fit.
    """
    triplets = consensus_triplets(obs.shape[1], consensus)
    fast = select_robust_jit(obs, lights, base, k_high, k_low, iterations, min_obs, triplets, scale_floor) \
        if jit_enabled() else None
    if fast is not None:
        return fast
    weights = consensus_weights(obs, lights, base, triplets, scale_floor=scale_floor) if consensus else base
    b = lambert_weighted(obs, lights, weights)
    for _ in range(iterations):
        resid = obs - (b @ lights.T if lights.ndim == 2 else np.einsum("ni,nki->nk", b, lights))
        scale = np.maximum(_mad(resid, weights) + 1e-9, scale_floor * np.linalg.norm(b, axis=1, keepdims=True))
        keep = base * ((resid < k_high * scale) & (resid > -k_low * scale))
        enough = keep.sum(axis=1) >= min_obs
        weights = np.where(enough[:, None], keep, base)
        b = lambert_weighted(obs, lights, weights)
    return weights, b


@functools.lru_cache(maxsize=16)
def consensus_triplets(count, triplets=CONSENSUS, seed=0):
    """(T, 3) int64: distinct triplets of ``count`` lights drawn with a fixed seed (all of them
    when there are fewer), the same for every pixel and chunk."""
    if triplets <= 0 or count < 3:
        return np.zeros((0, 3), np.int64)
    everything = math.comb(count, 3)
    if everything <= triplets:
        return np.array(list(itertools.combinations(range(count), 3)), np.int64)
    rng = np.random.default_rng(seed)
    chosen = set()
    while len(chosen) < triplets:
        chosen.add(tuple(sorted(int(i) for i in rng.choice(count, 3, replace=False))))
    return np.array(sorted(chosen), np.int64)


def _scored(lit):
    """The observations (N, K) bool whose residuals rank a pixel's triplets: at most
    :data:`SCORED` of its lit ones, evenly spread over them (the kth of m when k = i m // SCORED)."""
    m = lit.sum(axis=1, keepdims=True)
    rank = np.cumsum(lit, axis=1) - 1
    # rank r is scored when some i < SCORED gives i m // SCORED == r, i.e. ceil(r SCORED / m) does
    count = np.minimum(m, SCORED)
    i = -((-rank * count) // np.maximum(m, 1))
    return lit & (i < count) & ((i * m) // np.maximum(count, 1) == rank)


def consensus_weights(obs, lights, base, triplets, k_in=2.5, scale_floor=0.0):
    """The high-breakdown start of :func:`select_robust` (numpy reference of its kernel).

    For every triplet of non-shadowed lights (and a well-conditioned 3 x 3 system), the
    Lambertian b through its three observations; the triplet whose b has the least median
    squared residual over the pixel's non-shadowed observations wins (least median of
    squares; the median is taken over at most :data:`SCORED` of them, evenly spread), provided
    b faces the camera. The median is over the residuals the triplet does not fit itself: its
    own observations, where scored, are zero, and counted they put the median of a few lights'
    residuals at or beside those zeros, so that noise was rejected (docs/photometric-stereo.md,
    "Few lights"). The kept observations are those within
    ``k_in`` times the robust scale of that median (Rousseeuw's 1.4826 (1 + 5 / (n - 3))
    sqrt(median)). Pixels with no usable triplet keep ``base``. Returns 0/1 weights (N, K), a
    subset of base.
    """
    n, k = obs.shape
    lit = base > 0
    scored = _scored(lit)
    counts = scored.sum(axis=1)
    best = np.full(n, np.inf)
    best_b = np.zeros((n, 3))
    rows = np.arange(n)
    for start in range(0, len(triplets), 16):
        group = triplets[start:start + 16]
        sub = lights[:, group] if lights.ndim == 3 else lights[group]           # (N, T, 3, 3) or (T, 3, 3)
        det = np.abs(np.linalg.det(sub))
        sub = np.broadcast_to(sub, (n,) + sub.shape[-3:])
        with np.errstate(invalid="ignore"):
            b = solve3(sub.reshape(-1, 3, 3), obs[:, group].reshape(-1, 3)).reshape(n, len(group), 3)
        usable = lit[:, group].all(axis=2) & (det > MIN_DET) & np.isfinite(b).all(axis=2) & (b[..., 2] > 0)
        shade = np.einsum("nti,ki->ntk", b, lights) if lights.ndim == 2 else np.einsum("nti,nki->ntk", b, lights)
        r2 = np.where(scored[:, None, :], (obs[:, None, :] - shade) ** 2, np.inf)
        # the median of the residuals the triplet does not fit: its own scored ones are zero
        fitted = scored[:, group].sum(axis=2)
        half = np.minimum(fitted + (counts[:, None] - fitted) // 2, np.maximum(counts[:, None] - 1, 0))
        med = np.take_along_axis(np.sort(r2, axis=2), half[..., None], axis=2)[..., 0]
        med = np.where(usable, med, np.inf)
        j = np.argmin(med, axis=1)
        c = med[rows, j]
        better = c < best
        best[better] = c[better]
        best_b[better] = b[rows, j][better]
    scale = 1.4826 * (1 + 5 / np.maximum(counts - 3, 1)) * np.sqrt(np.where(np.isfinite(best), best, 0.0))
    scale = np.maximum(scale, scale_floor * np.linalg.norm(best_b, axis=1))
    resid = obs - (best_b @ lights.T if lights.ndim == 2 else np.einsum("ni,nki->nk", best_b, lights))
    inliers = lit & (np.abs(resid) <= k_in * scale[:, None])
    found = np.isfinite(best) & (inliers.sum(axis=1) >= 3)
    return np.where(found[:, None], inliers, lit).astype(obs.dtype)


def _mad(resid, weights):
    """1.4826 x median absolute residual over the weighted observations, per row (N, 1)."""
    # Sort with the unused observations pushed to the end; the median sits at count // 2.
    # float32 halves the sort's memory traffic; the median is a threshold scale, not a result.
    ordered = np.abs(resid, out=np.empty(resid.shape, np.float32), casting="same_kind")
    unused = ~(weights > 0)
    ordered[unused] = np.inf
    ordered.sort(axis=1)
    count = resid.shape[1] - unused.sum(axis=1)
    mid = np.take_along_axis(ordered, np.maximum(count // 2, 0)[:, None], axis=1)
    return 1.4826 * np.where(count[:, None] > 0, mid, 0.0).astype(resid.dtype)


def select_darkest(obs, base, t_low, min_obs=3):
    """The paper's rule: keep the darkest ``t_low`` fraction of each pixel's non-shadowed observations."""
    count = base.sum(axis=1, keepdims=True)
    ranked = np.where(base > 0, obs, np.inf)
    order = np.argsort(ranked, axis=1, kind="stable")
    # The rank of each observation is the inverse permutation of the order: a scatter, not a
    # second sort.
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.broadcast_to(np.arange(obs.shape[1]), order.shape), axis=1)
    keep = rank < np.maximum(np.ceil(t_low * count), min_obs)
    return (base * keep).astype(obs.dtype)


# ----------------------------------------------------------------------------- policy
#: the darkest-fraction rule is kept only where the lights it keeps determine the normals: the
#: median over sampled pixels of their noise amplification (radians of the normal per unit of
#: noise relative to the albedo, :func:`pipeline.photometric.lambert.normal_leverage`) must be
#: at most this (3: 1 % noise turns the normal by 1.7 degrees)
DARKEST_LEVERAGE_MAX = 3.0
#: pixels sampled for that test
SURROUND_SAMPLE = 1000


def darkest_leverage(obs, valid, lights, options):
    """How well the lights the darkest-fraction rule keeps determine the normals.

    The paper's rule assumes the darkest observations surround each normal (lights on every
    side of it, at grazing angles); under a narrow cone, or a few lights of which two stray,
    they sit on one side and their fit amplifies noise. For each pixel the normal is the robust
    selection's Lambertian fit, and the noise amplification is the angular standard deviation
    a Lambertian fit on the lights the rule keeps would have per unit of relative noise.

    Parameters
    ----------
    obs : ndarray (N, K)
    valid : ndarray (N, K) bool or None
    lights : ndarray (K, 3) or (N, K, 3)
    options : dict
        The darkest-fraction rule's options (``t_low``, ``t_shadow``).

    Returns
    -------
    float
        The median over the pixels whose kept lights determine a normal (inf when none do).
    """
    _, darkest, _ = select_observations(obs, valid, lights, selection="darkest", t_low=options["t_low"],
                                        t_shadow=options.get("t_shadow", T_SHADOW))
    _, _, b = select_observations(obs, valid, lights, selection="robust")
    leverage = normal_leverage(b, darkest, lights)
    finite = leverage[np.isfinite(leverage)]
    return float(np.median(finite)) if finite.size else float("inf")


def light_spread_deg(lights):
    """90th percentile of the lights' angles from their mean direction, in degrees."""
    shared = lights if lights.ndim == 2 else lights.reshape(lights.shape[0], -1, 3).mean(axis=1)
    mean = shared.mean(axis=0)
    mean = mean / max(np.linalg.norm(mean), 1e-12)
    return float(np.percentile(np.degrees(np.arccos(np.clip(shared @ mean, -1, 1))), 90))


def resolve_selection(lights, options):
    """Turn ``selection='auto'`` (the default) into concrete options from the light geometry.

    Wide light sets (spread > :data:`WIDE_SPREAD_DEG`, e.g. domes): the paper's darkest-fraction
    rule (t_low :data:`WIDE_T_LOW`, inside the paper's 20-40 %) after a :data:`WIDE_T_SHADOW`
    shadow threshold (lights that reach grazing angles make dim observations informative),
    without the shared shape: the darkest observations then surround each normal, and a broad
    specular lobe, which covers most observations, is left out by intensity. Narrow cones
    (DiLiGenT, about 40 degrees): that rule is ill-conditioned (the darkest lights all sit on
    one side), so robust selection (:func:`select_robust`) and the shared-shape prior are used.
    Explicit ``t_low``/``shape_prior``/``selection``/``t_shadow`` options always win.
    """
    options = dict(options)
    if options.get("selection", "auto") != "auto" or options.get("t_low") is not None:
        options.setdefault("selection", "robust")
        if options["selection"] == "auto":
            options["selection"] = "robust"
        return options
    if light_spread_deg(np.asarray(lights, float)) > WIDE_SPREAD_DEG:
        options.update(selection="darkest", t_low=WIDE_T_LOW)
        options.setdefault("shared_shape", False)
        options.setdefault("t_shadow", WIDE_T_SHADOW)
    else:
        options["selection"] = "robust"
    return options


def select_observations(obs, valid, lights, t_low=None, t_shadow=T_SHADOW, reject_k=REJECT_K, selection="robust",
                        consensus=CONSENSUS, scale_floor=SCALE_FLOOR, **_):
    """Apply a selection (options of :func:`resolve_selection`) to a chunk.

    Parameters
    ----------
    obs : ndarray (N, K)
    valid : ndarray (N, K) bool or None
    lights : ndarray (K, 3) or (N, K, 3)

    Returns
    -------
    base : ndarray (N, K)
        0/1 weights of the non-shadowed observations.
    weights : ndarray (N, K)
        0/1 weights of the selected ones (a subset of ``base``).
    b : ndarray (N, 3)
        The Lambertian start on the selected observations (albedo-scaled normals).
    """
    base = shadow_weights(obs, valid, t_shadow)
    if t_low is None:
        weights, b = select_robust(obs, lights, base, k_high=reject_k, k_low=reject_k, consensus=consensus,
                                   scale_floor=scale_floor)
    else:
        if not 0 < t_low <= 1:
            raise InputError(f"t_low must be in (0, 1], got {t_low}")
        weights = select_darkest(obs, base, t_low)
        b = lambert_weighted(obs, lights, weights)
    weights, b = widen_undetermined(obs, lights, base, weights, b)
    return base, weights, b


def reuse_selection(obs, valid, lights, chosen, t_shadow=T_SHADOW, **_):
    """:func:`select_observations`' result for a selection already made under other lights.

    The specular anchor's run at corrected lights (:func:`pipeline.photometric.estimate_normals`)
    keeps the observations its first run chose: which observations are shadows, highlights or
    interreflections does not depend on a few percent of the lights' polar angles. Measured on
    DiLiGenT ball at the corrected scale (1.053): 3 % of the selected observations differ from
    a fresh selection, and the mean error is 0.83 degrees with the kept selection, 0.85 fresh.

    Parameters
    ----------
    obs, valid, lights
        As for :func:`select_observations`.
    chosen : ndarray (N, K) bool
        The observations selected before.

    Returns
    -------
    base, weights, b
        As :func:`select_observations`: the non-shadowed observations, the chosen ones among
        them, and the Lambertian start on those under ``lights``.
    """
    base = shadow_weights(obs, valid, t_shadow)
    weights = base * chosen
    weights, b = widen_undetermined(obs, lights, base, weights, lambert_weighted(obs, lights, weights))
    return base, weights, b


#: pixels with at most this many selected observations are checked for a degenerate selection
#: (more are degenerate only under lights that are degenerate themselves)
WIDEN_CHECK_OBS = 8


def widen_undetermined(obs, lights, base, weights, b, min_obs=3):
    """Pixels whose selected observations determine no normal facing the camera take all their
    non-shadowed ones instead, where those do.

    A selection can leave a pixel too few observations, or ones too close to coplanar (the
    darkest few of a pixel under a wide dome often sit on one side), or a fit facing away;
    that pixel would get no normal at all, although its non-shadowed observations, outliers
    and all, determine one (12-light 8-bit domes: 1-8 % of the pixels, 6-16 % with 8 lights,
    where plain Lambert is within 5 degrees). Returns (weights, b), changed for those pixels.
    """
    count = weights.sum(axis=1)
    doubtful = (count < min_obs) | facing_away(b)
    small = np.flatnonzero(~doubtful & (count <= WIDEN_CHECK_OBS))
    if small.size:
        doubtful[small] = ill_conditioned(weights[small], lights if lights.ndim == 2 else lights[small])
    idx = np.flatnonzero(doubtful & (base.sum(axis=1) >= min_obs))
    if idx.size == 0:
        return weights, b
    sub = lights if lights.ndim == 2 else lights[idx]
    wider = lambert_weighted(obs[idx], sub, base[idx])
    take = ~facing_away(wider) & ~ill_conditioned(base[idx], sub)
    weights, b = weights.copy(), b.copy()
    weights[idx[take]], b[idx[take]] = base[idx[take]], wider[take]
    return weights, b
