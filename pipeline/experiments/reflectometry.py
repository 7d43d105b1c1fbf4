"""Sec. 4 / Fig. 5: reflectometry from ONE image of a sphere of known shape under one light.

Every pixel of the sphere is one observation (n from the sphere, l known, v = (0, 0, 1)); the
biquadratic model then is a linear system A x = i (A: the 9 basis values times n.l). The fitted
biquadratic, Lafortune and Lambertian models re-render the sphere; the difference maps and
their MAE show how well each describes the material. A simulated sphere also has the bivariate
table model the paper compares with (:class:`pipeline.reflectance.bivariate.BivariateTable`:
rho(theta_h, theta_d) from the material's BRDF, averaged over phi_d; not fitted to the image, so
a user's image has no such row), each model with its parameter count.
"""

import numpy as np

from ..core.errors import InputError
from ..reflectance import Geometry, get_model
from ..reflectance.bivariate import BivariateTable
from ..reflectance.merl import read_merl
from .tables import Table

__all__ = ["REFLECTOMETRY_MODELS", "sphere_normals", "simulate_sphere", "parse_material",
           "reflectometry", "reflectometry_table", "reflectometry_figure", "parameter_count", "materials_comparison",
           "materials_table", "materials_figure", "COMPARED", "DEFAULT_LIGHT"]

REFLECTOMETRY_MODELS = ("biquadratic", "lafortune", "lambert")
DEFAULT_LIGHT = (0.4, 0.3, 0.866)


def sphere_normals(shape, circle):
    """Normals (H, W, 3) and mask (H, W) of an orthographic sphere.

    ``circle`` = (cx, cy, r) in pixels, column / row of the centre (row 0 at the top); pixels
    within 0.99 r are kept so that grazing rims with ill-defined normals are not.
    """
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    cx, cy, r = circle
    if r <= 0:
        raise InputError(f"sphere circle radius must be positive, got {r}")
    x, y = (cols - cx) / r, -(rows - cy) / r
    rr = x * x + y * y
    mask = rr < 0.99 ** 2
    z = np.sqrt(np.clip(1.0 - rr, 0.0, None))
    normals = np.where(mask[..., None], np.stack([x, y, z], -1), 0.0)
    return normals, mask


def parse_material(spec):
    """``cook-torrance[:m]``, ``ward[:m]`` (k_d = k_s = 1) or a MERL ``.binary`` path.

    Returns a function Geometry (...,) -> BRDF values (..., C) and the material's label.
    """
    name, _, arg = spec.partition(":")
    if name in ("cook-torrance", "ward"):
        try:
            m = float(arg) if arg else 0.3
        except ValueError:
            raise InputError(f"--simulate {spec!r}: roughness {arg!r} is not a number") from None
        model, params = get_model(name), np.array([1.0, 1.0, m])
        return (lambda g: model.evaluate(params, g)[..., None]), f"{name} m={m:g}"
    if spec.endswith(".binary"):
        brdf = read_merl(spec)
        return brdf.evaluate, brdf.name
    raise InputError(f"--simulate {spec!r}: expected cook-torrance[:m], ward[:m] or a MERL .binary file")


def simulate_sphere(material, light=DEFAULT_LIGHT, size=128):
    """Render rho (n.l) of a sphere filling a size x size image -> image (H, W, C), normals, mask."""
    normals, mask = sphere_normals((size, size), ((size - 1) / 2, (size - 1) / 2, size / 2 - 1))
    light = _unit(light)
    geometry = Geometry.from_vectors(normals[mask], light[None])
    rho = material(geometry)[:, 0, :]
    image = np.zeros((size, size, rho.shape[-1]))
    image[mask] = np.nan_to_num(rho) * np.clip(geometry.nl, 0, None)
    return image, normals, mask


def _unit(light):
    light = np.asarray(light, float)
    norm = np.linalg.norm(light)
    if light.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise InputError(f"light direction must be three numbers x,y,z, not all zero; got {light.tolist()}")
    return light / norm


