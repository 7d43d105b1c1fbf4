"""``psrig decode SESSION``: raw frames -> linear EXR + saturation masks in linear/."""

import sys

from ..settings.decode import COMPRESSIONS, DecodeOptions
from .writing import open_session

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
    DecodeOptions.add_arguments(parser)
    parser.add_argument("--jobs", type=int, default=None, help="worker processes (default: cores)")
    parser.add_argument("--force", action="store_true", help="decode again even when up to date")
    parser.set_defaults(func=run)


def run(args):
    """Handler: decode, print a summary, exit 1 when a frame failed."""
    from ..decode import decode_session, describe_failures, describe_record, frames_decoded

    session = open_session(args.session, args)
    before = session.stage("decode")
    record = decode_session(session, jobs=args.jobs, force=args.force, **DecodeOptions.from_args(args))
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
