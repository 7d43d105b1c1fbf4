"""``psrig export SESSION --relight DIR [--format exr|png]``"""

from ..core.errors import InputError

__all__ = ["register"]


def register(sub):
    parser = sub.add_parser(
        "export", help="write a session's fitted model for other viewers (--relight DIR)",
        description="--relight DIR: the fitted model at full resolution (normals, RGB albedo, the nine "
                    "coefficients of the paper's Eq. 2, mask) as float EXR or 16-bit PNG, and relight.json, "
                    "which says how to evaluate it (frames, channel order, decoding, formula, a worked "
                    "example).")
    parser.add_argument("session", metavar="SESSION", help="session folder (its normals stage has run)")
    parser.add_argument("--relight", metavar="DIR", help="folder to write the relighting files into")
    parser.add_argument("--format", choices=("exr", "png"), default="exr",
                        help="exr: float32 (default); png: 16-bit with per-channel offset and scale")
    parser.set_defaults(func=run)


def run(args):
    from ..relight import export_relight
    from ..core.session import Session

    if not args.relight:
        raise InputError("export: nothing to export: give --relight DIR")
    session = Session.open(args.session)
    spec = export_relight(session, args.relight, args.format)
    files = ", ".join(f["file"] for f in spec["files"].values())
    print(f"export: {session.root}: {spec['width']} x {spec['height']} model ({spec['method']}) -> {args.relight}: "
          f"{files}, relight.json")
    return 0
