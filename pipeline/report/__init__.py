"""The session report: ``report/index.html``, one page that opens from disk.

:mod:`.stage` gathers the pictures and writes the page (the ``report`` stage), :mod:`.html`
renders it, :mod:`.images` turns maps into pictures (tone maps, colour maps, status colours).
"""

from .stage import INDEX, THUMB_SIDE, report_session

__all__ = ["report_session", "INDEX", "THUMB_SIDE"]
