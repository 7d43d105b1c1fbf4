"""Lights in memory (:class:`LightSet`) and psrig's own ``lights.yaml``.

Directions are unit vectors (K, 3) from the surface toward the light, camera frame (x right,
y up, z toward the camera), in frame order. Intensities are (K, C), one value per light and
colour channel (C = 1 or 3).
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from ..atomic import atomic_write_text
from ..errors import InputError
from ..yamlio import dump_yaml, load_yaml

__all__ = ["LightSet", "read_lights_yaml", "write_lights_yaml", "check_directions", "check_intensities",
           "flag_behind"]


@dataclass
class LightSet:
    """Calibrated or nominal lights.

    Attributes
    ----------
    directions : ndarray (K, 3)
        Unit vectors toward each light, camera frame.
    intensities : ndarray (K, C)
        Relative intensity per light and colour channel (1.0 when unknown).
    positions : ndarray (K, 3) or None
        Light positions in the camera frame (same unit as the scene), for near lights.
    flags : dict
        {light index: reason} for doubtful lights.
    source : str
        How the lights were obtained.
    filenames : list of str or None
        Image names from an ``.lp`` file.
    extra : dict
        Other keys of ``lights.yaml`` (residuals, method, ...), kept as read.
    """

    directions: np.ndarray
    intensities: np.ndarray = None
    positions: np.ndarray = None
    flags: dict = field(default_factory=dict)
    source: str = ""
    filenames: list = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        self.directions = check_directions(self.directions, "directions")
        if self.intensities is None:
            self.intensities = np.ones((len(self.directions), 1))
        self.intensities = np.asarray(self.intensities, float)
        if self.intensities.ndim == 1:
            self.intensities = self.intensities[:, None]
        if len(self.intensities) != len(self.directions):
            raise InputError(f"intensities: {len(self.intensities)} rows for {len(self.directions)} lights")
        if self.positions is not None:
            self.positions = np.asarray(self.positions, float)
            _check_finite(self.positions, "positions", "position")
        _check_finite(self.intensities, "intensities", "intensity")

    def __len__(self):
        return len(self.directions)


def _check_finite(values, key, what):
    """InputError naming the first light whose ``values`` (K, ...) hold a NaN or an infinity:
    a NaN intensity would blank every pixel, an infinite one silently drop its light."""
    bad = ~np.isfinite(values).reshape(len(values), -1).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"{key}: light {k} has a non-finite {what} {np.asarray(values[k]).tolist()}")


def check_directions(directions, where="lights"):
    """Validate and normalise light directions; returns float64 (K, 3) unit vectors."""
    d = np.asarray(directions, dtype=float)
    if d.ndim != 2 or d.shape[1] != 3:
        raise InputError(f"{where}: light directions must be K x 3, got shape {d.shape}")
    bad = ~np.isfinite(d).all(axis=1)
    if bad.any():
        raise InputError(f"{where}: light {int(np.argmax(bad))} has a non-finite direction")
    with np.errstate(over="ignore"):
        norm = np.linalg.norm(d, axis=1)
    # the norm of (1e308, 1e308, 0) overflows: such rows are scaled by their largest component
    # first (the others are divided by their norm as they are, to the last bit)
    huge = ~np.isfinite(norm)
    if huge.any():
        d, norm = d.copy(), norm.copy()
        d[huge] /= np.abs(d[huge]).max(axis=1, keepdims=True)
        norm[huge] = np.linalg.norm(d[huge], axis=1)
    if (norm < 1e-9).any():
        k = int(np.argmax(norm < 1e-9))
        raise InputError(f"{where}: light {k} has a zero direction vector {d[k].tolist()}")
    return d / norm[:, None]


def check_intensities(values, count, where="intensities"):
    """Validate intensities for ``count`` lights: (K,), (K, 1) or (K, 3), or the transpose of
    (K, 1) / (K, 3); returns float64 (K, C). Each must be finite and positive."""
    data = np.asarray(values, dtype=float)
    if data.ndim == 1:
        data = data[:, None]
    if data.ndim == 2 and data.shape[0] in (1, 3) and data.shape[1] == count and data.shape[0] != count:
        data = data.T
    if data.ndim != 2 or data.shape[0] != count or data.shape[1] not in (1, 3):
        raise InputError(f"{where}: expected {count} rows of 1 or 3 values (one per light, one per colour "
                         f"channel), got shape {data.shape}")
    bad = ~np.isfinite(data).all(axis=1) | (data <= 0).any(axis=1)
    if bad.any():
        raise InputError(f"{where}: light {int(np.argmax(bad))} has an intensity that is not a positive "
                         f"number ({data[int(np.argmax(bad))].tolist()})")
    return data


def flag_behind(lights, where="lights"):
    """Flag (in ``lights.flags``) every light with z <= 0, which cannot light a surface the
    camera sees from the front; returns their indices.

    More than half of them so is taken as a file whose z axis points away from the camera
    (another convention) and refused: flagging them all would leave too few lights.
    """
    behind = np.flatnonzero(lights.directions[:, 2] <= 0)
    if len(behind) > len(lights) / 2:
        raise InputError(f"{where}: {len(behind)} of {len(lights)} lights have z <= 0 (pointing away from the "
                         "camera); psrig's frame has x right, y up, z toward the camera: negate z (and y if the "
                         "file's y points down) and import again")
    for k in behind:
        lights.flags.setdefault(int(k), f"z = {lights.directions[k, 2]:.3f} <= 0: the light is behind the "
                                        "surface, facing away from the camera")
    return [int(k) for k in behind]


def read_lights_yaml(path, foreign=None):
    """Read ``lights.yaml`` into a :class:`LightSet`, naming the key at fault on error.

    ``foreign``: for a file the user named as a light file, what to add when the document has
    no ``directions`` (it is then some other YAML or JSON, not a lights.yaml missing a key).
    """
    path = Path(path)
    try:
        data = load_yaml(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {exc}") from None
    if foreign and not (isinstance(data, dict) and "directions" in data):
        found = f"keys {', '.join(map(str, list(data)[:6]))}" if isinstance(data, dict) else \
            f"a {type(data).__name__}"
        raise InputError(f"{path}: not a light file psrig reads (a YAML/JSON document with {found}, no "
                         f"'directions'); {foreign}")
    if not isinstance(data, dict) or "directions" not in data:
        raise InputError(f"{path}: missing key 'directions'")
    try:
        dirs = np.asarray(data["directions"], dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{path}: key 'directions' must be K lists of x, y, z") from None
    intensities = data.get("intensities")
    positions = data.get("positions")
    try:
        lights = LightSet(
            check_directions(dirs, f"{path}: directions"),
            intensities=None if intensities is None else np.asarray(intensities, float),
            positions=None if positions is None else np.asarray(positions, float),
            flags={int(k): str(v) for k, v in (data.get("flags") or {}).items()},
            source=str(data.get("source", "")),
            filenames=data.get("filenames"),
            extra={k: v for k, v in data.items()
                   if k not in ("directions", "intensities", "positions", "flags", "source", "filenames")},
        )
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from None
    if lights.positions is not None and lights.positions.shape != lights.directions.shape:
        raise InputError(f"{path}: key 'positions' must be K x 3 like 'directions'")
    return lights


def write_lights_yaml(path, lights):
    """Write a :class:`LightSet` to ``lights.yaml`` atomically."""
    data = {"directions": np.round(lights.directions, 8).tolist(),
            "intensities": np.round(lights.intensities, 8).tolist()}
    if lights.positions is not None:
        data["positions"] = np.round(np.asarray(lights.positions, float), 8).tolist()
    if lights.flags:
        data["flags"] = {int(k): str(v) for k, v in lights.flags.items()}
    data["source"] = lights.source
    if lights.filenames:
        data["filenames"] = list(lights.filenames)
    data.update(lights.extra)
    atomic_write_text(path, dump_yaml(data))
