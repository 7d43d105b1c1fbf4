"""Sec. 5.2 / Fig. 6: photometric stereo with every model, on a rendered two-material object
and on DiLiGenT.

Per pixel (all pixels at once): shadows (below 10 % of the pixel's 90th percentile) are dropped,
the darkest T_low of the rest kept, Lambertian PS starts, then the model's parameters (n fixed)
and n (rho fixed, linear least squares) alternate until the residual changes by less than 1e-7
(paper Eq. 8, 9). The rendered object is a sphere whose BRDF blends a Cook-Torrance and a Ward
material along smooth stripes, rendered by psrig's own models (100 lights, fixed seed).
"""

from pathlib import Path

import numpy as np

from ..core.progress import progress
from ..reflectance import Geometry, get_model, solve_batched
from .cook_torrance import low_frequency_weights
from .reflectometry import sphere_normals
from .tables import Table

__all__ = ["PS_METHODS", "render_two_materials", "alternating_normals", "angular_error",
           "run_methods", "run_diligent", "ps_table", "ps_figure", "DEFAULT_DILIGENT", "PSRIG_DEFAULT",
           "SEED"]

SEED = 2012
#: (label, model name, use only the low-frequency observations).
PS_METHODS = (("Lambert (all)", "lambert", False), ("Lambert (low)", "lambert", True),
              ("biquadratic", "biquadratic", True), ("bicubic", "bicubic", True),
              ("Lafortune", "lafortune", True), ("Cook-Torrance", "cook-torrance", True),
              ("Ward", "ward", True))
PSRIG_DEFAULT = "psrig default (estimate_normals)"
DEFAULT_DILIGENT = Path(__file__).resolve().parents[3] / "shared" / "data" / "diligent"
#: The two blended materials: (model, (k_d, k_s, m)).
#: Broad lobes, so that even the darkest observations are not Lambertian (as with the paper's
#: ALUM-BRONZE and CHERRY-235).
MATERIALS = (("cook-torrance", (0.3, 1.0, 0.5)), ("ward", (0.6, 0.6, 0.35)))


def _hemisphere_lights(count, seed, max_polar_deg=70.0):
    rng = np.random.default_rng(seed)
    z = rng.uniform(np.cos(np.radians(max_polar_deg)), 1.0, count)
    phi = rng.uniform(0, 2 * np.pi, count)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def render_two_materials(size=96, n_lights=100, seed=SEED):
    """Images (K, H, W), lights (K, 3), true normals (H, W, 3), mask (H, W), blend (H, W)."""
    normals, mask = sphere_normals((size, size), ((size - 1) / 2, (size - 1) / 2, size / 2 - 1))
    lights = _hemisphere_lights(n_lights, seed)
    rows, cols = np.mgrid[0:size, 0:size] / size
    blend = 0.5 + 0.5 * np.tanh(6 * np.sin(2 * np.pi * (2 * cols + rows)))
    geometry = Geometry.from_vectors(normals[mask], lights)
    rho = sum(weight[..., None] * get_model(name).evaluate(np.array(params), geometry)
              for weight, (name, params) in zip((blend[mask], 1 - blend[mask]), MATERIALS))
    images = np.zeros((n_lights, size, size))
    images[:, mask] = (rho * np.clip(geometry.nl, 0, None)).T
    return images, lights, normals, mask, blend


def _lambert_normals(intensities, lights, weights):
    b = solve_batched(np.broadcast_to(lights, intensities.shape + (3,)), intensities, weights)
    return _normalise(b, np.array([0.0, 0.0, 1.0]))


def _normalise(b, fallback):
    norm = np.linalg.norm(b, axis=-1, keepdims=True)
    ok = np.isfinite(norm) & (norm > 1e-12)
    return np.where(ok, b / np.where(ok, norm, 1.0), fallback)


def alternating_normals(intensities, lights, model_name, weights, max_iter=30, tol=1e-7):
    """Alternate model fit (n fixed) and normal solve (rho fixed), all pixels at once.

    A pixel whose residual changes by less than ``tol`` is frozen, so later iterations only
    touch the pixels still moving.

    Parameters
    ----------
    intensities : ndarray (N, K)
        Pixel values divided by light intensities.
    lights : ndarray (K, 3) or (N, K, 3)
    weights : ndarray (N, K)
        0/1 selection (non-shadowed, low-frequency).

    Returns
    -------
    normals (N, 3) and the number of iterations run.
    """
    normals = _lambert_normals(intensities, lights, weights)
    if model_name == "lambert":
        return normals, 0
    model = get_model(model_name)
    per_pixel = np.ndim(lights) == 3
    active = np.arange(len(normals))
    previous = np.full(len(normals), np.inf)
    for iteration in range(1, max_iter + 1):
        values, w = intensities[active], weights[active]
        light = lights[active] if per_pixel else lights
        normals[active], residual = _alternate_once(model, normals[active], light, values, w)
        moving = np.abs(previous[active] - residual) >= tol
        previous[active] = residual
        active = active[moving]
        if active.size == 0:
            break
    return normals, iteration


