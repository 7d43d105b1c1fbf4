"""``psrig decode SESSION``: raw frames -> linear EXR + saturation masks in linear/."""

import argparse
import sys

from .writing import open_session

#: pipeline.decode.COMPRESSIONS, spelled out so that building the parser imports no numpy (a test
#: checks they agree)
COMPRESSIONS = ("auto", "zip", "none")

__all__ = ["register", "COMPRESSIONS"]


def register(subparsers):
    """Add the ``decode`` sub-command."""
    parser = subparsers.add_parser(
        "decode", help="raw frames -> linear float32 EXR + saturation masks",
        description="Decode every frame of a session into linear/<id>.exr (float32, 1.0 = white "
                    "level minus black) and linear/<id>_sat.png (255 = saturated). The mean "
                    "ambient (else dark) frame is subtracted from lit frames; the exposures of "
                    "a bracket (exposure: {bracket: [...]}) are merged into linear/<frame>.exr, "
                    "each pixel from the longest unsaturated one.")
    parser.add_argument("session", metavar="SESSION", help="session folder")
    parser.add_argument("--method", choices=("mosaic", "postprocess"), default="mosaic",
                        help="mosaic: from the raw mosaic with per-channel black levels, "
                             "unbiased (default); postprocess: LibRaw's linear pipeline")
    parser.add_argument("--grey", action="store_true", help="one grey channel instead of RGB")
    parser.add_argument("--bin", type=int, choices=(1, 2), default=1, dest="binning",
                        help="2: half size, 2x2 cells averaged without demosaicing")
    parser.add_argument("--gamma", default="auto", type=_gamma,
                        help="transfer function of 8- and 16-bit image frames: auto (default: what "
                             "each file declares; for 8-bit files that declare none, the transfer "
                             "under which the object frames best fit a rank-3 (Lambertian) stack, "
                             "sRGB when none fits clearly better; linear for 16-bit), srgb, linear, "
                             "or an exponent such as 2.2; printed with the evidence and recorded")
    parser.add_argument("--compression", choices=COMPRESSIONS, default="auto",
                        help="linear/ EXRs: auto (default: lossless ZIP for the frames it shrinks "
                             "to 1/1.8 or less, such as frames from 8/16-bit files), zip, none")
    parser.add_argument("--half", action="store_true",
                        help="half-float EXRs: half the disk, but lossy (11-bit mantissa)")
    parser.add_argument("--jobs", type=int, default=None, help="worker processes (default: cores)")
    parser.add_argument("--force", action="store_true", help="decode again even when up to date")
    parser.set_defaults(func=run)


def _gamma(text):
    from ..gamma import parse_gamma

    try:
        return parse_gamma(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run(args):
    """Handler: decode, print a summary, exit 1 when a frame failed."""
    from ..decode import decode_session, describe_failures, describe_record, frames_decoded

    session = open_session(args.session, args)
    before = session.stage("decode")
    record = decode_session(session, method=args.method,
                            channels="grey" if args.grey else "rgb", binning=args.binning,
                            gamma=args.gamma, compression=args.compression, half=args.half,
                            jobs=args.jobs, force=args.force)
    done = frames_decoded(record)
    if record is before:
        print(f"decode: up to date ({done} frames)")
        return 0
    subtracted = record.get("subtracted", {}).get("kind") or "nothing"
    print(f"decode: {done} frames decoded into {session.root / 'linear'} "
          f"({record.get('seconds', 0):.1f} s, subtracted: {subtracted})")
    for line in describe_record(record):
        print(f"decode: {line}")
    for warning in record.get("warnings") or []:
        print(f"decode: warning: {warning}")
    for line in describe_failures(record.get("failed")):
        print(f"psrig decode: error: {line}", file=sys.stderr)
    return 0 if record["status"] == "ok" else 1
