"""Exception tree shared by every psrig package.

Every error a user can cause derives from :class:`PsrigError`; the command line prints its
message (which names the file, frame or key at fault) and exits non-zero without a traceback.
"""

__all__ = [
    "PsrigError",
    "SessionError",
    "ManifestError",
    "ImageFileError",
    "InputError",
    "StageError",
    "describe_os_error",
]


class PsrigError(Exception):
    """Base of all errors psrig reports to a user."""


class SessionError(PsrigError):
    """A session folder is missing, malformed, or an operation on it is not allowed."""


class ManifestError(SessionError):
    """``session.yaml`` is damaged or hand-edited into an invalid state."""


class ImageFileError(PsrigError):
    """An image file cannot be read or written."""


class InputError(PsrigError, ValueError):
    """Arrays or parameters handed to an algorithm are invalid."""


class StageError(PsrigError):
    """A processing stage cannot run (missing inputs, stale hashes, failed frames)."""


# what an operator does about the errors a full or protected disk gives
_OS_MEANINGS = {
    "ENOSPC": "disk full",
    "EDQUOT": "disk quota exceeded",
    "EROFS": "read-only file system",
    "EACCES": "permission denied",
    "EPERM": "permission denied (operation not permitted)",
    "EIO": "input/output error (a failing disk or a lost network mount)",
}


def describe_os_error(exc):
    """One line for an OSError: the path it concerns and what its errno means.

    ``'S/depth/mesh.obj: disk full (No space left on device)'``; without a path, the meaning.
    """
    import errno as _errno

    name = _errno.errorcode.get(exc.errno or 0)
    reason = exc.strerror or (str(exc.args[0]) if exc.args else type(exc).__name__)
    meaning = _OS_MEANINGS.get(name)
    text = f"{meaning} ({reason})" if meaning and meaning.lower() != reason.lower() else reason
    paths = [p for p in (exc.filename, getattr(exc, "filename2", None)) if p is not None]
    return ": ".join([" -> ".join(map(str, paths))] if paths else []) + (": " if paths else "") + text
