"""The session report: ``report/index.html``, one page that opens from disk, and a comparison
page of several sessions on the same scales.

:mod:`.stage` is the ``report`` stage, :mod:`.sections` its page's sections, :mod:`.maps` the
result maps and their stated scales, :mod:`.images` pictures (tone maps, colour maps, colour
bars, status colours), :mod:`.charts` the SVG charts, :mod:`.lights` the lights plot and table,
:mod:`.details` the stage records, :mod:`.mesh_view` the 3-D view (with ``viewer.js``),
:mod:`.html` the page's building blocks, :mod:`.compare` the comparison page.
"""

from .compare import compare_sessions
from .stage import INDEX, REPORT, THUMB_SIDE, ReportStage, report_session

__all__ = ["report_session", "compare_sessions", "INDEX", "THUMB_SIDE", "ReportStage", "REPORT"]
