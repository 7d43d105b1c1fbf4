"""Normal integration: normals (H, W, 3) + mask -> depth (H, W), one dispatcher over methods.

Conventions (docs/design.md): camera frame x right, y up, z toward the camera; image row 0 is the
top row, so +y points to decreasing rows.

- Orthographic (``K=None``): the result is the surface *height* z toward the camera, in pixel
  units (one pixel = one unit laterally), larger = closer to the camera. Each connected
  component has its own unknown offset; it is fixed so that the component's mean height is 0.
- Perspective (``K`` 3x3, pixel coordinates column, row, 0-based): the result is the positive
  distance along the optical axis, known only up to scale (log-depth formulation). Each
  component has its own unknown scale; it is fixed so that the component's geometric mean
  depth is 1.

Outside the mask the depth is NaN. Methods are registered by name in :data:`METHODS`.
"""

import inspect
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ..core.errors import InputError
from ..core.jit import single_threaded
from ..core.registry import Registry
from .bilateral import solve_bilateral, solve_smooth
from .grid import build_problem

__all__ = ["integrate_normals", "integrate_normals_full", "IntegrationResult", "METHODS",
           "NORMAL_WEIGHTING",
           "check_intrinsics", "OFFSETS_NOTE"]

#: name -> solver(problem, **options) -> (z (N,), info dict)
METHODS = Registry("integration method")
METHODS.register("smooth", solve_smooth)
METHODS.register("bilateral", solve_bilateral)
#: name -> default of ``normal_weighting`` (measured on DiLiGenT cat, see benchmarks/integrate.py)
NORMAL_WEIGHTING = {"smooth": False, "bilateral": True}

OFFSETS_NOTE = ("the mask has {n} disconnected components; each was integrated on its own and "
                "the {what} between them is unknown")


@dataclass
class IntegrationResult:
    """Everything an integration run produced.

    Attributes
    ----------
    depth : ndarray (H, W) float64
        Height (orthographic, pixels) or depth (perspective, up to scale); NaN outside the mask.
    components : ndarray (H, W) int32
        4-connected component label of each masked pixel (1..n), 0 outside the mask.
    n_components : int
    method : str
    perspective : bool
    iterations : int
        Conjugate-gradient iterations, all rounds together.
    outer_iterations : int
        Reweighting rounds (1 for smooth).
    seconds : float
    warnings : list of str
        E.g. the unknown offsets between components.
    """

    depth: np.ndarray
    components: np.ndarray
    n_components: int
    method: str
    perspective: bool
    iterations: int
    outer_iterations: int
    seconds: float
    warnings: list = field(default_factory=list)


def integrate_normals(normals, mask, K=None, method="smooth", **options):
    """Integrate a normal map into depth.

    Parameters
    ----------
    normals : ndarray (H, W, 3)
        Normals, camera frame (x right, y up, z toward the camera); normalised here.
    mask : ndarray (H, W) bool
        Pixels to integrate; any shape, holes and several components allowed.
    K : array-like (3, 3), optional
        Camera intrinsics; None for orthographic projection.
    method : {'smooth', 'bilateral'}
        Name in :data:`METHODS`.
    options
        Passed to the method (see :func:`~pipeline.integrate.bilateral.solve_smooth` and
        :func:`~pipeline.integrate.bilateral.solve_bilateral`), plus ``normal_weighting``
        (see :func:`integrate_normals_full`).

    Returns
    -------
    depth : ndarray (H, W) float64
        See the module docstring for units and the unknown offset / scale; NaN outside mask.
    """
    return integrate_normals_full(normals, mask, K, method, **options).depth


def integrate_normals_full(normals, mask, K=None, method="smooth", *, normal_weighting=None,
                           invalid="raise", **options):
    """Like :func:`integrate_normals` but returns an :class:`IntegrationResult`.

    ``normal_weighting`` (default: per method, :data:`NORMAL_WEIGHTING`) weights each pixel's
    equations by its squared steepness (``n_z**2``, or ``(n . ray)**2`` under K). Off, each
    edge's step is the plain mean of its end slopes, exact for quadratic surfaces; on, grazing
    pixels count less, which the bilateral weights need to find discontinuities.

    ``invalid``: 'raise' (default) refuses masked pixels with non-finite or zero normals or
    normals facing away from the camera (n_z <= 0, or away from the viewing ray under K);
    'drop' leaves them out of the mask (NaN in the depth) and says so in ``warnings``.
    """
    start = time.perf_counter()
    solver = METHODS[method]
    try:
        inspect.signature(solver).bind(None, **options)
    except TypeError as exc:
        raise InputError(f"integration method {method!r}: bad option ({exc})") from None
    K = None if K is None else check_intrinsics(K)
    normals, mask, warnings = _check_normals(normals, mask, K, invalid)
    if normal_weighting is None:
        normal_weighting = NORMAL_WEIGHTING.get(method, False)
    problem = build_problem(normals, mask, K, normal_weighting=bool(normal_weighting))
    # one BLAS thread: the solver's vectors are small, and on a busy machine multithreaded BLAS
    # calls (inside pyamg) spin-wait and run up to 100x slower
    with single_threaded("blas"):
        z, info = solver(problem, **options)
    labels, count = ndimage.label(mask)
    depth = _to_depth(z, mask, labels, count, K is not None)
    if count > 1:
        what = "scale" if K is not None else "offset"
        warnings.append(OFFSETS_NOTE.format(n=count, what=what))
    return IntegrationResult(depth, labels.astype(np.int32), int(count), method, K is not None,
                             int(info["iterations"]), int(info["outer_iterations"]),
                             time.perf_counter() - start, warnings)


