"""``psrig demo DIR [--force]``: simulated rig -> capture, process, evaluate, report."""

from .eval import format_summary

__all__ = ["register"]


def register(subparsers):
    """Add the ``demo`` sub-command."""
    parser = subparsers.add_parser(
        "demo", help="simulated rig: capture, process, report",
        description="Capture a session on the simulated rig into DIR, run every stage (decode, "
                    "calibrate from the chrome-sphere frames, normals, integrate, report), score "
                    "it against the simulated ground truth and print where the report is.")
    parser.add_argument("folder", metavar="DIR", help="session folder to create (new or empty)")
    parser.add_argument("--force", action="store_true",
                        help="replace a demo session already in DIR")
    parser.set_defaults(func=run)


def run(args):
    from ..demo import run_demo

    result = run_demo(args.folder, force=args.force, echo=lambda line: print(line, flush=True))
    summary = format_summary(result["scores"])
    if summary:
        print(summary)
    print(f"demo: done in {result['seconds']:.1f} s; report: {result['report']}")
    return 0
