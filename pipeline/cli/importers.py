"""``psrig import``: existing data -> a session folder.

    psrig import diligent SRC SESSION
    psrig import images SESSION --object GLOB [--sphere GLOB [--outline GLOB]] [--mask FILE] [--lights FILE]
                        [--intensities FILE] [--sphere-mask FILE] [--keep-all]
"""

import argparse


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
                             usage="psrig import images SESSION --object GLOB [GLOB ...] [--sphere GLOB [GLOB ...]] "
                                   "[--outline GLOB [GLOB ...]] "
                                   "[--mask FILE] [--lights FILE] [--intensities FILE] [--sphere-mask FILE] "
                                   "[--keep-all]",
                             description="Import image files. Quote the patterns: psrig expands "
                                         "them and sorts the files naturally (img2 before img10); "
                                         "frame i is lit by light i.")
    # SESSION may come before or after the options: a pattern option takes several values (so
    # that a pattern the shell expanded arrives whole and the handler can say to quote it), and
    # the last such option hands back a SESSION it swallowed (_Patterns)
    img.add_argument("session", metavar="SESSION", nargs="?", help="session folder to create")
    img.add_argument("--object", required=True, metavar="GLOB", action=_Patterns, nargs="+",
                     help="object frames: quoted patterns (each sorted naturally) or file names, taken in "
                          "the order given (frame i is lit by light i); any image OpenImageIO reads or camera "
                          "raw LibRaw reads")
    img.add_argument("--sphere", metavar="GLOB", action=_Patterns, nargs="+",
                     help="chrome-sphere frames (same lights)")
    img.add_argument("--outline", metavar="GLOB", action=_Patterns, nargs="+",
                     help="evenly (room-)lit photo(s) of the sphere(s), rig lights off, same camera "
                          "position: calibration finds the sphere outlines on it")
    img.add_argument("--mask", metavar="FILE", help="object mask image (white = object)")
    img.add_argument("--lights", metavar="FILE",
                     help="light directions: lights.yaml, RTI .lp (paired by file name), text with x y z, "
                          "x y z i or x y z r g b per line, .npy/.npz, .mat, OpenCV FileStorage; "
                          "FILE:NAME picks one array of a .mat, .npz or OpenCV file")
    img.add_argument("--intensities", metavar="FILE",
                     help="per-light intensities, one row of 1 or 3 values per light (e.g. DiLiGenT's "
                          "light_intensities.txt)")
    img.add_argument("--sphere-mask", metavar="FILE",
                     help="mask of the sphere(s) in the sphere frames, one blob per sphere: stored in the "
                          "session, the calibrate stage uses it instead of finding the spheres")
    img.add_argument("--keep-all", action="store_true",
                     help="keep files named like masks or maps (NAME.mask.png, *_normal*, albedo, depth), "
                          "which the patterns skip by default")
    img.set_defaults(func=_run_images)


def _run_diligent(args):
    from ..importers import import_diligent

    session = import_diligent(args.src, args.session)
    _print(session)
    return 0


class _Patterns(argparse.Action):
    """A pattern option's values; it notes that it came last, as it may hold SESSION at its end."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, list(values))
        namespace.last_patterns = self.dest


def _session(args):
    """SESSION, given before the options or swallowed by the last pattern option."""
    if args.session is not None:
        return args.session
    values = getattr(args, getattr(args, "last_patterns", None) or "object", None) or []
    if len(values) < 2:
        from ..core.errors import InputError

        raise InputError("give the SESSION folder to create, e.g. psrig import images SESSION --object 'img*.png'")
    return values.pop()


def _pattern(option, values):
    """The pattern given to ``option``, or the list of patterns and files (taken in the order
    given: frame i is lit by light i). A list of files in the shell's sorted order that natural
    sorting would reorder (img1 img10 img2) is refused: that is a pattern the shell expanded."""
    if values is None or len(values) == 1:
        return None if values is None else values[0]
    from ..core.errors import InputError
    from ..importers import natural_key

    files = [v for v in values if not any(char in v for char in "*?[")]
    if len(files) == len(values) and values == sorted(values) and values != sorted(values, key=natural_key):
        shown = " ".join(values[:3]) + (" ..." if len(values) > 3 else "")
        raise InputError(f"{option}: {len(values)} files ({shown}) in the order a shell sorts them, which puts "
                         f"{_first_misplaced(values, natural_key)}: if the shell expanded a pattern, quote it, "
                         f"e.g. {option} 'img*.png', so that psrig expands it (sorting it naturally and skipping "
                         "masks); if this is the order of the lights, list them in another order or rename them")
    return list(values)


def _first_misplaced(values, key):
    natural = sorted(values, key=key)
    index = next(i for i, (a, b) in enumerate(zip(values, natural)) if a != b)
    return f"{values[index]} before {natural[index]}"


def _run_images(args):
    from ..importers import import_images, import_notes

    session = import_images(_session(args), _pattern("--object", args.object),
                            sphere_glob=_pattern("--sphere", args.sphere), mask=args.mask,
                            lights=args.lights, outline=_pattern("--outline", args.outline),
                            intensities=args.intensities,
                            sphere_mask=args.sphere_mask, keep_all=args.keep_all)
    for line in import_notes(session):
        print(f"import: {line}")
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
