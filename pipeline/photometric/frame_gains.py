"""Each frame's brightness checked against its light's intensity, from the images themselves.

Photometric stereo divides each frame by its light's intensity (lights.yaml, or the caller's
images already divided). A frame whose light gave more or less than that (an LED that dimmed
or misfired, an exposure or gain that changed between frames, a wrong row of the intensity
file, a light file without intensities) biases every normal it takes part in, silently: the
per-pixel selection rejects such a frame at many pixels, but not at all of them. The frames
say so themselves. At a pixel, a robust Lambertian fit of all its observations predicts each
frame's value; over many pixels, the median ratio of a frame's values to those predictions is
that frame's brightness relative to the others (its gain), whatever the object's shape.

:func:`check_frames` measures the gains on a fixed random sample of the object's pixels before
the solve. A frame whose gain departs from the others' by more than :data:`GAIN_TOL` and by
more than :data:`SIGNIFICANCE` x the spread of its own ratios is rescaled by its gain (the
estimate is refined in :data:`GAIN_ROUNDS` rounds, each with the frames rescaled so far); the
others are left as given, so that a session whose intensities are right is solved exactly as
before. The check is reported in the result's options (``frame_check``) and by the normals
stage; on the same sample :mod:`pipeline.photometric.frame_directions` checks each frame's
light direction.

What the images cannot tell: a gain that varies linearly across the lights (log gain = a . l)
is, under a narrow cone of lights, nearly the same as a small shear of every normal. Measured
on DiLiGenT with its intensities left out: after rescaling, the gains' error is a ramp of
that form (log error 0.4-0.6 x l_x) plus 0.01 (median); the normals stay far off (ball 19.7 ->
10.3 degrees), so psrig says the intensities look uncalibrated rather than that it fixed them.
Measurements behind the defaults: docs/photometric-stereo.md (frame gains).
"""

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..core.errors import InputError
from .frame_directions import check_directions, column_quantiles
from .methods import shading
from .selection import select_observations

__all__ = ["FrameCheck", "GainMeasure", "check_frames", "measure_gains", "GAIN_TOL", "GAIN_SAMPLE", "GAIN_ROUNDS",
           "MIN_EVIDENCE", "UNCALIBRATED_SHARE", "SIGNIFICANCE", "FRAME_GAIN_MODES"]

#: frames whose brightness departs from the others' by more than this (log units: 16 %) are
#: rescaled: well above what calibrated frames of the DiLiGenT objects depart by (docs,
#: "Constants")
GAIN_TOL = 0.15
#: ... and by more than this many times the spread of its own ratios over the pixels (a robust
#: standard deviation): where the object's reflectance departs from the Lambertian prediction
#: under some light, that frame's ratios spread widely and their median moves by itself
SIGNIFICANCE = 1.0
#: pixels of the object the gains are measured on (a fixed random sample)
GAIN_SAMPLE = 1000
#: rounds of measurement once some frame is to be rescaled (each sees the frames rescaled so far)
GAIN_ROUNDS = 4
#: sampled pixels a frame must light (above the shadow threshold) to be judged
MIN_EVIDENCE = 20
#: when more than this share of the frames is rescaled, the intensities look uncalibrated
UNCALIBRATED_SHARE = 0.25
#: the option ``frame_gains``: 'auto' rescales the frames that depart; True every frame by its
#: measured gain (no frame's intensity is trusted); False checks nothing
FRAME_GAIN_MODES = ("auto", True, False)


@dataclass
class FrameCheck:
    """What :func:`check_frames` found.

    Attributes
    ----------
    gains : ndarray (K,)
        Each frame's brightness relative to what its intensity says (1 where left as given);
        the solve divides frame k by ``gains[k]``.
    deviation : ndarray (K,)
        The first measurement, log units relative to the median frame; NaN where a frame lit
        fewer than :data:`MIN_EVIDENCE` sampled pixels (not judged).
    rescaled : ndarray (R,) int
        Indices of the rescaled frames.
    verdict : str
        'consistent' (none rescaled), 'rescaled', 'estimated' (mode True), 'not checked'.
    spread : ndarray (K,)
        The spread of each frame's log ratios in the first measurement (robust standard
        deviation over the pixels).
    directions : dict or None
        :func:`pipeline.photometric.frame_directions.check_directions` on the same sample (the
        frames rescaled), for lights shared by all pixels.
    """

    gains: np.ndarray
    deviation: np.ndarray
    rescaled: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    verdict: str = "consistent"
    spread: np.ndarray = None
    directions: dict = None

    @classmethod
    def unchecked(cls, count):
        """The check of ``count`` frames that was not made: every frame as given."""
        return cls(np.ones(count), np.full(count, np.nan), verdict="not checked", spread=np.full(count, np.nan))

    def applied(self):
        """The gains the solve divides by, or None when every frame is left as given."""
        return self.gains if self.rescaled.size else None

    def record(self):
        """The result's ``frame_check`` entry: verdict, largest deviation, rescaled frames' gains, the
        directions' record."""
        judged = self.deviation[np.isfinite(self.deviation)]
        out = {"verdict": self.verdict,
               "max_deviation": round(float(np.abs(judged).max()), 4) if judged.size else None}
        if self.rescaled.size:
            out["rescaled"] = {int(k): round(float(self.gains[k]), 4) for k in self.rescaled}
            out["uncalibrated"] = bool(self.rescaled.size > UNCALIBRATED_SHARE * len(self.gains))
        if self.directions is not None:
            out["directions"] = self.directions
        return out