def parameter_count(name, params):
    """Parameters per colour channel of a result of :func:`reflectometry`."""
    if isinstance(params, BivariateTable):
        return params.n_params
    return int(np.atleast_2d(params).shape[-1])


def reflectometry(image, normals, mask, light, models=REFLECTOMETRY_MODELS, saturation=None, material=None):
    """Fit each model to one image and re-render it.

    Parameters
    ----------
    image : ndarray (H, W, C)
        Linear radiance of the sphere.
    normals : ndarray (H, W, 3), mask : ndarray (H, W) bool
    light : (3,) unit direction toward the light, camera frame.
    saturation : float, optional
        Pixels at or above it are clipped and left out (a captured image: its white level).
    material : callable, optional
        The material's BRDF (Geometry -> (..., C)), when known (a simulated sphere): adds the
        ``bivariate`` table model, built from it (not fitted), after the fitted ones.

    Returns
    -------
    dict model name -> (params (C, P), or the BivariateTable, rendering (H, W, C), MAE over the
    used pixels); and the (H, W) bool map of the pixels used (lit, unclipped, positive).
    """
    light = _unit(light)
    geometry = Geometry.from_vectors(normals[mask], light[None])
    shading = np.clip(geometry.nl[:, 0], 0, None)
    values = image[mask].T  # (C, M)
    used = (shading > 1e-3) & np.all(values > 0, 0)
    if saturation is not None:
        used &= np.all(values < saturation, 0)
    if used.sum() < 9:
        raise InputError(f"only {used.sum()} lit, unclipped sphere pixels: need at least 9")
    flat = Geometry(*(np.broadcast_to(getattr(geometry, k), (used.size, 1))[:, 0]
                      for k in ("nl", "nv", "nh", "lh", "lv")))
    results = {}
    for name in models:
        model = get_model(name)
        params = model.fit(flat, values, shading=shading, weights=used.astype(float))
        rendered = np.zeros_like(image, dtype=float)
        rendered[mask] = (model.evaluate(params, flat) * shading).T
        mae = float(np.mean(np.abs(rendered[mask] - image[mask])[used]))
        results[name] = (params, rendered, mae)
    if material is not None:
        table = BivariateTable.from_material(material)
        rho = table.evaluate(flat)                                         # (M, C)
        rho = rho if rho.shape[1] == values.shape[0] else np.repeat(rho[:, :1], values.shape[0], axis=1)
        rendered = np.zeros_like(image, dtype=float)
        rendered[mask] = rho * shading[:, None]
        mae = float(np.mean(np.abs(rendered[mask] - image[mask])[used]))
        results["bivariate"] = (table, rendered, mae)
    used_map = np.zeros(mask.shape, bool)
    used_map[mask] = used
    return results, used_map


def reflectometry_table(results, label, image):
    bivariate = "bivariate" in results
    note = "Radiance units of the input image; mean over the lit, unclipped pixels. " + (
        "bivariate: the material's BRDF tabulated over (theta_h, theta_d) and averaged over phi_d, as the "
        "paper builds it (not fitted to the image)." if bivariate else
        "No bivariate table row: it is built from the material's BRDF, known only for a simulated sphere.")
    table = Table(f"Fig. 5: reflectometry from one image ({label})",
                  ["model", "MAE", "MAE / mean radiance", "parameters", "values (first channel)"], note=note)
    scale = float(np.mean(image[image > 0])) if np.any(image > 0) else 1.0
    for name, (params, _, mae) in results.items():
        shown = (f"table {params.table.shape[0]} x {params.table.shape[1]}" if isinstance(params, BivariateTable)
                 else " ".join(f"{p:.4g}" for p in np.atleast_2d(params)[0]))
        table.add(name, mae, mae / scale, parameter_count(name, params), shown)
    return table


