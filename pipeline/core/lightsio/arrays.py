"""Light tables stored as arrays: NumPy ``.npy`` / ``.npz``, MATLAB ``.mat`` (SciPy) and OpenCV
FileStorage files (``%YAML:1.0`` with ``!!opencv-matrix``, or XML), read by OpenCV itself.

A file holding several arrays needs the one to use named after a colon (``lights.mat:L``);
with one array (or one that is a light table) it is taken.
"""

import numpy as np

from ..errors import InputError

__all__ = ["read_array", "MAT_V73"]

MAT_V73 = b"\x89HDF\r\n\x1a\n"
_NOT_DATA = ("__header__", "__version__", "__globals__")


def _choose(arrays, path, name, what, whats=None):
    """The array named ``name`` of {name: ndarray}, or the only (table-shaped) one."""
    whats = whats or what + "s"
    if name is not None:
        if name not in arrays:
            raise InputError(f"{path}: no {what} {name!r}; it holds {_listing(arrays)}")
        return np.asarray(arrays[name])
    if len(arrays) == 1:
        return np.asarray(next(iter(arrays.values())))
    tables = {k: v for k, v in arrays.items() if np.ndim(v) == 2 and 3 in np.shape(v)}
    if len(tables) == 1:
        return np.asarray(next(iter(tables.values())))
    if not arrays:
        raise InputError(f"{path}: holds no {whats}")
    raise InputError(f"{path}: holds {len(arrays)} {whats} ({_listing(arrays)}); name the one to use after a "
                     f"colon, e.g. {path}:{next(iter(tables or arrays))}")


def _listing(arrays):
    return ", ".join(f"{k} {'x'.join(map(str, np.shape(v))) or 'scalar'}" for k, v in arrays.items())


def _mat(path, name):
    from scipy.io import loadmat

    try:
        data = loadmat(str(path))
    except (ValueError, TypeError, OSError, NotImplementedError) as exc:
        raise InputError(f"{path}: cannot read the MATLAB file ({exc})") from None
    arrays = {k: v for k, v in data.items() if k not in _NOT_DATA and isinstance(v, np.ndarray)
              and v.dtype.kind in "biuf"}
    return _choose(arrays, path, name, "numeric variable")


def _npy(path, name):
    try:
        loaded = np.load(str(path), allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"{path}: cannot read the NumPy file ({exc})") from None
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            return _choose({k: loaded[k] for k in loaded.files}, path, name, "array")
    if name is not None:
        raise InputError(f"{path}: a .npy file holds one array; drop ':{name}'")
    return loaded


def _opencv(path, name):
    import cv2

    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        if not storage.isOpened():
            raise InputError(f"{path}: OpenCV cannot read this FileStorage file")
        root = storage.root()
        arrays = {}
        for key in root.keys():
            node = root.getNode(key)
            if node.isMap() or node.isSeq():
                matrix = node.mat()
                if matrix is not None:
                    arrays[key] = matrix
            elif node.isReal() or node.isInt():
                continue
    except cv2.error as exc:
        raise InputError(f"{path}: not a valid OpenCV FileStorage file ({str(exc).strip().splitlines()[-1]})") from None
    finally:
        storage.release()
    return _choose(arrays, path, name, "matrix", "matrices")


_READERS = {"mat": _mat, "npy": _npy, "opencv": _opencv}


def read_array(path, kind, name=None):
    """The array of a binary or OpenCV light file.

    Parameters
    ----------
    path : Path
    kind : {'mat', 'npy', 'opencv'}
    name : str, optional
        Variable / array / node to use (required when the file holds several).

    Returns
    -------
    ndarray
    """
    return np.asarray(_READERS[kind](path, name), dtype=float)
