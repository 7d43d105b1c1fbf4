"""Merging an exposure bracket into one linear frame (pure, vectorised; no files).

Each pixel (and colour channel) is taken from the longest exposure in which it is not
saturated, scaled to a reference shutter time: ``value * reference / shutter``. A pixel
saturated in every exposure keeps the shortest exposure's (clipped) value and is flagged in
the merged saturation mask, never silently used. The record says what was done.

Decode calls it for the frames of one light and one bracket group (the capture's
``bracket: {group, index, shutter}``); it is kept apart from the decode stage so it can be
tested, and moved, on its own.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["merge_exposures", "MergedExposure"]


@dataclass
class MergedExposure:
    """The result of :func:`merge_exposures`.

    Attributes
    ----------
    image : ndarray, float32
        Linear values scaled to the reference shutter (1.0 = white at the reference).
    saturated : ndarray, bool
        Saturated in every exposure.
    source : ndarray, int8
        Index (into the given order) of the exposure each value came from.
    record : dict
        What was done: method, reference shutter (s), the shutters (s), how many values came
        from each, how many are saturated in all.
    """

    image: np.ndarray
    saturated: np.ndarray
    source: np.ndarray
    record: dict


def merge_exposures(images, shutters, saturated, *, reference=None):
    """Merge N exposures of one scene into one linear frame.

    Parameters
    ----------
    images : array (N, H, W) or (N, H, W, C)
        Linear frames (black removed, 1.0 = white level), one per exposure.
    shutters : sequence of N floats
        Their shutter times, seconds (distinct, > 0).
    saturated : array of bool, the shape of ``images``
        Saturated values of each exposure (decode's saturation masks).
    reference : float, optional
        Shutter time the result is scaled to; default the shortest, so that unsaturated
        values stay within 0..1.

    Returns
    -------
    MergedExposure
    """
    images = np.asarray(images, dtype=np.float32)
    saturated = np.asarray(saturated, dtype=bool)
    shutters = np.asarray(shutters, dtype=np.float64)
    if images.ndim not in (3, 4) or len(images) < 1:
        raise InputError(f"images: expected (N, H, W[, C]), got shape {images.shape}")
    if saturated.shape != images.shape:
        raise InputError(f"saturated: shape {saturated.shape} differs from images {images.shape}")
    if shutters.shape != (len(images),) or not (np.isfinite(shutters) & (shutters > 0)).all() \
            or len(set(shutters.tolist())) != len(shutters):
        raise InputError(f"shutters: expected {len(images)} distinct positive times, got {shutters.tolist()}")
    reference = float(shutters.min() if reference is None else reference)
    if not reference > 0:
        raise InputError(f"reference: expected a positive shutter time, got {reference}")
    usable = ~saturated
    by_time = np.argsort(shutters)  # shortest first
    # the longest usable exposure: the last usable one in time order (argmax finds the first,
    # so look at the order reversed); none usable: the shortest
    reversed_usable = usable[by_time[::-1]]
    anywhere = reversed_usable.any(axis=0)
    longest = len(images) - 1 - np.argmax(reversed_usable, axis=0)
    rank = np.where(anywhere, longest, 0)
    source = by_time[rank]
    picked = np.take_along_axis(images, source[None], axis=0)[0]
    scale = (reference / shutters)[source].astype(np.float32)
    merged = picked * scale
    counts = np.bincount(source.ravel(), minlength=len(images))
    record = {"method": "longest unsaturated exposure, scaled by shutter time",
              "reference_shutter": reference, "shutters": shutters.tolist(),
              "values_from": {float(t): int(c) for t, c in zip(shutters, counts)},
              "saturated_in_all": int((~anywhere).sum())}
    return MergedExposure(merged.astype(np.float32), ~anywhere, source.astype(np.int8), record)