class GainMeasure(NamedTuple):
    """What :func:`measure_gains` returns: ``step`` (K,) the frames' log gains relative to their
    median, ``spread`` (K,) the robust standard deviation of each frame's log ratios (both NaN
    where not judged), and the fit they came from: ``scaled`` (N, K) the observations divided by
    the gains, ``base`` (N, K) their non-shadowed ones, ``b`` (N, 3) the Lambertian fit."""

    step: np.ndarray
    spread: np.ndarray
    scaled: np.ndarray
    base: np.ndarray
    b: np.ndarray


def measure_gains(obs, valid, lights, gains, options, min_evidence=MIN_EVIDENCE):
    """One measurement of the frames' log gains (K,) relative to their median, with the
    frames divided by ``gains`` (K,) first, and the spread (K,) of each frame's log ratios over
    the pixels (a robust standard deviation); NaN for frames lit at fewer than
    ``min_evidence`` of the pixels. Returns a :class:`GainMeasure`.

    Parameters
    ----------
    obs : ndarray (N, K)
        Observations of N sampled pixels.
    valid : ndarray (N, K) bool or None
    lights : ndarray (K, 3) or (N, K, 3)
        Unit directions toward the lights, camera frame.
    gains : ndarray (K,)
    options : dict
        The solve's options (its shadow threshold and rejection); the fit is always the robust
        selection's Lambertian one, whatever rule the solve uses.

    Notes
    -----
    Every non-shadowed observation counts, the rejected ones too: a frame far off is rejected
    at most pixels, and the pixels that keep it would hide how far. Observations where the
    prediction is below 5 % of the albedo (grazing light) are left out: their ratio is noise.
    """
    scaled = obs / gains
    chosen = dict(options, t_low=None, selection="robust")
    base, _, b = select_observations(scaled, valid, lights, **chosen)
    predicted = shading(b, lights)
    albedo = np.linalg.norm(b, axis=1, keepdims=True)
    use = (base > 0) & (predicted > 0.05 * albedo) & (scaled > 0)
    ratio = np.where(use, np.log(np.where(use, scaled, 1.0) / np.where(use, predicted, 1.0)), np.nan)
    low, step, high = column_quantiles(ratio, use, (0.25, 0.5, 0.75))
    judged = use.sum(axis=0) >= min_evidence
    step, spread = np.where(judged, step, np.nan), np.where(judged, (high - low) / 1.349, np.nan)
    if judged.any():
        step -= np.median(step[judged])
    return GainMeasure(step, spread, scaled, base, b)


def check_frames(gather, pixels, options, mode="auto", sample=GAIN_SAMPLE, tol=GAIN_TOL, rounds=GAIN_ROUNDS,
                 significance=SIGNIFICANCE, seed=1):
    """Measure each frame's gain on a sample of ``pixels`` and decide which frames to rescale.

    Parameters
    ----------
    gather : callable
        :func:`pipeline.photometric.engine.gatherer`'s function for the image (as given).
    pixels : ndarray (P,) int
        Flat indices of the object's pixels.
    options : dict
        The solve's options (see :func:`measure_gains`).
    mode : {'auto', True, False}
        See :data:`FRAME_GAIN_MODES`.
    tol, significance
        A frame is rescaled when its deviation exceeds ``tol`` (log units) and ``significance``
        x the spread of its ratios (:data:`GAIN_TOL`, :data:`SIGNIFICANCE`).

    Returns
    -------
    FrameCheck
    """
    if mode not in FRAME_GAIN_MODES:
        raise InputError(f"frame_gains must be 'auto', True or False, got {mode!r}")
    rng = np.random.default_rng(seed)
    take = np.sort(rng.choice(len(pixels), min(sample, len(pixels)), replace=False))
    obs, valid, lights = gather(pixels[take])
    count = obs.shape[1]
    gains = np.ones(count)
    if mode is False or count < 4:
        return FrameCheck.unchecked(count)
    measured = measure_gains(obs, valid, lights, gains, options)
    deviation, spread = measured.step, measured.spread
    chosen = np.isfinite(deviation) if mode is True else _departs(deviation, spread, tol, significance)
    step = deviation
    for _ in range(rounds if chosen.any() else 0):
        # the frames left as given are the reference: their median step is the offset
        kept = ~chosen & np.isfinite(step)
        offset = np.median(step[kept]) if kept.any() else 0.0
        gains[chosen] *= np.exp(np.nan_to_num(step[chosen] - offset))
        measured = measure_gains(obs, valid, lights, gains, options)
        step = measured.step
        if mode == "auto":
            chosen |= _departs(step, measured.spread, tol, significance)   # one the rescaled ones had hidden
    if mode is True:
        gains /= np.exp(np.median(np.log(gains)))
    verdict = "consistent" if not chosen.any() else "estimated" if mode is True else "rescaled"
    directions = check_directions(measured.scaled, measured.base, measured.b, lights) if lights.ndim == 2 else None
    return FrameCheck(gains, deviation, np.flatnonzero(chosen), verdict, spread, directions)


def _departs(deviation, spread, tol, significance):
    """Frames (K,) bool whose deviation exceeds ``tol`` and ``significance`` x their spread."""
    size = np.abs(np.nan_to_num(deviation))
    return (size > tol) & (size > significance * np.nan_to_num(spread, nan=np.inf))
