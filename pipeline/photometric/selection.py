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

import numpy as np

from ..errors import InputError
from .lambert import lambert_weighted

__all__ = ["shadow_weights", "select_robust", "select_darkest", "select_observations", "resolve_selection",
           "light_spread_deg", "WIDE_SPREAD_DEG", "WIDE_T_LOW", "WIDE_T_SHADOW", "FALLBACK_T_LOW"]


def shadow_weights(obs, valid=None, t_shadow=0.1):
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


def select_robust(obs, lights, base, k_high=2.5, k_low=2.5, iterations=3, min_obs=3):
    """Robust Lambertian reweighting.

    Parameters
    ----------
    obs, base : ndarray (N, K)
        Intensities and the non-shadowed 0/1 weights (:func:`shadow_weights`).
    lights : ndarray (K, 3) or (N, K, 3)
        Unit light directions, shared or per pixel.

    Returns
    -------
    weights : ndarray (N, K)
        0/1 weights, a subset of ``base``.
    b : ndarray (N, 3)
        Albedo-scaled normals of the last Lambertian fit.
    """
    weights = base
    b = lambert_weighted(obs, lights, weights)
    for _ in range(iterations):
        # Lights (K, 3) shared, or (N, K, 3) per pixel (near lights).
        resid = obs - (b @ lights.T if lights.ndim == 2 else np.einsum("ni,nki->nk", b, lights))
        scale = _mad(resid, base) + 1e-9
        keep = base * ((resid < k_high * scale) & (resid > -k_low * scale))
        enough = keep.sum(axis=1) >= min_obs
        weights = np.where(enough[:, None], keep, base)
        b = lambert_weighted(obs, lights, weights)
    return weights, b


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
WIDE_SPREAD_DEG = 45.0
WIDE_T_LOW = 0.35
WIDE_T_SHADOW = 0.02
#: The narrow-cone fallback when the object fails the single-material check: the paper's
#: darkest-fraction rule with its wide-cone value (one value of the paper's 20-40 % for both).
#: The rule is worse conditioned under a narrow cone than robust selection with the prior, but
#: a prior fitted to two materials biases both. Measured (tests/pipeline/photometric/test_shape_check.py's
#: object, 64 lights in a 42-degree cone; mean error, noisy / noise-free): sharp lobes, default
#: 2.62 / 2.45, t_low 0.25-0.4: 0.44-0.62 / 0.03-0.07; broad lobes, default 5.98 / 5.94, t_low
#: 0.25-0.4: 1.37-1.59 / 0.89-1.32 degrees. No value of the range wins on all four.
FALLBACK_T_LOW = WIDE_T_LOW


def light_spread_deg(lights):
    """90th percentile of the lights' angles from their mean direction, in degrees."""
    shared = lights if lights.ndim == 2 else lights.reshape(lights.shape[0], -1, 3).mean(axis=1)
    mean = shared.mean(axis=0)
    mean = mean / max(np.linalg.norm(mean), 1e-12)
    return float(np.percentile(np.degrees(np.arccos(np.clip(shared @ mean, -1, 1))), 90))


def resolve_selection(lights, options):
    """Turn ``selection='auto'`` (the default) into concrete options from the light geometry.

    Wide light sets (spread > 45 degrees, e.g. domes): the paper's darkest-fraction rule
    (t_low 0.35, inside the paper's 20-40 %) after a 2 % shadow threshold (lights that reach
    grazing angles make dim observations informative), with independent per-pixel fits; the
    darkest observations then surround each
    normal, and a broad specular lobe, which covers most observations, is left out by
    intensity. Narrow cones (DiLiGenT, about 40 degrees): that rule is ill-conditioned (the
    darkest lights all sit on one side), so robust residual-based rejection and the shared-shape
    prior are used; if the object fails the single-material check, the prior is dropped and
    every pixel uses the darkest ``fallback_t_low`` fraction instead (default
    :data:`FALLBACK_T_LOW`, None for no fallback). Explicit ``t_low``/``shape_prior``/``selection``
    options always win; an explicit ``selection`` or ``t_low`` also turns the fallback off.
    """
    options = dict(options)
    if options.get("selection", "auto") != "auto" or options.get("t_low") is not None:
        options.setdefault("selection", "robust")
        if options["selection"] == "auto":
            options["selection"] = "robust"
        options.pop("fallback_t_low", None)   # the caller chose the selection
        return options
    if light_spread_deg(np.asarray(lights, float)) > WIDE_SPREAD_DEG:
        options.update(selection="darkest", t_low=WIDE_T_LOW)
        options.setdefault("shape_prior", 0.0)
        options.setdefault("t_shadow", WIDE_T_SHADOW)
        options.pop("fallback_t_low", None)
    else:
        options["selection"] = "robust"
        fraction = options.setdefault("fallback_t_low", FALLBACK_T_LOW)
        if fraction is not None and not 0 < fraction <= 1:
            raise InputError(f"fallback_t_low must be in (0, 1] or None, got {fraction}")
    return options


def select_observations(obs, valid, lights, t_low=None, t_shadow=0.1, reject_k=2.5, selection="robust", **_):
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
        weights, b = select_robust(obs, lights, base, k_high=reject_k, k_low=reject_k)
    else:
        if not 0 < t_low <= 1:
            raise InputError(f"t_low must be in (0, 1], got {t_low}")
        weights = select_darkest(obs, base, t_low)
        b = lambert_weighted(obs, lights, weights)
    return base, weights, b
