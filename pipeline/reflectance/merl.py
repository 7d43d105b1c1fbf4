"""MERL measured isotropic BRDFs (Matusik et al. 2003): the ``.binary`` format and lookup.

File layout: three int32 dimensions (90, 90, 180) = (theta_h, theta_d, phi_d), then
3 x 90 x 90 x 180 float64 values channel-major (R block, G block, B block), scaled by
1/1500, 1.15/1500 and 1.66/1500. theta_h is indexed on a square-root scale
(index = sqrt(theta_h / (pi/2)) * 90), theta_d linearly over [0, pi/2), phi_d over [0, pi)
(reciprocity folds phi_d + pi onto phi_d). Negative entries mark unmeasured cells.
"""

from pathlib import Path

import numpy as np

from ..core.errors import ImageFileError
from ..core.atomic import atomic_write_bytes

__all__ = ["MerlBrdf", "read_merl", "write_merl", "MERL_SHAPE", "MERL_SCALE", "rusinkiewicz_angles"]

#: (theta_h, theta_d, phi_d) resolution of every MERL file.
MERL_SHAPE = (90, 90, 180)
#: Per-channel scale of the stored values (R, G, B).
MERL_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])


class MerlBrdf:
    """A MERL BRDF table; :meth:`evaluate` looks values up for a :class:`Geometry`.

    Attributes
    ----------
    table : ndarray (3, 90, 90, 180)
        Scaled BRDF values (R, G, B); NaN where unmeasured.
    name : str
        The file's stem (e.g. ``blue-rubber``).
    """

    def __init__(self, table, name=""):
        self.table = np.asarray(table, float)
        self.name = name

    def evaluate(self, geometry):
        """Nearest-cell BRDF values (..., K, 3) for cosines (..., K); NaN where unmeasured."""
        th, td, pd = rusinkiewicz_angles(geometry)
        ih = np.clip(np.sqrt(np.clip(th, 0, None) / (np.pi / 2)) * 90, 0, 89).astype(int)
        idd = np.clip(td / (np.pi / 2) * 90, 0, 89).astype(int)
        ip = np.clip(pd / np.pi * 180, 0, 179).astype(int)
        return np.moveaxis(self.table[:, ih, idd, ip], 0, -1)


def rusinkiewicz_angles(geometry):
    """theta_h, theta_d (radians) and phi_d in [0, pi] from a Geometry's cosines.

    With h as pole, n sits at theta_h in the phi = 0 half-plane, so
    n.l = cos th cos td - sin th sin td cos phi_d; isotropy and reciprocity make phi_d and
    -phi_d, phi_d + pi equivalent, so phi_d in [0, pi] from its cosine is enough.
    """
    nh = np.clip(np.asarray(geometry.nh, float), -1, 1)
    lh = np.clip(np.asarray(geometry.lh, float), -1, 1)
    th, td = np.arccos(nh), np.arccos(lh)
    denom = np.sqrt(1 - nh * nh) * np.sqrt(1 - lh * lh)
    cos_pd = np.where(denom > 1e-9, (nh * lh - np.asarray(geometry.nl, float))
                      / np.where(denom > 1e-9, denom, 1.0), 1.0)
    return th, td, np.arccos(np.clip(cos_pd, -1, 1))


def read_merl(path):
    """Read a MERL ``.binary`` file -> :class:`MerlBrdf`.

    Raises
    ------
    ImageFileError
        The file is missing, too short, or its header is not 90 x 90 x 180.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ImageFileError(f"{path}: cannot read MERL BRDF: {exc.strerror}") from None
    if len(raw) < 12:
        raise ImageFileError(f"{path}: not a MERL BRDF (shorter than its 12-byte header)")
    dims = tuple(int(d) for d in np.frombuffer(raw[:12], dtype="<i4"))
    if dims != MERL_SHAPE:
        raise ImageFileError(f"{path}: not a MERL BRDF: dimensions {dims}, expected {MERL_SHAPE}")
    count = 3 * int(np.prod(MERL_SHAPE))
    if len(raw) != 12 + 8 * count:
        raise ImageFileError(f"{path}: truncated MERL BRDF: {len(raw) - 12} data bytes, "
                             f"expected {8 * count}")
    table = np.frombuffer(raw[12:], dtype="<f8").reshape((3,) + MERL_SHAPE)
    table = np.where(table < 0, np.nan, table) * MERL_SCALE[:, None, None, None]
    return MerlBrdf(table, name=path.stem)


def write_merl(path, table):
    """Write a scaled table (3, 90, 90, 180) (NaN = unmeasured) as a MERL ``.binary`` file."""
    table = np.asarray(table, float)
    if table.shape != (3,) + MERL_SHAPE:
        raise ValueError(f"{path}: MERL table must be {(3,) + MERL_SHAPE}, got {table.shape}")
    stored = np.where(np.isnan(table), -1.0, table / MERL_SCALE[:, None, None, None])
    data = np.asarray(MERL_SHAPE, "<i4").tobytes() + stored.astype("<f8").tobytes()
    atomic_write_bytes(path, data)
