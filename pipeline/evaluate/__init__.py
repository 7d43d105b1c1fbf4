"""Errors of a session's results against its ground truth.

Scores whatever the session has and ground truth exists for (``session.truth(key)``):

- normals: angular error (degrees) over the ground-truth mask AND the estimated mask; mean,
  median, percentiles, fractions under 5 / 10 / 20 degrees, and a colour-mapped error map
  ``normals/error.png`` (0 .. ``max_deg`` degrees, 30 unless told, so that maps of two
  sessions compare; black outside the evaluated mask);
- lights: per-light angle between ``calibration/lights.yaml`` and the true directions, unless
  the lights in use were imported with the data and never calibrated in the session (they are
  then the ground truth's own, and comparing them with it says nothing);
- depth: mean absolute error of ``depth/depth.exr``. Orthographic depth is known up to an offset
  only, so one offset (the median of truth - estimate) is fitted; perspective depth is known up
  to scale, so one scale (the median of truth / estimate) is fitted, as the DiLiGenT protocol
  does. The fit used is reported.

The numbers are written to ``normals/eval.yaml``.
"""

import numpy as np
import yaml

from ..core.atomic import atomic_write_text
from ..core.errors import InputError
from ..core.imageio import read_image, read_mask, read_normal_png, write_image
from ..core.lightsio import read_lights
from ..core.paths import DEPTH, ERROR_MAP, EVAL, INTEGRATION, LIGHTS, NORMALS, NORMALS_MASK, UNCERTAINTY
from ..settings.report import ReportOptions
from ..core.yamlio import load_yaml

__all__ = ["angular_error", "error_stats", "light_errors", "intensity_errors", "position_errors", "depth_error",
           "error_map_rgb", "normal_errors", "lights_imported", "evaluate_session", "EVAL_FILE", "ERROR_MAP",
           "PERCENTILES", "THRESHOLDS", "ERROR_TOP_DEG"]

EVAL_FILE = EVAL
PERCENTILES = (25, 75, 90, 95)
THRESHOLDS = (5, 10, 20)
#: top of every angular-error colour scale unless told otherwise (degrees; declared with the
#: report's options)
ERROR_TOP_DEG = ReportOptions.defaults()["max_deg"]


def angular_error(n1, n2, mask=None):
    """Angle between two normal maps, degrees.

    Parameters
    ----------
    n1, n2 : ndarray (H, W, 3)
        Normals, camera frame; need not be unit length.
    mask : ndarray (H, W) bool, optional
        Pixels to evaluate.

    Returns
    -------
    ndarray (H, W) float64
        Angle in degrees; NaN outside ``mask`` and where either normal is zero.
    """
    n1, n2 = np.asarray(n1, np.float64), np.asarray(n2, np.float64)
    if n1.shape != n2.shape or n1.ndim != 3 or n1.shape[2] != 3:
        raise InputError(f"normal maps must both be H x W x 3, got {n1.shape} and {n2.shape}")
    norms = np.linalg.norm(n1, axis=2) * np.linalg.norm(n2, axis=2)
    valid = norms > 1e-12
    if mask is not None:
        valid &= np.asarray(mask, bool)
    cosine = np.einsum("hwc,hwc->hw", n1, n2) / np.where(valid, norms, 1.0)
    # arctan2 of |cross| and dot keeps small angles accurate where arccos of ~1 does not
    sine = np.linalg.norm(np.cross(n1, n2), axis=2) / np.where(valid, norms, 1.0)
    angle = np.degrees(np.arctan2(sine, cosine))
    return np.where(valid, angle, np.nan)