def _alternate_once(model, normals, lights, values, weights):
    """One fit of the model's parameters and one linear normal update; returns (n, residual)."""
    geometry = Geometry.from_vectors(normals, lights)
    params = model.fit(geometry, values, shading=np.clip(geometry.nl, 0, None), weights=weights)
    rho = np.nan_to_num(model.evaluate(params, geometry))
    normals = _normalise(solve_batched(rho[..., None] * lights, values, weights), normals)
    shading = np.clip(np.einsum("...kc,...c->...k", np.broadcast_to(lights, rho.shape + (3,)),
                                normals), 0, None)
    return normals, np.sum(weights * (values - rho * shading) ** 2, -1)


def angular_error(estimate, truth):
    """Angles (degrees) between unit normals (..., 3)."""
    cos = np.sum(estimate * truth, -1) / np.maximum(
        np.linalg.norm(estimate, axis=-1) * np.linalg.norm(truth, axis=-1), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def run_methods(images, lights, mask, truth, t_low=0.25, methods=PS_METHODS, shadow=0.1,
                psrig_default=True):
    """Mean angular error (degrees) and error map (H, W) for each method.

    images (K, H, W) linear, lights (K, 3), mask (H, W), truth (H, W, 3). ``shadow``: fraction
    of each pixel's 90th percentile below which an observation counts as shadowed.
    With ``psrig_default``, one more row: psrig's own default estimator
    (:func:`pipeline.photometric.estimate_normals`, robust selection, no T_low).
    """
    intensities = images[:, mask].T.astype(float)
    # Shadows: below ``shadow`` x the pixel's 90th percentile (the brightest value is often a
    # specular spike, too unstable a reference on real objects).
    lit = intensities > shadow * np.percentile(intensities, 90, axis=-1, keepdims=True)
    low = low_frequency_weights(intensities, lit, t_low)
    results = {}
    compact = _compact(intensities, lights, low)
    for label, name, use_low in progress(methods, desc="PS methods", unit="method"):
        if use_low:
            normals, _ = alternating_normals(compact[0], compact[1], name, compact[2])
        else:
            normals, _ = alternating_normals(intensities, lights, name, np.ones_like(intensities))
        results[label] = _scored(normals, truth, mask)
    if psrig_default:
        from ..photometric import estimate_normals

        estimate = estimate_normals(images.astype(np.float32), lights, mask)
        results[PSRIG_DEFAULT] = _scored(estimate.normals[mask].astype(float), truth, mask)
    return results


def _scored(normals, truth, mask):
    """(mean angular error, error map (H, W)) of normals (M, 3) at the mask's pixels."""
    error = np.zeros(mask.shape)
    error[mask] = angular_error(normals, truth[mask])
    return float(error[mask].mean()), error


def _compact(intensities, lights, weights):
    """Keep only the selected observations: (N, Kmax) values, (N, Kmax, 3) lights, weights.

    The fits cost in proportion to K, and T_low keeps a quarter of it.
    """
    order = np.argsort(-weights, axis=-1, kind="stable")
    kmax = max(int(weights.sum(-1).max()), 1)
    order = order[:, :kmax]
    take = lambda a: np.take_along_axis(a, order, axis=-1)  # noqa: E731
    return take(intensities), lights[order], take(weights)


def ps_table(columns, t_low=0.25, shadow_note=""):
    """``columns``: dict dataset label -> run_methods result."""
    table = Table(f"Fig. 6: photometric stereo, mean angular error (degrees), T_low = {t_low:.0%}",
                  ["method"] + list(columns),
                  note="Lambert (all) uses every observation; the others the darkest T_low of "
                       "the non-shadowed ones (the paper's rule, psrig's own implementation in "
                       "pipeline.experiments.ps); the last row is psrig's default estimator. "
                       + shadow_note)
    for label in [m[0] for m in PS_METHODS] + [PSRIG_DEFAULT]:
        if any(label in results for results in columns.values()):
            table.add(label, *[columns[c][label][0] if label in columns[c] else float("nan")
                               for c in columns])
    return table


def ps_figure(results, truth, mask, image):
    """Fig. 6 style: an input image, the true normals, and each method's error map."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = len(results) + 2
    fig, axes = plt.subplots(1, panels, figsize=(2.4 * panels, 2.8))
    axes[0].imshow(np.clip(image / max(float(image.max()), 1e-12), 0, 1), cmap="gray")
    axes[0].set_title("input", fontsize=8)
    axes[1].imshow(np.where(mask[..., None], (truth + 1) / 2, 0))
    axes[1].set_title("true normals", fontsize=8)
    vmax = max(float(np.percentile(err[mask], 99)) for _, err in results.values()) or 1.0
    for ax, (label, (mean, err)) in zip(axes[2:], results.items()):
        ax.imshow(np.where(mask, err, np.nan), cmap="jet", vmin=0, vmax=vmax)
        ax.set_title(f"{label}\n{mean:.2f} deg", fontsize=8)
    for ax in axes:
        ax.axis("off")
    return fig


def run_diligent(folder, t_low=0.25, methods=PS_METHODS, shadow=0.1, psrig_default=True):
    """run_methods on a DiLiGenT object folder (grey images divided by the light intensities)."""
    from ..importers import read_diligent
    from ..core.errors import InputError

    obj = read_diligent(folder)
    if obj.normals_gt is None:
        raise InputError(f"{folder}: no Normal_gt.mat to score against")
    images = obj.load_images(grey=True)[0]
    lights = obj.directions / np.linalg.norm(obj.directions, axis=1, keepdims=True)
    return run_methods(images, lights, obj.mask, obj.normals_gt, t_low, methods, shadow, psrig_default)
