"""Text light files: plain lists (``x y z``, ``x y z i`` or ``x y z r g b`` per line) and the
RTI ``.lp`` format (first line N, then ``filename x y z`` per light)."""

from pathlib import Path, PureWindowsPath

import numpy as np

from ..atomic import atomic_write_text
from ..errors import InputError
from .core import check_directions

__all__ = ["read_lights_text", "read_lp", "write_lp", "looks_like_lp", "split_columns", "lp_name"]


def _numeric_rows(path, text):
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            rows.append((lineno, [float(t) for t in line.replace(",", " ").split()]))
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a row of numbers: {line!r}") from None
    return rows


def split_columns(data, where, count=None):
    """Directions (K, 3) and intensities (K, C) or None of a table of lights.

    Parameters
    ----------
    data : ndarray (K, 3 | 4 | 6), or its transpose
        One light per row: ``x y z``, ``x y z i`` or ``x y z r g b``. A table with 3, 4 or 6
        rows and more than 6 columns is one light per column (as PSBox and MATLAB write them);
        when both readings fit, the one giving ``count`` lights wins, else one per row.
    where : str
        Named in errors.
    count : int, optional
        The number of frames the lights are for.
    """
    data = np.asarray(data, dtype=float)
    if data.ndim == 1 and data.size in (3, 4, 6):
        data = data[None, :]
    if data.ndim != 2:
        raise InputError(f"{where}: expected a table of lights (K rows of x y z [i | r g b]), got shape {data.shape}")
    rows_fit, columns_fit = data.shape[1] in (3, 4, 6), data.shape[0] in (3, 4, 6)
    if columns_fit and (not rows_fit or _columns_are_lights(data, count)):
        data = data.T
    if data.shape[1] not in (3, 4, 6):
        raise InputError(f"{where}: expected 3, 4 or 6 numbers per light (x y z, x y z i or x y z r g b), "
                         f"found {data.shape[1]}")
    directions = check_directions(data[:, :3], where)
    return directions, (data[:, 3:] if data.shape[1] > 3 else None)


def _columns_are_lights(data, count):
    """For a table that reads either way (3 x 4, 4 x 6, ...): the one giving ``count`` lights,
    else one light per row, unless the columns beyond x y z could not be intensities."""
    if count is not None and data.shape[0] != data.shape[1]:
        if count in data.shape:
            return data.shape[1] == count
    return data.shape[1] > 3 and not (data[:, 3:] > 0).all()


def read_lights_text(path, count=None):
    """Directions and intensities from text: ``x y z``, ``x y z i`` or ``x y z r g b`` per line,
    optionally after a count line; commas or spaces between numbers, ``#`` starts a comment.

    Returns
    -------
    directions : ndarray (K, 3)
    intensities : ndarray (K, 1 | 3) or None
    """
    path = Path(path)
    rows = _numeric_rows(path, path.read_text(encoding="utf-8", errors="replace"))
    if rows and len(rows[0][1]) == 1:
        declared = rows[0][1][0]
        rows = rows[1:]
        if declared != len(rows):
            raise InputError(f"{path}: the count line says {declared:g} lights but {len(rows)} follow")
    widths = sorted({len(r) for _, r in rows})
    if not rows or len(widths) != 1:
        lineno = next((n for n, r in rows if len(r) != len(rows[0][1])), 1)
        raise InputError(f"{path}:{lineno}: expected rows of 3, 4 or 6 numbers (x y z, x y z i or x y z r g b) "
                         f"alike, found rows of {widths} numbers")
    return split_columns(np.array([r for _, r in rows]), str(path), count)


def looks_like_lp(text):
    """True when ``text`` reads as an .lp file: a count line, then lines starting with a name."""
    lines = [ln.split() for ln in text.splitlines() if ln.strip()]
    if len(lines) < 2 or len(lines[0]) != 1 or not lines[0][0].isdigit():
        return False
    try:
        float(lines[1][0])
    except ValueError:
        return len(lines[1]) >= 4
    return False


def lp_name(name):
    """The file name an .lp line gives, without the folders (Windows or POSIX) before it."""
    return PureWindowsPath(name).name if "\\" in name else Path(name).name


def read_lp(path):
    """Read an RTI ``.lp`` file: first line N, then ``filename x y z`` per light.

    Returns
    -------
    names : list of str
        The file names, in the file's order.
    directions : ndarray (K, 3)
    """
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
            if len(parts) < 4:
                raise ValueError
            dirs.append([float(v) for v in parts[-3:]])
            names.append(" ".join(parts[:-3]))   # a name may hold spaces: the numbers end the line
        except ValueError:
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
