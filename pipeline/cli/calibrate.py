"""``psrig calibrate SESSION [--circle CX,CY,R] [--sphere-mask FILE] [--K FILE] [--force]``."""

import numpy as np

from ..errors import InputError
from ..session import Session

__all__ = ["register"]


def _circle(text):
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3:
        raise InputError(f"--circle: expected CX,CY,R in pixels, got {text!r}")
    return values


def register(subparsers):
    p = subparsers.add_parser("calibrate", help="chrome sphere -> calibration/lights.yaml, lights.lp")
    p.add_argument("session")
    p.add_argument("--circle", action="append", help="sphere outline CX,CY,R in pixels (repeat for two spheres)")
    p.add_argument("--sphere-mask", help="PNG mask of the sphere")
    p.add_argument("--K", help="text file with the 3x3 intrinsics (perspective view rays)")
    p.add_argument("--force", action="store_true", help="recompute even when up to date")
    p.set_defaults(func=run)


def run(args):
    from calibration.stage import calibrate_session

    circles = [_circle(c) for c in args.circle or []]
    circle = None if not circles else (circles[0] if len(circles) == 1 else circles)
    K = None
    if args.K:
        try:
            K = np.loadtxt(args.K).reshape(3, 3)
        except (OSError, ValueError) as exc:
            raise InputError(f"{args.K}: cannot read a 3x3 K matrix ({exc})") from None
    session = Session.open(args.session)
    result = calibrate_session(session, circle=circle, sphere_mask=args.sphere_mask, K=K, force=args.force)
    if result is None:
        return 0
    for k, (d, res) in enumerate(zip(result.directions, result.residual_deg)):
        print(f"light {k:3d}  {d[0]:+.4f} {d[1]:+.4f} {d[2]:+.4f}  residual {res:.3f} deg"
              + (f"  FLAGGED: {result.flags[k]}" if k in result.flags else ""))
    if result.flags:
        print(f"{len(result.flags)} flagged light(s): " + ", ".join(str(k) for k in sorted(result.flags)))
    return 0
