"""Reading any light file psrig knows, decided by its content: :func:`read_lights` and
:func:`read_intensities`."""

from pathlib import Path

import numpy as np

from ..errors import InputError
from .arrays import MAT_V73, read_array
from .core import LightSet, check_intensities, read_lights_yaml
from .text import looks_like_lp, read_lights_text, read_lp, split_columns

__all__ = ["read_lights", "read_intensities", "light_format", "LIGHT_FORMATS"]

#: every light file format, for messages
LIGHT_FORMATS = ("psrig lights.yaml, RTI .lp (count line, then 'filename x y z'), text with 'x y z', "
                 "'x y z i' or 'x y z r g b' per line, NumPy .npy/.npz, MATLAB .mat (up to v7), "
                 "OpenCV FileStorage (%YAML:1.0 or XML with an opencv-matrix)")


def _split_name(path):
    """(file, array name or None) of ``FILE`` or ``FILE:NAME``."""
    text = str(path)
    if not Path(text).exists() and ":" in text:
        head, _, name = text.rpartition(":")
        if Path(head).is_file() and name:
            return Path(head), name
    return Path(text), None


def light_format(path):
    """The format of a light file from its first bytes: 'yaml', 'lp', 'text', 'npy', 'mat',
    'opencv'; InputError with the list of supported formats when it is none of them."""
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head.startswith(b"\x93NUMPY") or head.startswith(b"PK\x03\x04"):
        return "npy"
    if head.startswith(b"MATLAB ") and b"MAT-file" in head[:128]:
        return "mat" if head[512:520] != MAT_V73 else _mat73(path)
    if b"\0" in head:
        raise InputError(f"{path}: not a light file psrig reads (binary data); it reads {LIGHT_FORMATS}")
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    stripped = text.lstrip()
    if stripped.startswith("%YAML") or (stripped.startswith("<?xml") and "opencv_storage" in text):
        return "opencv"
    if looks_like_lp(text):
        return "lp"
    first = next((ln.split("#", 1)[0].strip() for ln in text.splitlines() if ln.split("#", 1)[0].strip()), "")
    if first.startswith(("directions", "{", "---")) or Path(path).suffix.lower() in (".yaml", ".yml"):
        return "yaml"
    try:
        [float(t) for t in first.replace(",", " ").split()]
    except ValueError:
        raise InputError(f"{path}: not a light file psrig reads (first line {first[:60]!r}); it reads "
                         f"{LIGHT_FORMATS}") from None
    return "text"


def _mat73(path):
    raise InputError(f"{path}: a MATLAB v7.3 (HDF5) file, which SciPy does not read; save it with "
                     "save(FILE, VARIABLE, '-v7') or as text")


def read_lights(path, count=None):
    """Read lights from any supported file, decided by content (:data:`LIGHT_FORMATS`).

    Parameters
    ----------
    path : str or Path
        The file, or ``FILE:NAME`` for the array named NAME of a .mat, .npz or OpenCV file.
    count : int, optional
        How many frames the lights are for: decides the orientation of tables that read
        either way (3 x 4, 4 x 6, ...).

    Returns
    -------
    LightSet
        ``filenames`` set for .lp files; intensities from a 4th (or 4th to 6th) column.
    """
    path, name = _split_name(path)
    if not path.is_file():
        raise InputError(f"{path}: light file not found")
    kind = light_format(path)
    if name is not None and kind not in ("npy", "mat", "opencv"):
        raise InputError(f"{path}: ':{name}' names an array, but this is a {kind} file")
    source = f"imported from {path.name}" + (f":{name}" if name else "")
    if kind == "yaml":
        return read_lights_yaml(path, foreign=f"it reads {LIGHT_FORMATS}")
    if kind == "lp":
        names, directions = read_lp(path)
        try:
            return LightSet(directions, filenames=names, source=source)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
    if kind == "text":
        directions, intensities = read_lights_text(path, count)
    else:
        where = f"{path}" + (f":{name}" if name else "")
        directions, intensities = split_columns(read_array(path, kind, name), where, count)
    if intensities is not None:
        intensities = check_intensities(intensities, len(directions), f"{path}: intensity columns")
    try:
        return LightSet(directions, intensities, source=source)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def read_intensities(path, count):
    """Per-light intensities (K, 1) or (K, 3) from a text, .npy/.npz, .mat or OpenCV file.

    Parameters
    ----------
    path : str or Path
        Or ``FILE:NAME`` (an array of a .mat, .npz or OpenCV file).
    count : int
        Number of lights (K).
    """
    path, name = _split_name(path)
    if not path.is_file():
        raise InputError(f"{path}: intensity file not found")
    kind = light_format(path)
    if kind in ("npy", "mat", "opencv"):
        values = read_array(path, kind, name)
    elif kind in ("text", "lp"):
        rows = [ln.split("#", 1)[0].replace(",", " ").split() for ln in path.read_text().splitlines()]
        rows = [r for r in rows if r]
        if rows and len(rows[0]) == 1 and len(rows) == count + 1:
            rows = rows[1:]   # a count line
        try:
            values = np.array([[float(v) for v in r] for r in rows])
        except ValueError:
            raise InputError(f"{path}: expected {count} rows of 1 or 3 numbers (intensities)") from None
    else:
        raise InputError(f"{path}: not an intensity file; expected text, .npy/.npz, .mat or OpenCV with "
                         f"{count} rows of 1 or 3 numbers")
    return check_intensities(values, count, str(path))
