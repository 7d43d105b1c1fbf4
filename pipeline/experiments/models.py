"""Sec. 3.2-3.3 / Fig. 4: every model fitted to the low-frequency samples (T_low = 25 %).

Materials: Cook-Torrance and Ward with k_d = k_s = 1 over a few roughness values, plus any MERL
files given. The nonlinear models (Cook-Torrance, Ward) are fitted by their batched
variable-projection fit and then polished with scipy.optimize.least_squares (bounded), as the
paper does with lsqnonlin.
"""

from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from ..core.progress import progress
from ..reflectance import Geometry, get_model
from ..reflectance.cook_torrance import ROUGHNESS_RANGE, LambertSpecular
from ..reflectance.merl import read_merl
from .cook_torrance import low_frequency_weights, pooled, protocol_geometry, protocol_note
from .merl import merl_samples
from .tables import Table

__all__ = ["MODEL_COLUMNS", "synthetic_materials", "fit_model_mae", "models_comparison",
           "models_table", "models_figure"]

#: (column label, registered model name), in the order of the paper's Fig. 4 legend.
MODEL_COLUMNS = (
    ("biquadratic (relax.)", "biquadratic"), ("biquadratic (iter.)", "biquadratic-factorised"),
    ("Lafortune", "lafortune"), ("Ashikhmin", "ashikhmin"), ("Cook-Torrance", "cook-torrance"),
    ("Ward", "ward"), ("bilinear", "bilinear"), ("bicubic", "bicubic"), ("Lambert", "lambert"),
)


def synthetic_materials(roughness=(0.1, 0.2, 0.3, 0.5, 0.7)):
    """(label, model name, params) of the generated materials, k_d = k_s = 1."""
    return [(f"{name} m={m:g}", name, np.array([1.0, 1.0, m]))
            for name in ("cook-torrance", "ward") for m in roughness]


def _polish(model, params, geometry, values):
    """Refine (k_d, k_s, m) of one channel with bounded scipy least squares."""
    def residual(p):
        return model.evaluate(p, geometry) - values

    lower, upper = [0.0, 0.0, ROUGHNESS_RANGE[0]], [np.inf, np.inf, ROUGHNESS_RANGE[1]]
    start = np.clip(params, lower, np.minimum(upper, 1e6))
    return least_squares(residual, start, bounds=(lower, upper), x_scale="jac").x


def fit_model_mae(name, geometry, values):
    """MAE of model ``name`` fitted to values (C, M) (one fit per channel), mean over channels."""
    model = get_model(name)
    finite = np.isfinite(values)
    clean = np.nan_to_num(values)
    params = model.fit(geometry, clean, weights=finite.astype(float))
    if isinstance(model, LambertSpecular):
        params = np.stack([_polish(model, params[c], _select(geometry, finite[c]), values[c][finite[c]])
                           if finite[c].any() else params[c] for c in range(len(values))])
    errors = np.abs(model.evaluate(params, geometry) - values)
    return float(np.mean([np.mean(e[f]) for e, f in zip(errors, finite) if f.any()]))


def _select(geometry, keep):
    """The observations where ``keep`` (M,) is True, as a Geometry of 1-D arrays."""
    return Geometry(**{k: np.broadcast_to(getattr(geometry, k), keep.shape)[keep]
                       for k in ("nl", "nv", "nh", "lh", "lv")})


def models_comparison(merl_files=(), t_low=0.25, roughness=(0.1, 0.2, 0.3, 0.5, 0.7), **protocol):
    """MAE (materials, models) and the material labels."""
    _, _, geometry = protocol_geometry(**protocol)
    lit = geometry.nl > 0
    labels, rows = [], []
    sources = [(label, lambda n=name, p=params: get_model(n).evaluate(p, geometry)[None])
               for label, name, params in synthetic_materials(roughness)]
    sources += [(Path(f).stem, lambda f=f: merl_samples(read_merl(f), geometry)) for f in merl_files]
    for label, make in progress(sources, desc="materials", unit="material"):
        rho = make()
        weights = low_frequency_weights(np.mean(rho, 0) * geometry.nl, lit, t_low)
        geo, values = pooled(geometry, rho, weights)
        labels.append(label)
        rows.append([fit_model_mae(name, geo, values) for _, name in MODEL_COLUMNS])
    return np.array(rows), labels


def models_table(mae, labels, t_low=0.25, **protocol):
    """Rows: materials, then mean and median; columns: models."""
    table = Table(f"Fig. 4: MAE of every model on low-frequency samples (T_low = {t_low:.0%})",
                  ["material"] + [label for label, _ in MODEL_COLUMNS],
                  note=f"BRDF units; synthetic materials have k_d = k_s = 1; {protocol_note(**protocol)}.")
    for label, row in zip(labels, mae):
        table.add(label, *row)
    table.add("mean", *np.mean(mae, axis=0))
    table.add("median", *np.median(mae, axis=0))
    return table


def models_figure(mae, labels):
    """Fig. 4 style: MAE per material (ordered by the relaxed biquadratic), one line per model."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = np.argsort(mae[:, 0], kind="stable")
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for j, (label, _) in enumerate(MODEL_COLUMNS):
        ax.semilogy(range(len(order)), mae[order, j], marker="o", ms=3,
                    label=f"{label} ({np.mean(mae[:, j]):.2e}/{np.median(mae[:, j]):.2e})")
    ax.set_xticks(range(len(order)), [labels[i] for i in order], rotation=60, fontsize=7, ha="right")
    ax.set_ylabel("MAE (mean/median in legend)")
    ax.legend(fontsize=7)
    return fig
