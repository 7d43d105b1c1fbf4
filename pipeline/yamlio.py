"""YAML in psrig's files: what may be written (plain types) and how it is read (safely).

Manifests, stage records, light files and rig files are YAML read with safe loading only.
What goes into them is first made plain (:func:`plain`): numpy scalars and arrays become
Python numbers and lists, tuples lists, paths strings, mapping keys strings, so that the file
holds no Python tags and reads back equal to what was compared.
"""

from pathlib import PurePath

import numpy as np

__all__ = ["plain"]


def plain(value, decimals=None):
    """A YAML-safe copy of ``value``, recursively.

    Parameters
    ----------
    value
        Mappings, sequences, numpy arrays and scalars, paths and plain values, nested.
    decimals : int, optional
        Round numpy arrays to this many decimals (rig geometry in files people read).
    """
    if isinstance(value, dict):
        return {str(k): plain(v, decimals) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v, decimals) for v in value]
    if isinstance(value, np.ndarray):
        return (value if decimals is None else np.round(value, decimals)).tolist()
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, np.generic):
        return value.item()
    return value
