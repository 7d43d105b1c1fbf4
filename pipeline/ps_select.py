"""Choosing which observations of each pixel photometric stereo uses.

Two rules, both vectorised over pixels:

* :func:`select_robust` (default): drop shadows (below ``t_shadow`` of the pixel's 90th
  percentile), then reweight a Lambertian fit iteratively, rejecting observations whose residual
  exceeds ``k`` robust standard deviations (MAD) above (specular highlights) or below (cast
  shadows, inter-reflection deficits) the fit.
* :func:`select_darkest`: the paper's rule (Sec. 5.1): drop shadows, keep the darkest ``t_low``
  fraction of the remaining observations.
"""

import numpy as np

from .ps_lambert import lambert_weighted

__all__ = ["shadow_weights", "select_robust", "select_darkest"]


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