def _to_depth(z, mask, labels, count, perspective):
    """Fix each component's free offset (mean 0) and map log-depth to depth."""
    lab = labels[mask]
    sizes = np.bincount(lab, minlength=count + 1)
    means = np.bincount(lab, z, minlength=count + 1) / np.maximum(sizes, 1)
    z = z - means[lab]
    depth = np.full(mask.shape, np.nan)
    depth[mask] = np.exp(z) if perspective else z
    return depth


def _check_normals(normals, mask, K, invalid):
    """Validate and normalise; returns (unit normals (H, W, 3) float64, mask, warnings)."""
    normals = np.asarray(normals)
    mask = np.asarray(mask)
    if normals.ndim != 3 or normals.shape[2] != 3:
        raise InputError(f"normals: expected an (H, W, 3) array, got shape {normals.shape}")
    if mask.shape != normals.shape[:2]:
        raise InputError(f"mask: shape {mask.shape} does not match the normals' {normals.shape[:2]}")
    if invalid not in ("raise", "drop"):
        raise InputError(f"invalid: expected 'raise' or 'drop', got {invalid!r}")
    mask = mask.astype(bool)
    if not mask.any():
        raise InputError("mask: empty (no pixel to integrate)")
    unit = np.zeros(normals.shape, dtype=np.float64)
    unit[mask] = normals[mask]
    length = np.linalg.norm(unit, axis=2)
    with np.errstate(invalid="ignore"):
        broken = mask & ~(np.isfinite(unit).all(axis=2) & (length > 1e-6))
    unit[broken] = 0.0
    unit[mask & ~broken] /= length[mask & ~broken, None]
    checks = [(broken, "have non-finite or zero normals"),
              (mask & ~broken & (unit[..., 2] <= 0.0), "face away from the camera (n_z <= 0)")]
    if K is not None:
        checks.append((mask & ~broken & _away_from_rays(unit, K),
                       "face away from their viewing ray under K"))
    warnings = []
    for bad, what in checks:
        if bad.any():
            row, col = np.argwhere(bad)[0]
            text = f"{int(bad.sum())} masked pixel(s) {what}, first at row {row}, column {col}"
            if invalid == "raise":
                raise InputError(f"normals: {text}; fix the normals, leave those pixels out of "
                                 "the mask, or drop them (--drop-invalid; invalid='drop' in the API)")
            warnings.append(f"dropped from the mask: {text}")
            mask = mask & ~bad
    if not mask.any():
        raise InputError("mask: no valid pixel left to integrate")
    return unit, mask, warnings


def _away_from_rays(unit, K):
    """(H, W) bool: normal . viewing ray >= 0 (OpenCV axes), i.e. not seen from the front."""
    rows, cols = np.indices(unit.shape[:2], dtype=np.float64)
    rays = np.stack([cols, rows, np.ones_like(rows)], axis=2) @ np.linalg.inv(K).T
    return np.einsum("hwc,hwc->hw", unit * np.array([1.0, -1.0, -1.0]), rays) >= 0.0


def check_intrinsics(K, where="K"):
    """Validate camera intrinsics: a finite, invertible 3x3 matrix. Returns float64 (3, 3)."""
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: intrinsics must be a 3x3 matrix of numbers") from None
    if K.shape != (3, 3):
        raise InputError(f"{where}: intrinsics must be a 3x3 matrix, got shape {K.shape}")
    if not np.isfinite(K).all():
        raise InputError(f"{where}: intrinsics contain non-finite values")
    if abs(np.linalg.det(K)) < 1e-12 * max(np.abs(K).max(), 1.0) ** 3 or K[0, 0] == 0 or K[1, 1] == 0:
        raise InputError(f"{where}: intrinsics are not invertible (det = {np.linalg.det(K):.3g})")
    return K
