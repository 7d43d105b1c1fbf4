"""Near point lights: the object's depth for the per-pixel light directions, from a first solve.

Per-pixel directions and falloff of near lights depend on where each surface point is. Before
integration its depth is unknown, so a first solve takes the object on the plane of the
calibration spheres' centres (:class:`~pipeline.photometric.near_lights.PointLights` ``plane_z`` = 0). Its
normals integrate (orthographically, in pixels) to the surface's relief up to one unknown
offset: the object's height above that plane. The offset is the value whose solve leaves the
smallest photometric residual on a fixed sample of pixels (a coarse scan, then a
golden-section search around the best), and the relief plus that offset is the depth the next
solve uses.

What it recovers on the simulated ``sim-near`` rig: docs/near-lights.md.

Limits: one offset for the whole mask (each connected component integrates to its own zero
mean, so separate objects at different heights share it); orthographic relief (a perspective
``K`` is not used here).
"""

import cv2
import numpy as np

from ..core.golden import golden_section, golden_steps
from ..integrate import integrate_normals
from .near_lights import PointLights
from .methods import STATUS

__all__ = ["refine_near_depth", "RELIEF_PIXELS", "SAMPLE_PIXELS", "SCAN_STEPS", "PASSES", "MAX_RATIO"]

#: pixels whose mean residual scores an offset (a fixed random sample of the mask)
SAMPLE_PIXELS = 4000
#: largest normal map integrated as it is; larger ones are integrated on block means
RELIEF_PIXELS = 250_000
#: statuses without a normal to integrate
_UNSOLVED = (STATUS["background"], STATUS["too_few"])
#: depth refinements at most; another follows only when the last cut the mean residual to at
#: most MAX_RATIO of the one before (the relief moved a lot); docs/near-lights.md has the
#: passes' effect.
PASSES = 3
MAX_RATIO = 0.5
#: offsets scanned over +-half the median light distance before the golden-section search
SCAN_STEPS = 9


def refine_near_depth(solve, lights, mask, *, passes=PASSES, sample_pixels=SAMPLE_PIXELS, seed=0, tol=0.5):
    """Solve with near lights, then again at the depth the first solve's normals give.

    Parameters
    ----------
    solve : callable
        ``solve(lights, mask)`` -> :class:`~pipeline.photometric.PhotometricResult`, the
        photometric-stereo solve of the caller's images with :class:`PointLights` ``lights``
        over ``mask`` (H, W) bool.
    lights : PointLights
        Calibrated light positions (their ``plane_z`` is the first solve's depth).
    mask : ndarray (H, W) bool
        Object pixels.
    passes : int
        Depth refinements after the first solve at most (0 = the first solve only); they stop
        when one does not cut the mean residual to :data:`MAX_RATIO` of the last one.
    sample_pixels, seed
        The pixel sample that scores offsets.
    tol : float
        Offset precision, pixels.

    Returns
    -------
    result : PhotometricResult
        The last solve, or an earlier one if a refinement did not lower the mean residual.
    record : dict
        ``passes`` done, ``offset_px`` (object height above the spheres' plane, at the mean of
        its relief), ``residual`` mean per solve, ``kept`` (which solve was returned).
    """
    result = solve(lights, mask)
    residuals = [_mean_residual(result, mask)]
    record = {"passes": 0, "offset_px": None, "residual": residuals, "kept": 0}
    sample = _sample(mask, sample_pixels, seed)
    for _ in range(passes):
        relief = _relief(result, mask)
        if relief is None:
            break
        offset = _best_offset(solve, lights, relief, sample, tol)
        refined = solve(_at_depth(lights, relief + offset), mask)
        residuals.append(_mean_residual(refined, mask))
        record["passes"] += 1
        if not residuals[-1] < residuals[record["kept"]]:
            break  # by its own measure the relief did not help: keep the better solve
        gain = residuals[-1] / residuals[record["kept"]]
        result, record["kept"], record["offset_px"] = refined, record["passes"], round(float(offset), 2)
        if gain > MAX_RATIO:
            break  # converged: another pass would change little
    record["residual"] = [round(float(r), 6) for r in residuals]
    return result, record


def _at_depth(lights, depth):
    return PointLights(lights.positions, lights.shape, plane_z=depth)


def _relief(result, mask, max_pixels=RELIEF_PIXELS):
    """Orthographic height (H, W) of the solved normals, mean 0 over them, 0 elsewhere; None
    when too few pixels were solved. Normal maps of more than ``max_pixels`` are integrated
    on f x f block means (heights times f, then interpolated back): the directions to lights
    hundreds of pixels away hardly change over a block, and the whole-image solve stays small.
    """
    solved = mask & np.isfinite(result.normals).all(-1) & ~np.isin(result.status, _UNSOLVED)
    if solved.sum() < 20:
        return None
    f = max(1, int(np.ceil(np.sqrt(solved.sum() / max_pixels))))
    normals = np.where(solved[..., None], result.normals, 0.0)
    if f > 1:
        normals, solved_small = _block_mean(normals, f), _block_mean(solved.astype(float), f) > 0.5
        height = integrate_normals(normals, solved_small) * f
        # back to the padded size of the blocks, then cropped: block i covers pixels i*f..i*f+f-1
        blocks = np.nan_to_num(height - np.nanmean(height), nan=0.0)
        height = cv2.resize(blocks, (blocks.shape[1] * f, blocks.shape[0] * f),
                            interpolation=cv2.INTER_LINEAR)[:mask.shape[0], :mask.shape[1]]
    else:
        height = integrate_normals(normals, solved)
    return np.nan_to_num(height - np.nanmean(height[solved]), nan=0.0)


def _block_mean(image, f):
    """Means of f x f blocks of ``image`` (H, W, ...), the last partial blocks padded by edge values."""
    h, w = image.shape[:2]
    pad = [(0, -h % f), (0, -w % f)] + [(0, 0)] * (image.ndim - 2)
    image = np.pad(image, pad, mode="edge")
    shape = (image.shape[0] // f, f, image.shape[1] // f, f) + image.shape[2:]
    return image.reshape(shape).mean(axis=(1, 3))


def _sample(mask, count, seed):
    """A fixed random subset of ``mask`` (H, W) bool of at most ``count`` pixels."""
    flat = np.flatnonzero(mask)
    pick = np.random.default_rng(seed).choice(flat, min(count, flat.size), replace=False)
    sample = np.zeros(mask.shape, bool)
    sample.flat[pick] = True
    return sample


def _mean_residual(result, mask):
    # over every pixel of the fixed set, not the ones that fitted: which pixels fit (rather
    # than fall back or stop unconverged) changes with the depth, and those that stop fitting
    # at a wrong depth are the clearest sign of it
    return float(np.mean(result.residual[mask]))


def _best_offset(solve, lights, relief, sample, tol):
    """Height above the spheres' plane (pixels) whose solve leaves the least residual on ``sample``."""
    def score(offset):
        return _mean_residual(solve(_at_depth(lights, relief + offset), sample), sample)

    reach = 0.5 * float(np.median(np.linalg.norm(lights.positions, axis=1)))
    grid = np.linspace(-reach, reach, SCAN_STEPS)
    best = int(np.argmin([score(o) for o in grid]))
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    return float(golden_section(score, lo, hi, golden_steps(hi - lo, tol)))
