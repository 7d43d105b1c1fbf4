"""Display transfer functions (gamma): the sRGB curve and power laws, both ways.

8-bit photos store display-encoded values. Decoding undoes the encoding to get linear light
(:func:`inverse_gamma_lut`); calibration re-encodes linear frames to find sphere outlines on
the values the camera sharpened (:func:`encode_gamma`).
"""

import numpy as np

from .errors import InputError

__all__ = ["parse_gamma", "inverse_gamma_lut", "encode_gamma"]


def parse_gamma(gamma):
    """'srgb' or a positive number (the encoding exponent, e.g. 2.2); returns it normalised."""
    if isinstance(gamma, str) and gamma.strip().lower() == "srgb":
        return "srgb"
    try:
        value = float(gamma)
    except (TypeError, ValueError):
        raise InputError(f"gamma: expected 'srgb' or a number, got {gamma!r}") from None
    if not 0.1 <= value <= 10:
        raise InputError(f"gamma: {value} is out of range (0.1 .. 10)")
    return value


def inverse_gamma_lut(gamma, levels=256):
    """Linear value of each 8-bit code.

    Parameters
    ----------
    gamma : 'srgb' or float
        The encoding: the sRGB curve (IEC 61966-2-1) or code = linear ** (1 / gamma).

    Returns
    -------
    ndarray (levels,) float32
    """
    code = np.arange(levels, dtype=np.float64) / (levels - 1)
    if parse_gamma(gamma) == "srgb":
        linear = np.where(code <= 0.04045, code / 12.92, ((code + 0.055) / 1.055) ** 2.4)
    else:
        linear = code ** float(gamma)
    return linear.astype(np.float32)


def encode_gamma(linear, gamma):
    """Display-encode linear values (any shape, 0..1): the inverse of :func:`inverse_gamma_lut`.

    Returns float32 codes in 0..1 (not quantised).
    """
    x = np.clip(np.asarray(linear, np.float32), 0, 1)
    if parse_gamma(gamma) == "srgb":
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055).astype(np.float32)
    return (x ** (1 / float(gamma))).astype(np.float32)
