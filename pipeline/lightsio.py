"""Light files: ``lights.yaml``, the RTI ``.lp`` format and plain text direction lists.

Directions are unit vectors (K, 3) from the surface toward the light, camera frame (x right,
y up, z toward the camera), in frame order. Intensities are (K, C), one value per light and
colour channel (C = 1 or 3).
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .atomic import atomic_write_text
from .errors import InputError
from .yamlio import dump_yaml, load_yaml

__all__ = ["LightSet", "read_lights", "read_lights_text", "read_lp", "write_lp",
           "read_lights_yaml", "write_lights_yaml", "check_directions"]


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
    norm = np.linalg.norm(d, axis=1)
    if (norm < 1e-9).any():
        raise InputError(f"{where}: light {int(np.argmax(norm < 1e-9))} has a zero direction vector")
    return d / norm[:, None]


def read_lights(path):
    """Read lights from ``.yaml``/``.yml``, ``.lp`` or plain text (``x y z`` per line)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: light file not found")
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml"):
        return read_lights_yaml(path)
    if suffix == ".lp":
        names, dirs = read_lp(path)
        return LightSet(dirs, filenames=names, source=f"imported from {path.name}")
    return LightSet(read_lights_text(path), source=f"imported from {path.name}")


def _numeric_rows(path):
    rows = []
    for lineno, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            rows.append((lineno, [float(t) for t in line.replace(",", " ").split()]))
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a row of numbers: {line!r}") from None
    return rows


def read_lights_text(path):
    """Directions from text: ``x y z`` per line, optionally after a count line.

    A 3-row file with more than 3 columns (lights as columns, as PSBox and MATLAB write them) is
    transposed.
    """
    path = Path(path)
    rows = _numeric_rows(path)
    if rows and len(rows[0][1]) == 1:
        count = rows[0][1][0]
        rows = rows[1:]
        if count != len(rows):
            raise InputError(f"{path}: the count line says {count:g} lights but {len(rows)} follow")
    widths = {len(r) for _, r in rows}
    if not rows or len(widths) != 1:
        raise InputError(f"{path}: expected rows of 3 numbers (x y z), found rows of {sorted(widths)} numbers")
    data = np.array([r for _, r in rows])
    if data.shape[0] == 3 and data.shape[1] > 3:
        data = data.T
    if data.shape[1] != 3:
        raise InputError(f"{path}: expected 3 numbers per light (x y z), found {data.shape[1]}")
    return check_directions(data, str(path))


def read_lp(path):
    """Read an RTI ``.lp`` file: first line N, then ``filename x y z`` per light."""
    path = Path(path)
    lines = [ln.strip() for ln in path.read_text(encoding="utf-8", errors="replace").splitlines() if ln.strip()]
    try:
        count = int(lines[0].split()[0])
    except (IndexError, ValueError):
        raise InputError(f"{path}:1: an .lp file starts with the light count") from None
    names, dirs = [], []
    for lineno, line in enumerate(lines[1:], 2):
        parts = line.split()
        try:
            names.append(parts[0])
            dirs.append([float(v) for v in parts[1:4]])
            if len(parts) < 4:
                raise ValueError
        except (ValueError, IndexError):
            raise InputError(f"{path}:{lineno}: expected 'filename x y z', got {line!r}") from None
    if len(names) != count:
        raise InputError(f"{path}: the first line says {count} lights but {len(names)} follow")
    return names, check_directions(dirs, str(path))


def write_lp(path, filenames, directions):
    """Write an RTI ``.lp`` file (6 decimals, x right, y up, z toward the camera)."""
    directions = check_directions(directions)
    if len(filenames) != len(directions):
        raise InputError(f"{path}: {len(filenames)} file names for {len(directions)} lights")
    lines = [str(len(directions))]
    lines += [f"{name} {x:.6f} {y:.6f} {z:.6f}" for name, (x, y, z) in zip(filenames, directions)]
    atomic_write_text(path, "\n".join(lines) + "\n")


def read_lights_yaml(path):
    """Read ``lights.yaml`` into a :class:`LightSet`, naming the key at fault on error."""
    path = Path(path)
    try:
        data = load_yaml(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML: {exc}") from None
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
