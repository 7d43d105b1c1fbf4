"""Atomic file writes: temporary file in the same folder, fsync, rename, fsync of the folder.

A reader (or a process killed mid-write) sees either the old file or the new one, never a
truncated file.

Nothing is written through a link: the temporary file is created exclusively (``mkstemp``) and
reopened with ``O_NOFOLLOW``, and a target that is a symlink or not a regular file is refused
(:class:`~pipeline.core.errors.SessionError` naming it) rather than silently replaced: a session
received as an archive may hold links anywhere.
"""

import contextlib
import errno
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

from .errors import SessionError

__all__ = ["atomic_write_bytes", "atomic_write_text", "atomic_path", "fsync_dir",
           "atomic_write_begin", "atomic_commit", "discard_temp", "sweep_tree", "is_temp_name",
           "check_target"]

# the names _temp_beside gives: "." + stem + "." + mkstemp's random part + ".tmp" + suffix
_TEMP_NAME = re.compile(r"^\..*\.[^.]+\.tmp(\.[^.]*)?$")


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def fsync_dir(folder):
    """Flush a folder's entry table so a rename inside it survives a power loss."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; on success, fsync it and rename it onto ``path``.

    The temporary name keeps the extension so that writers choosing a format by extension
    (OpenImageIO) still work. On any exception the temporary file is removed and ``path`` is
    untouched.
    """
    path = Path(path)
    fd, tmp = _temp_beside(path)
    os.close(fd)
    try:
        yield Path(tmp)
        _fsync_file(tmp)
        check_target(path)
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        _name(exc, path)
        raise


def check_target(path):
    """Refuse to replace ``path`` when it is a symlink or not a regular file (absent is fine).

    Raises
    ------
    SessionError
        Naming the path and what it is.
    """
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISREG(mode):
        return
    what = (f"a symbolic link to {os.readlink(path)}" if stat.S_ISLNK(mode)
            else "a folder" if stat.S_ISDIR(mode) else "not a regular file")
    raise SessionError(f"{path}: is {what}; psrig writes only regular files and never through links "
                       "(remove it and run again)")


def _fsync_file(tmp):
    """fsync a temporary file of ours, opened without following a link put in its place."""
    fd = os.open(tmp, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise SessionError(f"{tmp}: the temporary file was replaced by something else; nothing written")
        os.fsync(fd)
    finally:
        os.close(fd)


def _name(exc, path):
    """Name the file being written in a disk error that names none or only its temporary file
    (a full disk fails a write(), which has no file name), so that messages say which file."""
    if isinstance(exc, OSError) and (exc.filename is None or is_temp_name(Path(str(exc.filename)).name)):
        exc.filename = str(path)
    if isinstance(exc, OSError) and exc.errno is None and _disk_full(path.parent):
        # a short write without an errno (numpy: "18432 requested and 18400 written")
        exc.errno, exc.strerror = errno.ENOSPC, f"No space left on device: {exc.args[0] if exc.args else exc}"


def _disk_full(folder):
    """True when the file system of ``folder`` has (almost) no space left for its user."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < (1 << 20)


def _temp_beside(path):
    """(open fd, name) of a new temporary file beside ``path`` (folder created if needed)."""
    check_target(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    except OSError as exc:
        _name(exc, path)
        raise
    # mkstemp creates 0600; session files are ordinary files, readable as the umask allows.
    os.fchmod(fd, 0o666 & ~_umask())
    return fd, tmp


def atomic_write_begin(path, data):
    """First half of an atomic write: ``data`` (bytes-like) into a new temporary file beside
    ``path``, not yet synced; ``path`` is untouched.

    The second half, :func:`atomic_commit` (fsync, rename, fsync of the folder), may run later
    and in another thread or process, so that one writer goes on computing while the disk
    catches up. Give up with :func:`discard_temp`.

    Returns
    -------
    Path
        The temporary file (removed again if writing fails).
    """
    path = Path(path)
    fd, tmp = _temp_beside(path)
    try:
        with open(fd, "wb", closefd=True) as fh:
            fh.write(data)
    except BaseException as exc:
        discard_temp(tmp)
        _name(exc, path)
        raise
    return Path(tmp)


def atomic_commit(tmp, path):
    """Second half of an atomic write: fsync ``tmp``, rename it onto ``path``, fsync the folder.

    On any failure ``tmp`` is removed and ``path`` keeps its old content (or stays absent).
    """
    path = Path(path)
    try:
        _fsync_file(tmp)
        check_target(path)
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except BaseException as exc:
        discard_temp(tmp)
        _name(exc, path)
        raise


def discard_temp(tmp):
    """Remove a temporary file of :func:`atomic_write_begin` (no error if already gone)."""
    with contextlib.suppress(OSError):
        os.unlink(tmp)


def atomic_write_bytes(path, data):
    """Write ``data`` (bytes) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)


def atomic_write_text(path, text):
    """Write ``text`` (str, UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def is_temp_name(name):
    """True for the names of the temporary files this module creates."""
    return bool(_TEMP_NAME.match(name))


def sweep_tree(folder, *, recursive=True, everything=False):
    """Remove what interrupted writers left under ``folder``; returns (files, bytes) removed.

    Parameters
    ----------
    folder : path
    recursive : bool
        Also in sub-folders (symlinks are not followed).
    everything : bool
        ``folder`` is a scratch folder: remove it whole (a symlink in its place is unlinked,
        never followed).

    Call it only while no other writer works in ``folder`` (the session's lock says so).
    """
    folder = Path(folder)
    if everything:
        if folder.is_symlink() or folder.is_file():
            folder.unlink()
            return 1, 0
        if not folder.is_dir():
            return 0, 0
        files, size = _tree_size(folder)
        shutil.rmtree(folder, ignore_errors=True)
        return files, size
    if not folder.is_dir() or folder.is_symlink():
        return 0, 0
    files = size = 0
    for where, dirs, names in os.walk(folder) if recursive else [(str(folder), [], os.listdir(folder))]:
        for name in names:
            path = os.path.join(where, name)
            if is_temp_name(name) and not os.path.islink(path) and os.path.isfile(path):
                with contextlib.suppress(OSError):
                    size += os.path.getsize(path)
                    os.unlink(path)
                    files += 1
    return files, size


def _tree_size(folder):
    files = size = 0
    for where, _, names in os.walk(folder):
        for name in names:
            with contextlib.suppress(OSError):
                size += os.lstat(os.path.join(where, name)).st_size
                files += 1
    return files, size