def error_stats(errors):
    """Summary of angular errors (degrees, NaN ignored): mean, median, percentiles, fractions."""
    values = np.asarray(errors, np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        raise InputError("no pixel to evaluate: the masks do not overlap")
    stats = {"mean_deg": float(values.mean()), "median_deg": float(np.median(values)),
             "max_deg": float(values.max()), "pixels": int(values.size)}
    for p, value in zip(PERCENTILES, np.percentile(values, PERCENTILES)):
        stats[f"p{p}_deg"] = float(value)
    for t in THRESHOLDS:
        stats[f"under_{t}_deg"] = float((values < t).mean())
    return stats


def light_errors(estimated, truth):
    """Per-light angle (degrees) between direction sets (K, 3) and its summary."""
    est, true = np.asarray(estimated, float), np.asarray(truth, float)
    if est.shape != true.shape:
        raise InputError(f"lights: {len(est)} estimated directions for {len(true)} true ones")
    est = est / np.linalg.norm(est, axis=1, keepdims=True)
    true = true / np.linalg.norm(true, axis=1, keepdims=True)
    angles = np.degrees(np.arccos(np.clip((est * true).sum(axis=1), -1.0, 1.0)))
    return {"mean_deg": float(angles.mean()), "median_deg": float(np.median(angles)),
            "max_deg": float(angles.max()), "worst_light": int(np.argmax(angles)),
            "per_light_deg": [round(float(a), 4) for a in angles]}


def depth_error(estimate, truth, projection="orthographic"):
    """Mean absolute depth error after one offset (orthographic) or scale (perspective) fit.

    Parameters
    ----------
    estimate, truth : ndarray (H, W)
        Depth, NaN where unknown; compared where both are finite.
    projection : {'orthographic', 'perspective'}

    Returns
    -------
    dict
        mean_abs, median_abs, rms (truth units), fit ('offset' or 'scale') and its value.
    """
    est, true = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    if est.shape != true.shape:
        raise InputError(f"depth: estimate {est.shape} and truth {true.shape} differ in size")
    valid = np.isfinite(est) & np.isfinite(true)
    if projection == "perspective":
        valid &= np.abs(est) > 1e-12
    if not valid.any():
        raise InputError("depth: no pixel where both estimate and truth are known")
    est, true = est[valid], true[valid]
    if projection == "perspective":
        fit, value = "scale", float(np.median(true / est))
        aligned = est * value
    else:
        fit, value = "offset", float(np.median(true - est))
        aligned = est + value
    diff = np.abs(aligned - true)
    return {"mean_abs": float(diff.mean()), "median_abs": float(np.median(diff)),
            "rms": float(np.sqrt((diff ** 2).mean())), "fit": fit, fit: value,
            "pixels": int(valid.sum())}


def error_map_rgb(errors, max_deg=ERROR_TOP_DEG, cmap="viridis"):
    """Colour-mapped error map: (H, W, 3) uint8, 0 .. ``max_deg`` degrees (larger errors have
    the top colour), black where NaN; returns it and ``max_deg``."""
    from matplotlib import colormaps

    errors = np.asarray(errors, np.float64)
    finite = np.isfinite(errors)
    max_deg = ERROR_TOP_DEG if max_deg is None else float(max_deg)
    if max_deg <= 0:
        raise InputError(f"error scale: the top must be positive, got {max_deg}")
    scaled = np.clip(np.nan_to_num(errors) / max(max_deg, 1e-9), 0.0, 1.0)
    rgb = (colormaps[cmap](scaled)[..., :3] * 255 + 0.5).astype(np.uint8)
    rgb[~finite] = 0
    return rgb, float(max_deg)


def _read_normals(path):
    """Normals (H, W, 3) and mask from an EXR (mask: non-zero) or a DiLiGenT-encoded PNG."""
    if path.suffix.lower() == ".exr":
        normals = read_image(path)[:, :, :3]
        return normals, (normals != 0).any(axis=2) & np.isfinite(normals).all(axis=2)
    return read_normal_png(path)


def normal_errors(session):
    """Per-pixel angular error of the session's normals against its ground truth.

    Returns
    -------
    ndarray (H, W) float64 or None
        Degrees over the estimated AND the true mask, NaN elsewhere; None when the session
        has no normals or no true normals.
    true_pixels : int
        Pixels of the true mask (the coverage's denominator).
    """
    est_path, mask_path = session.path(NORMALS), session.path(NORMALS_MASK)
    if not est_path.is_file() or session.truth("normals") is None or not session.truth("normals").is_file():
        return None, 0
    est, est_mask = _read_normals(est_path)
    if mask_path.is_file():
        est_mask &= read_mask(mask_path)
    true, true_mask = _read_normals(session.truth("normals"))
    if session.truth("mask") is not None:
        true_mask &= read_mask(session.truth("mask"))
    if true.shape != est.shape:
        raise InputError(f"{session.truth('normals')}: ground truth is {true.shape[1]}x{true.shape[0]} "
                         f"but {est_path} is {est.shape[1]}x{est.shape[0]}")
    return angular_error(est, true, est_mask & true_mask), int(true_mask.sum())


def _eval_normals(session, max_deg):
    errors, true_pixels = normal_errors(session)
    if errors is None:
        return None
    stats = error_stats(errors)
    stats["truth_pixels"] = true_pixels
    stats["coverage"] = stats["pixels"] / max(stats["truth_pixels"], 1)
    rgb, stats["error_map_max_deg"] = error_map_rgb(errors, max_deg)
    write_image(session.path(ERROR_MAP), rgb, bits=8)
    stats["error_map"] = ERROR_MAP
    found = _eval_uncertainty(session, errors)
    if found is not None:
        stats["uncertainty"] = found
    return stats


def _eval_uncertainty(session, errors):
    """How the normals stage's expected errors (``normals/uncertainty.exr``) agree with the
    actual ``errors`` (H, W, degrees): :func:`pipeline.photometric.uncertainty.agreement` over
    the pixels that have both; None without a map."""
    from ..photometric.uncertainty import agreement

    path = session.path(UNCERTAINTY)
    if not path.is_file():
        return None
    predicted = read_image(path)[:, :, 0]
    if predicted.shape != errors.shape:
        raise InputError(f"{path}: {predicted.shape[1]}x{predicted.shape[0]}, but the normals are "
                         f"{errors.shape[1]}x{errors.shape[0]}")
    both = np.isfinite(predicted) & np.isfinite(errors)
    if not both.any():
        return None
    found = agreement(predicted[both], errors[both])
    return {**found, "bad_share": round(found["bad_share"], 5),
            "auc": None if found["auc"] is None else round(found["auc"], 4)}


def intensity_errors(estimated, truth):
    """Relative intensity errors (K, C) after one common scale fit (intensities are known up
    to scale); summary in percent."""
    est, true = np.asarray(estimated, float), np.asarray(truth, float)
    if est.shape != true.shape:
        raise InputError(f"lights: intensities {est.shape} and true intensities {true.shape} differ")
    scale = np.median(true / est)
    relative = np.abs(est * scale / true - 1.0) * 100.0
    return {"mean_pct": float(relative.mean()), "max_pct": float(relative.max()),
            "worst_light": int(np.argmax(relative.max(axis=1)))}


def position_errors(estimated, truth):
    """Light position errors: distance from the true position as a percentage of the light's
    true distance from the frame origin."""
    est, true = np.asarray(estimated, float), np.asarray(truth, float)
    relative = np.linalg.norm(est - true, axis=1) / np.linalg.norm(true, axis=1) * 100.0
    distance = np.abs(np.linalg.norm(est, axis=1) / np.linalg.norm(true, axis=1) - 1.0) * 100.0
    return {"mean_pct": float(relative.mean()), "max_pct": float(relative.max()),
            "distance_mean_pct": float(distance.mean()), "distance_max_pct": float(distance.max())}


def lights_imported(session):
    """True when the lights in use came with imported data and no calibration of this session
    replaced them: an importer's lights are then the ground truth's own."""
    return session.manifest["lights"].get("source") == "imported" and session.stage("calibrate") is None


def _eval_lights(session):
    est_path = session.path(LIGHTS)
    if not est_path.is_file():
        return None
    estimated, truth = read_lights(est_path), read_lights(session.truth("lights"))
    if lights_imported(session):
        return {"evaluated": False, "source": estimated.source,
                "reason": "imported with the data: the lights in use are the ground truth's own"}
    if len(estimated) != len(truth):
        raise InputError(f"{est_path}: {len(estimated)} lights, the ground truth has {len(truth)}")
    # flagged lights carry no trustworthy direction; they are reported, not scored
    kept = np.array([i not in estimated.flags for i in range(len(estimated))])
    if not kept.any():
        return {"source": estimated.source, "flagged": sorted(int(k) for k in estimated.flags)}
    result = light_errors(estimated.directions[kept], truth.directions[kept])
    result["worst_light"] = int(np.flatnonzero(kept)[result["worst_light"]])
    angles = iter(result["per_light_deg"])
    result["per_light_deg"] = [next(angles) if keep else None for keep in kept]
    result["source"] = estimated.source
    if not kept.all():
        result["flagged"] = sorted(int(k) for k in estimated.flags)
    if estimated.intensities.shape == truth.intensities.shape and np.ptp(truth.intensities) > 0:
        result["intensities"] = intensity_errors(estimated.intensities[kept], truth.intensities[kept])
        result["intensities"]["worst_light"] = int(np.flatnonzero(kept)[result["intensities"]["worst_light"]])
    if estimated.positions is not None and truth.positions is not None:
        result["positions"] = position_errors(estimated.positions[kept], truth.positions[kept])
    return result


def _eval_depth(session):
    est_path = session.path(DEPTH)
    if not est_path.is_file():
        return None
    projection = "orthographic"
    info_path = session.path(INTEGRATION)
    if info_path.is_file():
        info = load_yaml(info_path.read_text(encoding="utf-8")) or {}
        projection = info.get("projection", projection)
    return depth_error(read_image(est_path)[:, :, 0], read_image(session.truth("depth"))[:, :, 0],
                       projection)


def evaluate_session(session, *, max_deg=ERROR_TOP_DEG, write=True):
    """Score a session against its ground truth.

    Parameters
    ----------
    session : Session
    max_deg : float, optional
        Top of the error map's colour scale (default :data:`ERROR_TOP_DEG`, 30 degrees).
    write : bool
        Write ``normals/eval.yaml`` (and the error map, which is always written with normals).

    Returns
    -------
    dict
        Keys ``normals``, ``lights``, ``depth``, each present only when both the result and
        its ground truth exist.
    """
    result = {}
    evaluators = {"normals": lambda: _eval_normals(session, max_deg),
                  "lights": lambda: _eval_lights(session), "depth": lambda: _eval_depth(session)}
    for key, evaluate in evaluators.items():
        if session.truth(key) is None or not session.truth(key).is_file():
            continue
        scores = evaluate()
        if scores is not None:
            result[key] = scores
    if write and result:
        atomic_write_text(session.path(EVAL_FILE), yaml.safe_dump(result, sort_keys=False))
    return result
