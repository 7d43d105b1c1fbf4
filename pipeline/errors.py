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
