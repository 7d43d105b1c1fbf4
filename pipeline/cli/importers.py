"""``psrig import``: existing data -> a session folder.

    psrig import diligent SRC SESSION
    psrig import images SESSION --object GLOB [--sphere GLOB [--outline GLOB]] [--mask FILE] [--lights FILE]
"""

__all__ = ["register"]


def register(subparsers):
    """Add the ``import`` sub-command with its ``diligent`` and ``images`` sources."""
    parser = subparsers.add_parser("import", help="a DiLiGenT folder or image files -> session",
                                   description="Create a session from existing data.")
    sources = parser.add_subparsers(dest="source", metavar="SOURCE", required=True)
    dil = sources.add_parser("diligent", help="a DiLiGenT object folder (with ground truth)",
                             description="Import a DiLiGenT object folder: images, lights, "
                                         "object mask and ground-truth normals.")
    dil.add_argument("src", metavar="SRC", help="DiLiGenT object folder, e.g. ballPNG")
    dil.add_argument("session", metavar="SESSION", help="session folder to create")
    dil.set_defaults(func=_run_diligent)
    img = sources.add_parser("images", help="image files matched by glob patterns",
                             description="Import image files. Quote the patterns: psrig expands "
                                         "them and sorts the files naturally (img2 before img10); "
                                         "frame i is lit by light i.")
    img.add_argument("session", metavar="SESSION", help="session folder to create")
    img.add_argument("--object", required=True, metavar="GLOB", help="object frames")
    img.add_argument("--sphere", metavar="GLOB", help="chrome-sphere frames (same lights)")
    img.add_argument("--outline", metavar="GLOB",
                     help="evenly (room-)lit photo(s) of the sphere(s), rig lights off, same camera "
                          "position: calibration finds the sphere outlines on it")
    img.add_argument("--mask", metavar="FILE", help="object mask image (white = object)")
    img.add_argument("--lights", metavar="FILE",
                     help="light directions: lights.yaml, RTI .lp, or text x y z per line")
    img.set_defaults(func=_run_images)


def _run_diligent(args):
    from ..importers import import_diligent

    session = import_diligent(args.src, args.session)
    _print(session)
    return 0


def _run_images(args):
    from ..importers import import_images

    session = import_images(args.session, args.object, sphere_glob=args.sphere, mask=args.mask,
                            lights=args.lights, outline=args.outline)
    _print(session)
    return 0


def _print(session):
    kinds = {}
    for frame in session.frames():
        kinds[frame["kind"]] = kinds.get(frame["kind"], 0) + 1
    counts = ", ".join(f"{n} {kind}" for kind, n in kinds.items())
    lights = "lights imported" if session.manifest["lights"].get("file") else "no lights"
    truth = ", ".join(sorted(session.manifest["truth"])) or "none"
    print(f"import: {session.root}: {counts} frames, {lights}, ground truth: {truth}")
