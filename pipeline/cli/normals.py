"""``psrig normals SESSION [--method NAME] [--t-low F] ...``: the flags are the declared
:class:`pipeline.settings.NormalsOptions`."""

from ..settings.normals import NormalsOptions
from .writing import open_session


def register(sub):
    parser = sub.add_parser("normals", help="photometric stereo: linear frames + lights -> normals/")
    parser.add_argument("session", help="session folder")
    NormalsOptions.add_arguments(parser)
    parser.add_argument("--list-methods", action="store_true",
                        help="list the photometric-stereo methods (built in and installed) and their options")
    parser.add_argument("--force", action="store_true", help="run even when the stage is up to date")
    parser.set_defaults(func=run)


def list_methods():
    """Print every registered method with the options it takes."""
    from ..photometric import METHODS
    from ..photometric.methods import method_traits

    for name in METHODS.names():
        traits = method_traits(METHODS[name])
        print(f"{name}: options {', '.join(traits.options.names())}")
    for name, why in METHODS.broken().items():
        print(f"{name}: installed but cannot be loaded ({why})")


def run(args):
    if args.list_methods:
        list_methods()
        return 0
    from ..photometric import normals_session, normals_summary

    options = NormalsOptions.from_args(args)
    session = open_session(args.session, args)
    record = normals_session(session, force=args.force, **options)
    if record is None:
        print(f"{session.root}: normals up to date (use --force to rerun)")
        return 0
    method = record["params"]["method"]
    print(f"{session.root}: normals ({method}) in {record['seconds']:.2f} s; {normals_summary(record)}")
    budget = record.get("memory")
    if budget:
        print(f"{session.root}: normals: {budget['execution']}, estimated peak {budget['estimate_gb']:.2f} GB "
              f"within a budget of {budget['budget_gb']:.2f} GB (--memory)")
    for warning in record.get("warnings", []):
        print(f"{session.root}: normals: warning: {warning}")
    return 0
