"""``psrig calibrate SESSION [--circle CX,CY,R[;CX,CY,R]] [--sphere-mask FILE] [--outline FILE | --no-outline]
[--K FILE] [--force]`` or ``psrig calibrate SESSION --from OTHER_SESSION``."""

from ..core.errors import InputError
from .writing import open_session

__all__ = ["register", "parse_circles"]


def parse_circles(texts):
    """``--circle`` values (each 'CX,CY,R' or several joined by ';') -> list of [cx, cy, r]."""
    import numpy as np

    circles = []
    for text in texts or []:
        for part in filter(None, (p.strip() for p in text.split(";"))):
            try:
                values = [float(v) for v in part.split(",")]
            except ValueError:
                values = []
            if len(values) != 3 or not np.isfinite(values).all() or values[2] <= 0:
                raise InputError(f"--circle: expected CX,CY,R in pixels with R > 0, got {part!r}")
            circles.append(values)
    return circles


def register(subparsers):
    p = subparsers.add_parser("calibrate", help="chrome (and matte) spheres -> calibration/lights.yaml, lights.lp")
    p.add_argument("session")
    p.add_argument("--circle", action="append",
                   help="sphere outline CX,CY,R in pixels, 0-based (repeat, or join with ';', for several)")
    p.add_argument("--sphere-mask", help="PNG mask of the sphere(s): one blob or label per sphere")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--outline", metavar="FILE",
                       help="evenly (room-)lit photo of the sphere(s) from the same camera position, at the "
                            "frames' size: the sphere outlines are found on it instead of on the light "
                            "frames (default: the session's outline frames, when it has any)")
    which.add_argument("--no-outline", action="store_true",
                       help="find the sphere outlines on the light frames even when the session has "
                            "outline frames")
    p.add_argument("--from", dest="from_session", metavar="OTHER_SESSION",
                   help="use the calibration of another session shot under the same lights (its "
                        "calibration/lights.yaml) instead of this one's sphere frames; its path and hash are "
                        "recorded, so psrig run redoes this stage when it is recalibrated")
    p.add_argument("--K", help="text file with the 3x3 intrinsics (perspective view rays)")
    p.add_argument("--force", action="store_true", help="recompute even when up to date")
    p.set_defaults(func=run)


_SOURCES = {"fit": "found on the light frames", "outline": "found on the outline photo",
            "given": "given", "mask": "from the mask"}


def _read_K(path):
    import numpy as np

    try:
        return np.loadtxt(path).reshape(3, 3)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read a 3x3 K matrix ({exc})") from None


def run(args):
    from calibration import calibrate_session

    circles = parse_circles(args.circle)
    circle = None if not circles else (circles[0] if len(circles) == 1 else circles)
    if args.outline is not None and (circles or args.sphere_mask):
        raise InputError("--outline: the sphere outlines come from --outline, --circle or --sphere-mask; "
                         "give only one of them")
    K = _read_K(args.K) if args.K else None
    session = open_session(args.session, args)
    if args.from_session:
        if circles or args.sphere_mask or args.outline or args.no_outline or K is not None:
            raise InputError("--from: the lights come from the other session; give no --circle, --sphere-mask, "
                             "--outline or --K with it")
        calibrate_session(session, from_session=args.from_session, force=args.force)
        return 0
    result = calibrate_session(session, circle=circle, sphere_mask=args.sphere_mask, K=K,
                               outline=False if args.no_outline else args.outline, force=args.force)
    if result is None:
        return 0
    for kind in result.kinds:
        print(f"{kind['kind']:6s} sphere at ({kind['cx']:.2f}, {kind['cy']:.2f}) r {kind['r']:.2f} "
              f"(circle {_SOURCES.get(kind['method'], kind['method'])}, outline rms {kind['rms_px']:.2f} px, "
              f"lit share {kind['lit_share']:.3f})")
    print(result.near_reason)
    dist = result.distances
    for k, (d, res) in enumerate(zip(result.directions, result.residual_deg)):
        where = f"  distance {dist[k]:.1f} miss {result.position_error[k]:.2f}" if dist is not None else ""
        print(f"light {k:3d}  {d[0]:+.4f} {d[1]:+.4f} {d[2]:+.4f}  residual {res:.3f} deg{where}"
              + (f"  FLAGGED: {result.flags[k]}" if k in result.flags else ""))
    return 0