#: the models of the materials comparison, in the paper's Fig. 5 order, with Lafortune beside
COMPARED = ("biquadratic", "bivariate", "lafortune", "lambert")


def materials_comparison(materials, light=DEFAULT_LIGHT, size=128):
    """Fig. 5 over many materials: MAE (materials, :data:`COMPARED`), relative MAE (the MAE over
    the sphere's mean radiance), the parameter counts (per model) and the labels.

    ``materials`` is a list of (label, BRDF function) (see :func:`parse_material`).
    """
    mae, relative, labels, counts = [], [], [], {}
    for label, material in materials:
        image, normals, mask = simulate_sphere(material, light, size)
        results, _ = reflectometry(image, normals, mask, light, material=material)
        scale = float(np.mean(image[image > 0]))
        mae.append([results[name][2] for name in COMPARED])
        relative.append([results[name][2] / scale for name in COMPARED])
        counts = {name: parameter_count(name, results[name][0]) for name in COMPARED}
        labels.append(label)
    return np.array(mae), np.array(relative), counts, labels


def materials_table(mae, relative, counts, labels, light=DEFAULT_LIGHT, size=128):
    header = ["material"] + [f"{name} ({counts[name]} params) MAE" for name in COMPARED] + \
        [f"{name} % of mean" for name in COMPARED]
    table = Table("Fig. 5 over psrig's analytic materials: reflectometry from one image of a sphere",
                  header, note=f"One simulated {size} px sphere per material, light "
                                f"{tuple(round(v, 3) for v in light)}, "
                                "k_d = k_s = 1; MAE in BRDF x n.l units over the lit pixels, and as a percentage of "
                                "the sphere's mean radiance. biquadratic, Lafortune, Lambert: fitted to the one image; "
                                "bivariate: the material's BRDF tabulated over (theta_h, theta_d), averaged over phi_d "
                                "(not fitted; parameters per colour channel).")
    for label, row, rel in zip(labels, mae, relative):
        table.add(label, *row, *(100 * rel))
    table.add("mean", *np.mean(mae, axis=0), *(100 * np.mean(relative, axis=0)))
    table.add("median", *np.median(mae, axis=0), *(100 * np.median(relative, axis=0)))
    return table


def materials_figure(relative, counts, labels):
    """Relative MAE per material, one line per model (log scale), parameter counts in the legend."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for j, name in enumerate(COMPARED):
        ax.semilogy(range(len(labels)), 100 * relative[:, j], marker="o", ms=3,
                    label=f"{name} ({counts[name]} parameters; mean {100 * np.mean(relative[:, j]):.2f} %)")
    ax.set_xticks(range(len(labels)), labels, rotation=60, fontsize=7, ha="right")
    ax.set_ylabel("MAE, % of the sphere's mean radiance")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def reflectometry_figure(image, results, used):
    """Top row: input and re-renderings; bottom row: |difference| maps with their MAE."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    fig, axes = plt.subplots(2, len(names) + 1, figsize=(3 * (len(names) + 1), 6))
    vmax = float(np.percentile(image[used], 99.5)) if used.any() else 1.0
    axes[0, 0].imshow(np.clip(image.mean(-1) / vmax, 0, 1), cmap="gray")
    axes[0, 0].set_title("input")
    diffs = [np.abs(results[n][1] - image).mean(-1) * used for n in names]
    dmax = max(float(d.max()) for d in diffs) or 1.0
    for j, name in enumerate(names, start=1):
        axes[0, j].imshow(np.clip(results[name][1].mean(-1) / vmax, 0, 1), cmap="gray")
        axes[0, j].set_title(name)
        axes[1, j].imshow(diffs[j - 1], cmap="jet", vmin=0, vmax=dmax)
        axes[1, j].set_title(f"MAE {results[name][2]:.3g}")
    for ax in axes.ravel():
        ax.axis("off")
    return fig
