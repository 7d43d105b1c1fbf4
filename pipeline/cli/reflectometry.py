"""``psrig reflectometry``: the paper's Sec. 4 from ONE image of a sphere under one light."""

import time
from pathlib import Path

from ..core.errors import InputError

__all__ = ["register"]


def register(subparsers):
    parser = subparsers.add_parser(
        "reflectometry", help="fit reflectance models to one image of a sphere (paper Sec. 4)",
        description="Fit the biquadratic, Lafortune and Lambertian models to ONE linear image of "
                    "a sphere of known shape under one known light, re-render the sphere with "
                    "each fit, and write the MAE table (with each model's parameter count) and the "
                    "difference maps. Either a user's image (--image, --light, --circle) or a "
                    "simulated sphere (--simulate), which also has the paper's bivariate table "
                    "model rho(theta_h, theta_d), averaged over phi_d, built from the material.")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--image", metavar="FILE", help="linear image of the sphere (EXR, 16-bit PNG/TIFF)")
    source.add_argument("--simulate", metavar="MATERIAL", default=None,
                        help="cook-torrance[:m], ward[:m] or a MERL .binary file (default "
                             "cook-torrance:0.5)")
    parser.add_argument("--light", metavar="X,Y,Z", help="direction toward the light, camera frame "
                        "(x right, y up, z toward the camera)")
    parser.add_argument("--circle", metavar="CX,CY,R", help="sphere centre column, row and radius "
                        "in pixels (row 0 at the top); required with --image")
    parser.add_argument("--saturation", type=float, default=0.98,
                        help="with --image: pixel values at or above it are clipped and not used "
                             "(default 0.98 of the 1.0 white level)")
    parser.add_argument("--size", type=int, default=128, help="simulated image size (128)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default ./experiments-out/reflectometry)")
    parser.set_defaults(func=run)


def floats(text, what, count):
    """Exactly ``count`` comma-separated numbers, else an InputError naming the option."""
    from .experiments import parse_floats

    values = parse_floats(text, what)
    if len(values) != count:
        raise InputError(f"{what}: expected {count} comma-separated numbers, got {text!r}")
    return values


def _load(args):
    from ..experiments import reflectometry as exp
    from ..core.imageio import read_image

    light = floats(args.light, "--light", 3) if args.light else exp.DEFAULT_LIGHT
    if args.image:
        if not args.circle or not args.light:
            raise InputError("--image needs --light X,Y,Z and --circle CX,CY,R")
        image = read_image(args.image).astype(float)
        normals, mask = exp.sphere_normals(image.shape[:2], floats(args.circle, "--circle", 3))
        return image, normals, mask, light, Path(args.image).name, args.saturation, None
    material, label = exp.parse_material(args.simulate or "cook-torrance:0.5")
    if args.size < 16:
        raise InputError(f"--size must be at least 16, got {args.size}")
    image, normals, mask = exp.simulate_sphere(material, light, args.size)
    return image, normals, mask, light, f"simulated {label}", None, material


def run(args):
    from ..experiments import reflectometry as exp
    from ..experiments.tables import write_outputs

    started = time.perf_counter()
    image, normals, mask, light, label, saturation, material = _load(args)
    results, used = exp.reflectometry(image, normals, mask, light, saturation=saturation, material=material)
    table = exp.reflectometry_table(results, label, image)
    out = Path(args.out or Path("experiments-out") / "reflectometry")
    paths = write_outputs(out, table, exp.reflectometry_figure(image, results, used))
    print(table.to_markdown())
    print(f"wrote {', '.join(str(p) for p in paths)} in {time.perf_counter() - started:.1f} s")
    return 0
