"""Sec. 3.1 / Fig. 2: fit the biquadratic model to Cook-Torrance's low-frequency samples.

Protocol (shared with :mod:`.merl` and :mod:`.models`): view v = (0, 0, 1); 1620 normals from
36 longitudes x 45 altitudes of the visible hemisphere; 100 random lights on the upper
hemisphere (fixed seed); per normal, the non-shadowed samples are sorted by radiance
rho (n.l) and those ranked below T_low are kept. One model is fitted to the BRDF values of all
kept samples of all normals at once (it is one material), and the error is the mean absolute
difference of the BRDF values over those samples.
"""

import numpy as np

from ..core.progress import progress
from ..reflectance import Geometry, get_model
from .tables import Table

__all__ = ["protocol_geometry", "low_frequency_weights", "pooled", "fit_mae",
           "cook_torrance_grid", "cook_torrance_table", "protocol_note", "heatmap_figure", "DEFAULT_ROUGHNESS",
           "DEFAULT_T_LOW", "SEED"]

SEED = 2012
DEFAULT_ROUGHNESS = (0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0)
DEFAULT_T_LOW = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)


def protocol_geometry(n_longitudes=36, n_altitudes=45, n_lights=100, seed=SEED):
    """Normals, lights and their cosines for the Sec. 3.1 protocol.

    Returns
    -------
    normals : ndarray (N, 3)
        N = n_longitudes * n_altitudes, polar angles at the centres of n_altitudes equal
        steps of [0, 90) degrees, camera frame.
    lights : ndarray (K, 3)
        K = n_lights directions uniform on the upper hemisphere (z > 0).
    geometry : Geometry
        Cosines (N, K).
    """
    polar = (np.arange(n_altitudes) + 0.5) * (np.pi / 2) / n_altitudes
    azimuth = np.arange(n_longitudes) * 2 * np.pi / n_longitudes
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    normals = np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], -1).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.0, 1.0, n_lights)
    phi = rng.uniform(0.0, 2 * np.pi, n_lights)
    r = np.sqrt(1 - z * z)
    lights = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
    return normals, lights, Geometry.from_vectors(normals, lights)


def low_frequency_weights(radiance, lit, t_low):
    """0/1 weights (N, K) of the non-shadowed samples ranked below ``t_low`` per row.

    Parameters
    ----------
    radiance : ndarray (N, K)
        Values to rank (rho (n.l)); NaN counts as unusable.
    lit : ndarray (N, K) bool
        Non-shadowed samples.
    t_low : float
        Fraction in (0, 1]; each row keeps ceil(t_low * its lit count) samples.
    """
    usable = lit & np.isfinite(radiance)
    key = np.where(usable, radiance, np.inf)
    ranks = np.argsort(np.argsort(key, axis=-1, kind="stable"), axis=-1)
    keep = np.ceil(t_low * usable.sum(-1, keepdims=True) - 1e-9)
    return (usable & (ranks < keep)).astype(float)


def pooled(geometry, values, weights):
    """Flatten the kept samples of all rows into one observation set.

    values (..., N, K) with weights (N, K) -> Geometry (M,), values (..., M).
    """
    keep = weights > 0
    cos = {name: np.broadcast_to(getattr(geometry, name), keep.shape)[keep]
           for name in ("nl", "nv", "nh", "lh", "lv")}
    return Geometry(**cos), np.asarray(values)[..., keep]


def fit_mae(model_name, geometry, values):
    """Fit a model to BRDF values (..., M) (NaN ignored) and return the MAE over finite samples."""
    model = get_model(model_name)
    finite = np.isfinite(values)
    params = model.fit(geometry, np.nan_to_num(values), weights=finite.astype(float))
    fitted = model.evaluate(params, geometry)
    return float(np.mean(np.abs(fitted - values)[finite]))


def cook_torrance_grid(roughness=DEFAULT_ROUGHNESS, t_lows=DEFAULT_T_LOW, models=("biquadratic",
                       "biquadratic-factorised"), strengths=(1.0, 1.0), **protocol):
    """MAE (len(models), len(roughness), len(t_lows)) of each model on Cook-Torrance samples.

    ``strengths`` = (k_d, k_s) of the generating material (the paper: equal).
    """
    _, _, geometry = protocol_geometry(**protocol)
    lit = geometry.nl > 0
    ct = get_model("cook-torrance")
    mae = np.zeros((len(models), len(roughness), len(t_lows)))
    for i, m in enumerate(progress(roughness, desc="Cook-Torrance roughness")):
        rho = ct.evaluate(np.array([strengths[0], strengths[1], m]), geometry)
        for j, t_low in enumerate(t_lows):
            weights = low_frequency_weights(rho * geometry.nl, lit, t_low)
            geo, values = pooled(geometry, rho, weights)
            for k, name in enumerate(models):
                mae[k, i, j] = fit_mae(name, geo, values)
    return mae


def protocol_note(n_longitudes=36, n_altitudes=45, n_lights=100, seed=SEED):
    """One line describing the sampling, for table notes."""
    return (f"{n_longitudes * n_altitudes} normals ({n_longitudes} longitudes x {n_altitudes} "
            f"altitudes) x {n_lights} random lights (seed {seed}), view (0, 0, 1)")


def cook_torrance_table(mae, roughness, t_lows, models, **protocol):
    """One row per (model, m), one column per T_low."""
    table = Table("Fig. 2: MAE of fitting Cook-Torrance (k_d = k_s = 1) low-frequency samples",
                  ["model", "m"] + [f"T_low {t:.0%}" for t in t_lows],
                  note=f"BRDF units (1/sr); {protocol_note(**protocol)}.")
    for k, name in enumerate(models):
        for i, m in enumerate(progress(roughness, desc="Cook-Torrance roughness")):
            table.add(name, f"{m:g}", *mae[k, i])
    return table


def heatmap_figure(mae, row_labels, t_lows, titles, ylabel):
    """Fig. 2/3 style: one colour-coded MAE matrix per model (log scale), rows x T_low columns."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    fig, axes = plt.subplots(1, len(titles), squeeze=False, layout="constrained",
                             figsize=(5 * len(titles), 0.35 * len(row_labels) + 2))
    positive = mae[np.isfinite(mae) & (mae > 0)]
    vmax = positive.max() if positive.size else 1.0
    norm = LogNorm(vmin=max(positive.min() if positive.size else 1e-6, vmax * 1e-6), vmax=vmax)
    for ax, grid, title in zip(axes[0], mae, titles):
        image = ax.imshow(np.clip(grid, norm.vmin, None), cmap="jet", norm=norm, aspect="auto")
        ax.set_xticks(range(len(t_lows)), [f"{t:.0%}" for t in t_lows], fontsize=7)
        ax.set_yticks(range(len(row_labels)), row_labels, fontsize=7)
        ax.set_xlabel("T_low")
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=9)
    fig.colorbar(image, ax=axes[0].tolist(), label="MAE (log scale)")
    return fig
