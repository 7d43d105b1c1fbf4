"""``psrig run SESSION... [--jobs N] [--force] [--from STAGE] [stage options]``."""

import sys
from pathlib import Path

from ..errors import InputError
from ..runner import run_sessions, stage_options
from .calibrate import parse_circles
from ..session import STAGES

__all__ = ["register"]


def register(subparsers):
    """Add the ``run`` sub-command."""
    parser = subparsers.add_parser(
        "run", help="every stage that is not up to date",
        description="Run decode, calibrate, normals, integrate and report on each session, "
                    "skipping every stage whose record still matches its parameters and input "
                    "hashes. A changed option reruns that stage and the ones after it.")
    parser.add_argument("sessions", nargs="+", metavar="SESSION", help="session folders")
    parser.add_argument("--jobs", type=int, default=1,
                        help="sessions processed in parallel (separate processes)")
    parser.add_argument("--force", action="store_true", help="rerun every stage")
    parser.add_argument("--from", dest="start", choices=STAGES, metavar="STAGE",
                        help=f"rerun from this stage on ({', '.join(STAGES)})")
    parser.add_argument("--to", dest="stop", choices=STAGES, metavar="STAGE",
                        help="last stage to run (default: report)")
    parser.add_argument("--method", help="photometric-stereo method of the normals stage "
                                         "(default: the stage's, biquadratic)")
    parser.add_argument("--t-low", type=float, help="normals: fraction of low-frequency "
                                                    "observations kept (T_low)")
    parser.add_argument("--integrate-method", help="integration method (smooth, bilateral)")
    parser.add_argument("--bin", type=int, choices=(1, 2), dest="binning",
                        help="decode: 2 = half size without demosaicing")
    parser.add_argument("--gamma", help="decode: transfer function of 8/16-bit image frames (auto, srgb, "
                                        "linear or an exponent; see psrig decode --help)")
    calib = parser.add_argument_group("calibrate (as psrig calibrate; kept for later runs)")
    calib.add_argument("--circle", action="append", help="sphere outline CX,CY,R in pixels (repeat for several)")
    calib.add_argument("--sphere-mask", metavar="FILE", help="mask of the sphere(s), one blob per sphere")
    outline = calib.add_mutually_exclusive_group()
    outline.add_argument("--outline", metavar="FILE", help="evenly lit photo of the sphere(s) to find them on")
    outline.add_argument("--no-outline", action="store_true", help="find the spheres on the light frames")
    calib.add_argument("--calibration-from", metavar="OTHER_SESSION",
                       help="use another session's calibration (psrig calibrate --from)")
    parser.add_argument("--scheduler", nargs="?", const="local", metavar="ADDRESS",
                        help="run on a Dask cluster (psrig[cluster]): the scheduler's address, "
                             "or no address for a local cluster of --jobs workers; photometric "
                             "stereo is split into pixel tiles (put it after the session "
                             "folders, or write --scheduler local)")
    parser.set_defaults(func=run)


def _calibration(args):
    """The calibrate options of ``psrig run`` as stage keywords (None where not given)."""
    circles = parse_circles(args.circle)
    if sum(bool(v) for v in (circles, args.sphere_mask, args.outline, args.calibration_from)) > 1:
        raise InputError("give the sphere outlines one way only: --circle, --sphere-mask, --outline or "
                         "--calibration-from")
    return {"circle": None if not circles else (circles[0] if len(circles) == 1 else circles),
            # absolute: the stage records it, and later runs may start elsewhere
            "sphere_mask": args.sphere_mask and str(Path(args.sphere_mask).absolute()),
            "from_session": args.calibration_from and str(Path(args.calibration_from).absolute()),
            "outline": False if args.no_outline else args.outline}


def run(args):
    if args.jobs < 1:
        print("psrig run: error: --jobs must be >= 1", file=sys.stderr)
        return 2
    options = stage_options(method=args.method, t_low=args.t_low,
                            integrate_method=args.integrate_method, binning=args.binning,
                            gamma=args.gamma, **_calibration(args))
    run = dict(options=options, force=args.force, start=args.start, stop=args.stop, jobs=args.jobs,
               echo=lambda line: print(line, flush=True))
    if args.scheduler is not None:  # a batch on Dask, photometric stereo in pixel tiles
        from ..cluster import run_batch, summary_table

        outcomes = run_batch(args.sessions, scheduler=args.scheduler, **run)
        print(summary_table(outcomes), flush=True)
    else:
        outcomes = run_sessions(args.sessions, **run)
    failed = [o for o in outcomes if o.error]
    for outcome in failed:
        print(f"psrig run: error: {outcome.error}", file=sys.stderr)
    return 1 if failed else 0
