"""``psrig capture SESSION --rig NAME [--resume]``: capture a session on a rig.

The rig comes from the rig file (``--config``, else $PSRIG_RIGS, else ./rigs.yaml, else psrig's
own); ``--rig sim`` needs no hardware. A capture stopped by an error, Ctrl-C, SIGTERM or a kill
leaves a valid session that ``--resume`` completes (see :mod:`rig.capture`).

Debugging and tests: the environment variable ``PSRIG_SIM_FAULTS`` injects faults into a
simulated rig, e.g. ``PSRIG_SIM_FAULTS="busy:2,garble:1@object_005,camera.disconnect@sphere_003"``
(``name[:count][@frame id]``; the fault names are listed in :mod:`rig.sim.rig`). It is ignored
for real rigs.
"""

import os
import sys
from pathlib import Path

from .writing import open_session

__all__ = ["register", "run", "FAULTS_ENV"]

FAULTS_ENV = "PSRIG_SIM_FAULTS"


def register(subparsers):
    parser = subparsers.add_parser(
        "capture", help="capture object, sphere, dark and ambient frames into a session",
        description="Capture a session: dark and ambient frames with the lights off, one frame per "
                    "light, then the chrome sphere (the operator is asked to place it). Stopped "
                    "captures are completed with --resume; nothing captured is ever overwritten.")
    parser.add_argument("session", metavar="SESSION", help="session folder (new, empty, or to resume)")
    parser.add_argument("--rig", required=True, metavar="NAME", help="rig of the rig file (e.g. sim)")
    parser.add_argument("--config", metavar="FILE", help="rig file to read instead of rigs.yaml")
    parser.add_argument("--resume", action="store_true",
                        help="complete an existing session: verify its frames, capture the missing ones")
    parser.add_argument("--no-sphere", dest="sphere", action="store_false", default=None,
                        help="skip the chrome-sphere frames")
    parser.add_argument("--yes", action="store_true",
                        help="do not ask before the sphere frames (the sphere is already in place)")
    parser.add_argument("--no-preview-check", dest="preview", action="store_false", default=None,
                        help="start even when a preview of the brightest light clips")
    parser.add_argument("--max-clipped", type=float, metavar="SHARE",
                        help="largest clipped share of a channel the preview may show "
                             "(default the rig's preview: max_clipped, 0.01)")
    parser.set_defaults(func=run)


def _prompt_yes(message):
    print(f"{message}: assumed done (--yes)", file=sys.stderr)
    return True


def run(args):
    from rig.capture import capture_session
    from rig.config import get_rig

    rig = get_rig(args.rig, args.config)
    sim = None
    if rig.is_simulated and os.environ.get(FAULTS_ENV):
        from rig.sim.rig import SimulatedRig

        sim = SimulatedRig(rig, faults=os.environ[FAULTS_ENV])
    from ..core.session import MANIFEST

    # an existing session is locked before any device is touched (a new one, once it is made)
    target = open_session(args.session, args) if (Path(args.session) / MANIFEST).is_file() else args.session
    try:
        preview = rig.preview["check"] if args.preview is None else args.preview
        capture_session(target, rig, resume=args.resume, sim=sim, sphere=args.sphere,
                        on_prompt=_prompt_yes if args.yes else None, preview=preview,
                        max_clipped=args.max_clipped)
    except KeyboardInterrupt as exc:
        reason = str(exc) or "interrupted"
        config = f" --config {args.config}" if args.config else ""
        left_on = getattr(exc, "lights_left_on", None)
        lights = f"{left_on};" if left_on else "lights switched off,"
        print(f"psrig capture: {reason}; {lights} the frames captured so far are kept. "
              f"Complete with: psrig capture {args.session} --rig {args.rig}{config} --resume",
              file=sys.stderr)
        return 130
    return 0
