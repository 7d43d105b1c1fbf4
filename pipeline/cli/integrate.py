"""``psrig integrate``: normals to depth, meshes and a shaded render.

    psrig integrate SESSION [--K FILE] [--method NAME] [mesh options] [--force]
    psrig integrate --normals PNG --mask PNG [--K FILE] [--method NAME] [--albedo FILE] --out DIR

The integration modules (scipy, pyamg) are imported when the command runs, not when the
parser is built, so that ``psrig --help`` stays fast.
"""

from pathlib import Path

from ..core.errors import InputError
from ..settings.integrate import INTEGRATION_METHODS as METHOD_NAMES, IntegrateOptions
from .writing import open_session

__all__ = ["register", "METHOD_NAMES"]


def register(subparsers):
    parser = subparsers.add_parser(
        "integrate", help="integrate normals into depth, mesh.ply and a shaded render",
        description="Integrate a session's normals (normals/normals.exr, normals/mask.png) into "
                    "depth/, or a normal map from anywhere with --normals/--mask/--out.")
    parser.add_argument("session", nargs="?", help="session folder")
    parser.add_argument("--normals", help="normal map: 16-bit PNG (RGB = (n+1)/2) or float EXR")
    parser.add_argument("--mask", help="mask PNG (white = integrate); default: the normal map's "
                        "non-black pixels")
    parser.add_argument("--out", help="output folder for --normals")
    parser.add_argument("--K", dest="K", help="3x3 intrinsics text file (perspective); "
                        "omit for orthographic")
    parser.add_argument("--drop-invalid", action="store_true",
                        help="with --normals: leave pixels with unusable normals (non-finite, facing "
                             "away) out of the mask instead of refusing them (a session's own "
                             "normals always are, with a note)")
    parser.add_argument("--albedo", help="with --normals: albedo image (EXR or PNG) for the "
                        "meshes' vertex colours and texture")
    parser.add_argument("--uncertainty", help="with --normals: the normals' expected error in degrees (EXR, first "
                        "channel; a session's normals/uncertainty.exr) for mesh.ply's per-vertex quality; default: "
                        "uncertainty.exr beside the normal map, when there is one")
    IntegrateOptions.add_arguments(parser, first=("method", "k"))
    parser.add_argument("--force", action="store_true", help="rerun even if up to date")
    parser.set_defaults(func=run)


def run(args):
    from ..integrate import integrate_session, read_intrinsics

    K = read_intrinsics(args.K) if args.K else None
    options = IntegrateOptions.from_args(args)
    method = options.pop("method", IntegrateOptions.defaults()["method"])
    if args.drop_invalid:
        options["invalid"] = "drop"
    if "k" in options and method != "bilateral":
        raise InputError("--k applies to --method bilateral only")
    if args.normals:
        return _run_files(args, K, method, options)
    if not args.session:
        raise InputError("give a SESSION folder, or --normals PNG --mask PNG --out DIR")
    session = open_session(args.session, args)
    result = integrate_session(session, K=K, method=method, force=args.force, **options)
    if result is None:
        print(f"integrate: {session.root}: up to date (use --force to rerun)")
        return 0
    _print(result, session.path("depth"), session.stage("integrate")["mesh"])
    return 0


def _run_files(args, K, method, options):
    from ..core.imageio import read_image, read_mask
    from ..integrate import integrate_files, write_depth_outputs
    from ..integrate.stage import MESH_KEYS

    if args.session:
        raise InputError("give either a SESSION or --normals, not both")
    if not args.out:
        raise InputError("--normals needs --out DIR")
    normals, mask = _read_normal_map(Path(args.normals))
    if args.mask:
        mask = read_mask(args.mask)
        if mask.shape != normals.shape[:2]:
            raise InputError(f"{args.mask}: size {mask.shape} differs from {args.normals} "
                             f"{normals.shape[:2]}")
    mesh = {k: options.pop(k) for k in MESH_KEYS if k in options}
    options.pop("memory", None)   # the session's budget check; files given by hand are integrated as they are
    albedo = read_image(args.albedo) if args.albedo else None
    if albedo is not None and albedo.shape[:2] != normals.shape[:2]:
        raise InputError(f"{args.albedo}: size {albedo.shape[:2]} differs from {args.normals} {normals.shape[:2]}")
    uncertainty, uncertainty_path = _read_uncertainty(args, normals.shape[:2])
    result = integrate_files(normals, mask, K, method, args.normals, **options)
    info = {"inputs": {"normals": str(Path(args.normals).resolve()),
                       "mask": str(Path(args.mask).resolve()) if args.mask else None,
                       "albedo": str(Path(args.albedo).resolve()) if args.albedo else None,
                       "uncertainty": str(uncertainty_path.resolve()) if uncertainty_path else None}}
    summary = write_depth_outputs(Path(args.out), result, normals, K, info, albedo, uncertainty=uncertainty, **mesh)
    if uncertainty_path is not None:
        found = "" if args.uncertainty else " (found beside the normal map)"
        print(f"integrate: mesh.ply's vertex quality is the expected error from {uncertainty_path}{found}")
    result.warnings = summary["warnings"]
    _print(result, Path(args.out), summary["mesh"])
    return 0


def _read_uncertainty(args, shape):
    """The per-pixel expected error (H, W) for the PLY's quality and its file, or (None, None):
    ``--uncertainty``, else ``uncertainty.exr`` beside the normal map when there is one."""
    from ..core.imageio import read_image

    path = Path(args.uncertainty) if args.uncertainty else Path(args.normals).with_name("uncertainty.exr")
    if not path.is_file():
        if args.uncertainty:
            raise InputError(f"{path}: uncertainty map not found")
        return None, None
    values = read_image(path)[:, :, 0]
    if values.shape != tuple(shape):
        raise InputError(f"{path}: size {values.shape} differs from {args.normals} {tuple(shape)}")
    return values, path


def _read_normal_map(path):
    from ..core.imageio import read_image, read_normal_png

    if not path.is_file():
        raise InputError(f"{path}: normal map not found")
    if path.suffix.lower() == ".exr":
        normals = read_image(path)[:, :, :3]
        return normals, (normals != 0).any(axis=2)
    return read_normal_png(path)


def _print(result, folder, mesh):
    projection = "perspective" if result.perspective else "orthographic"
    print(f"integrate: {result.method}, {projection}, {int((result.components > 0).sum())} pixels, "
          f"{result.n_components} component(s), {result.iterations} CG iterations in "
          f"{result.outer_iterations} round(s), {result.seconds:.2f} s -> {folder}")
    print(f"integrate: meshes mesh.ply, mesh.obj: {mesh['vertices']} vertices, {mesh['faces']} faces, "
          f"unit {mesh['unit']}" + (f", colour from the {mesh['colour']}" if mesh.get("colour") else ""))
    for warning in result.warnings:
        print(f"integrate: note: {warning}")
