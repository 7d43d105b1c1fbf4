"""``psrig report SESSION [--force]``: report/index.html of a session."""

from ..report import INDEX, report_session
from .writing import open_session

__all__ = ["register"]


def register(subparsers):
    """Add the ``report`` sub-command."""
    parser = subparsers.add_parser(
        "report", help="report/index.html",
        description="Write report/index.html (opens from disk): frame thumbnails, calibration "
                    "overlays, normal, albedo, residual, status and error maps, the shaded "
                    "depth, each stage's settings and timings, and the errors against ground "
                    "truth when the session has it.")
    parser.add_argument("session", metavar="SESSION", help="session folder")
    parser.add_argument("--force", action="store_true", help="rebuild even when up to date")
    parser.add_argument("--no-eval", action="store_true",
                        help="do not score against ground truth first")
    parser.set_defaults(func=run)


def run(args):
    session = open_session(args.session, args)
    record = report_session(session, force=args.force, evaluate=not args.no_eval)
    state = "up to date" if record is None else f"written in {record['seconds']:.1f} s"
    print(f"report: {session.path(INDEX)} ({state})")
    return 0
