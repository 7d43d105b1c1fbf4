"""Sec. 3.1 / Fig. 3: the Cook-Torrance protocol on measured MERL BRDFs a user has.

No MERL file ships with psrig; point the experiment at a folder of ``*.binary`` files.
Samples are ranked by the mean of the three channels' radiance; each channel is fitted on its
own and the MAE is averaged over channels. Unmeasured cells are ignored.
"""

from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.progress import progress
from ..reflectance.merl import read_merl
from .cook_torrance import (DEFAULT_T_LOW, fit_mae, low_frequency_weights, pooled, protocol_geometry,
                            protocol_note)
from .tables import Table

__all__ = ["find_merl_files", "merl_samples", "merl_grid", "merl_table"]


def find_merl_files(folder):
    """Sorted ``*.binary`` files of ``folder``; InputError naming the folder when there are none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder of MERL .binary files")
    files = sorted(folder.glob("*.binary"))
    if not files:
        raise InputError(f"{folder}: no MERL .binary files in it")
    return files


def merl_samples(brdf, geometry):
    """BRDF values (3, N, K) of a MerlBrdf at the protocol geometry (N, K); NaN = unmeasured."""
    return np.moveaxis(brdf.evaluate(geometry), -1, 0)


def merl_grid(files, t_lows=DEFAULT_T_LOW, models=("biquadratic", "biquadratic-factorised"),
              **protocol):
    """MAE (len(models), len(files), len(t_lows)) over the given MERL files."""
    _, _, geometry = protocol_geometry(**protocol)
    lit = geometry.nl > 0
    mae = np.zeros((len(models), len(files), len(t_lows)))
    for i, path in enumerate(progress(files, desc="MERL materials", unit="file")):
        rho = merl_samples(read_merl(path), geometry)
        radiance = np.mean(rho, axis=0) * geometry.nl
        for j, t_low in enumerate(t_lows):
            geo, values = pooled(geometry, rho, low_frequency_weights(radiance, lit, t_low))
            for k, name in enumerate(models):
                mae[k, i, j] = fit_mae(name, geo, values)
    return mae


def merl_table(mae, files, t_lows, models, **protocol):
    """One row per (model, material), materials ordered by their mean MAE over T_low."""
    order = np.argsort(np.nanmean(mae[0], axis=-1), kind="stable")
    table = Table("Fig. 3: MAE of fitting MERL BRDFs' low-frequency samples",
                  ["model", "material"] + [f"T_low {t:.0%}" for t in t_lows],
                  note=f"BRDF units, mean over R, G, B; {protocol_note(**protocol)}.")
    for k, name in enumerate(models):
        for i in order:
            table.add(name, Path(files[i]).stem, *mae[k, i])
    return table, order
