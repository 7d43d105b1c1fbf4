"""Display transfer functions (gamma): the sRGB curve and power laws, both ways.

8-bit photos (and some 16-bit ones) store display-encoded values. Decoding undoes the encoding
to get linear light (:func:`inverse_gamma_lut`); calibration re-encodes linear frames to find sphere outlines on
the values the camera sharpened (:func:`encode_gamma`).
"""

import numpy as np

from .errors import InputError

__all__ = ["parse_gamma", "inverse_gamma_lut", "encode_gamma", "NAMES"]


#: named transfer functions: 'auto' (decode: what each file declares, else a default by bit
#: depth), the sRGB curve, and linear (no encoding, the same as 1.0)
NAMES = ("auto", "srgb", "linear")


def parse_gamma(gamma, *, allow_auto=True):
    """'auto', 'srgb', 'linear' or a positive number (the encoding exponent, e.g. 2.2);
    returns it normalised ('linear' for 1)."""
    if isinstance(gamma, str) and gamma.strip().lower() in NAMES:
        name = gamma.strip().lower()
        if name == "auto" and not allow_auto:
            raise InputError("gamma: 'auto' is only a decoding option; expected 'srgb', 'linear' or a number")
        return name
    try:
        value = float(gamma)
    except (TypeError, ValueError):
        raise InputError(f"gamma: expected auto, srgb, linear or a number, got {gamma!r}") from None
    if not 0.1 <= value <= 10:
        raise InputError(f"gamma: {value} is out of range (0.1 .. 10)")
    return "linear" if value == 1.0 else value


def inverse_gamma_lut(gamma, levels=256):
    """Linear value of each 8-bit code.

    Parameters
    ----------
    gamma : 'srgb', 'linear' or float
        The encoding: the sRGB curve (IEC 61966-2-1), none, or code = linear ** (1 / gamma).
    levels : int
        Number of codes: 256 (8-bit) or 65536 (16-bit).

    Returns
    -------
    ndarray (levels,) float32
    """
    code = np.arange(levels, dtype=np.float64) / (levels - 1)
    gamma = parse_gamma(gamma, allow_auto=False)
    if gamma == "linear":
        return code.astype(np.float32)
    if gamma == "srgb":
        linear = np.where(code <= 0.04045, code / 12.92, ((code + 0.055) / 1.055) ** 2.4)
    else:
        linear = code ** float(gamma)
    return linear.astype(np.float32)


def encode_gamma(linear, gamma):
    """Display-encode linear values (any shape, 0..1): the inverse of :func:`inverse_gamma_lut`.

    Returns float32 codes in 0..1 (not quantised).
    """
    x = np.clip(np.asarray(linear, np.float32), 0, 1)
    gamma = parse_gamma(gamma, allow_auto=False)
    if gamma == "linear":
        return x
    if gamma == "srgb":
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055).astype(np.float32)
    return (x ** (1 / float(gamma))).astype(np.float32)
