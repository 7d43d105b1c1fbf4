"""``psrig report SESSION... [--out DIR] [--max-deg F] [--force] [--no-eval]``: each session's
report/index.html and, for several sessions, a comparison page on the same scales."""

from ..settings.report import ReportOptions
from .writing import open_session

__all__ = ["register"]


def register(subparsers):
    """Add the ``report`` sub-command."""
    parser = subparsers.add_parser(
        "report", help="report/index.html; several sessions: side by side",
        description="Write each session's report/index.html (opens from disk): where the lights came "
                    "from, every stage's warnings, settings and timings, the errors against ground "
                    "truth (numbers, histogram, error against the observations used), the result "
                    "maps on stated scales with colour bars, the depth with a 3-D view, the lights "
                    "(hemisphere plot and table), calibration overlays and frame thumbnails. With "
                    "several sessions, also a comparison page (--out) laying them side by side on "
                    "the same scales.")
    parser.add_argument("sessions", nargs="+", metavar="SESSION", help="session folder(s)")
    parser.add_argument("--out", metavar="DIR",
                        help="folder of the comparison page with several sessions (default: "
                             "./psrig-compare; an earlier comparison there is replaced)")
    ReportOptions.add_arguments(parser)
    parser.add_argument("--force", action="store_true", help="rebuild even when up to date")
    parser.add_argument("--no-eval", action="store_true",
                        help="do not score against ground truth first")
    parser.set_defaults(func=run)


def run(args):
    from ..core.errors import InputError
    from ..report import INDEX, compare_sessions, report_session

    if args.out and len(args.sessions) < 2:
        raise InputError("--out is for a comparison of two sessions or more")
    options = ReportOptions.of(ReportOptions.from_args(args))
    sessions = [open_session(root, args) for root in args.sessions]  # every folder checked before any work
    for session in sessions:
        record = report_session(session, force=args.force, evaluate=not args.no_eval, max_deg=options.max_deg)
        state = "up to date" if record is None else f"written in {record['seconds']:.1f} s"
        print(f"report: {session.path(INDEX)} ({state})")
    if len(sessions) > 1:
        index = compare_sessions(sessions, args.out or "psrig-compare", max_deg=options.max_deg)
        print(f"report: comparison of {len(sessions)} sessions: {index.resolve()}")
    return 0
