"""Options of the ``report`` stage (:mod:`pipeline.report`)."""

from dataclasses import dataclass

from ..core.options import Options, option

__all__ = ["ReportOptions", "ERROR_TOP_DEG"]

#: top of the report's angular-error scale, degrees (the same for every session, so that reports compare)
ERROR_TOP_DEG = 30.0


@dataclass(frozen=True)
class ReportOptions(Options):
    """What ``psrig report`` and ``psrig run`` set of the report."""

    kind = "report option"
    max_deg: float = option(ERROR_TOP_DEG, "top of the angular-error scale, degrees", kind=float, above=0.0,
                            metavar="DEG")
    evaluate: bool = option(True, "score the session against its ground truth first (when it has any)", kind=bool,
                            flag="")
