"""Value checkers for rig files, and the error a bad rig file raises.

Each checker takes a value read from YAML and returns it cleaned, or raises ``ValueError``
saying what was expected; :mod:`rig.config` and every driver (:mod:`rig.drivers`, third-party
ones too) build their key tables from them, so one key is checked the same way everywhere.
"""

import numpy as np

from pipeline.core.errors import PsrigError

__all__ = ["ConfigError", "integer", "number", "usb_id", "text", "choice", "boolean", "mapping",
           "vectors", "vector"]


class ConfigError(PsrigError):
    """A rig file or rig definition is invalid; the message names the file, rig and key."""


def integer(low=None, high=None):
    """Checker of an integer (not a bool) in ``low .. high`` (either bound optional)."""
    def check(value):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError("expected an integer")
        if (low is not None and value < low) or (high is not None and value > high):
            raise ValueError(f"expected an integer >= {low}" if high is None
                             else f"expected an integer from {low} to {high}")
        return value
    return check


def number(low=0.0):
    """Checker of a finite number >= ``low``; returns a float."""
    def check(value):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError("expected a number")
        if not np.isfinite(value) or value < low:
            raise ValueError(f"expected a number >= {low:g}")
        return float(value)
    return check


def usb_id(value):
    """A USB vendor or product id: an integer 0-0xFFFF, or hex text such as '0x04a9'."""
    if isinstance(value, str):
        try:
            value = int(value, 16)
        except ValueError:
            raise ValueError("expected a USB id (an integer, or hex like 0x04a9)") from None
    return integer(0, 0xFFFF)(value)


def text(value):
    """A non-empty string."""
    if not isinstance(value, str) or not value.strip():
        raise ValueError("expected a non-empty string")
    return value


def choice(*options):
    """Checker of one of ``options``."""
    def check(value):
        if value not in options:
            raise ValueError(f"expected one of {', '.join(map(str, options))}")
        return value
    return check


def boolean(value):
    """A YAML boolean (a string such as 'no' is refused, not taken as true)."""
    if not isinstance(value, bool):
        raise ValueError("expected true or false")
    return value


def mapping(value):
    """A mapping; returns a plain dict copy."""
    if not isinstance(value, dict):
        raise ValueError("expected a mapping of keys to values")
    return dict(value)


def vectors(value):
    """K lists of 3 finite numbers; returns an array (K, 3)."""
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("expected lists of 3 numbers (x, y, z)") from None
    if array.ndim != 2 or array.shape[1] != 3 or len(array) == 0 or not np.isfinite(array).all():
        raise ValueError("expected lists of 3 numbers (x, y, z)")
    return array


def vector(value):
    """One list of 3 finite numbers; returns an array (3,)."""
    return vectors([value])[0]
