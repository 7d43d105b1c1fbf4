"""``psrig run SESSION... [--jobs N] [--force] [--from STAGE] [stage options] [-q | -v | --json]``.

Output: one line per stage as it finishes (``S: normals: ran in 3.2 s``, with its note and
warnings); ``-v`` adds each stage's settings, outputs and the normals' status shares; ``-q``
prints only warnings and errors (stderr) and no progress; ``--json`` prints one JSON object per
session (:func:`session_summary`) instead of the lines.
"""

import json
import os
import sys
from pathlib import Path

from ..core.errors import InputError
from ..settings import DecodeOptions, IntegrateOptions, NormalsOptions, ReportOptions
from .calibrate import parse_circles

__all__ = ["register", "session_summary", "STAGES"]

#: pipeline.core.session.STAGES, spelled out so that building the parser imports no numpy (a test
#: checks that the two agree)
STAGES = ("decode", "calibrate", "normals", "integrate", "report")


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
    # every stage's options, as its own command spells them (the two methods apart); an option
    # given replaces the recorded one, the others keep what the stage was last run with
    DecodeOptions.add_arguments(parser.add_argument_group("decode (as psrig decode)"),
                                rename={"method": "--decode-method"})
    calib = parser.add_argument_group("calibrate (as psrig calibrate; kept for later runs)")
    calib.add_argument("--circle", action="append", help="sphere outline CX,CY,R in pixels (repeat for several)")
    calib.add_argument("--sphere-mask", metavar="FILE", help="mask of the sphere(s), one blob per sphere")
    outline = calib.add_mutually_exclusive_group()
    outline.add_argument("--outline", metavar="FILE", help="evenly lit photo of the sphere(s) to find them on")
    outline.add_argument("--no-outline", action="store_true", help="find the spheres on the light frames")
    calib.add_argument("--calibration-from", metavar="OTHER_SESSION",
                       help="use another session's calibration (psrig calibrate --from)")
    NormalsOptions.add_arguments(parser.add_argument_group("normals (as psrig normals)"), first=("method",))
    # one --memory (the normals group's) is the budget of normals and integrate alike
    IntegrateOptions.add_arguments(parser.add_argument_group("integrate (as psrig integrate)"),
                                   rename={"method": "--integrate-method"}, skip=("memory",))
    ReportOptions.add_arguments(parser.add_argument_group("report (as psrig report)"))
    parser.add_argument("--scheduler", nargs="?", const="local", metavar="ADDRESS",
                        help="run on a Dask cluster (psrig[cluster]): the scheduler's address, "
                             "or no address for a local cluster of --jobs workers; photometric "
                             "stereo is split into pixel tiles (put it after the session "
                             "folders, or write --scheduler local)")
    output = parser.add_mutually_exclusive_group()
    output.add_argument("-q", "--quiet", action="store_true",
                        help="print only warnings and errors (stderr), no progress")
    output.add_argument("-v", "--verbose", action="store_true",
                        help="also print each stage's settings and outputs and the normals' status shares")
    output.add_argument("--json", action="store_true",
                        help="print one JSON object per session (stages run, times, status shares, "
                             "warnings, output paths) instead of lines")
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
    from ..runner import run_sessions

    if args.jobs < 1:
        print("psrig run: error: --jobs must be >= 1", file=sys.stderr)
        return 2
    if args.quiet:
        os.environ["PSRIG_PROGRESS"] = "off"  # an environment variable: worker processes see it too
    options = {"decode": DecodeOptions.from_args(args),
               "calibrate": {k: v for k, v in _calibration(args).items() if v is not None},
               "normals": NormalsOptions.from_args(args), "integrate": IntegrateOptions.from_args(args),
               "report": ReportOptions.from_args(args)}
    if "memory" in options["normals"]:
        options["integrate"]["memory"] = options["normals"]["memory"]
    lines = not (args.quiet or args.json)
    run = dict(options=options, force=args.force, start=args.start, stop=args.stop, jobs=args.jobs,
               echo=(lambda line: print(line, flush=True)) if lines else None, wait=args.wait)
    if args.scheduler is not None:  # a batch on Dask, photometric stereo in pixel tiles
        from ..cluster import run_batch, summary_table

        outcomes = run_batch(args.sessions, scheduler=args.scheduler, **run)
        if lines:
            print(summary_table(outcomes), flush=True)
    else:
        outcomes = run_sessions(args.sessions, **run)
    for outcome in outcomes:
        if args.json or args.verbose:   # these re-open the session for its records
            summary = session_summary(outcome)
            for line in [json.dumps(summary)] if args.json else _details(summary):
                print(line, flush=True)
        elif args.quiet:
            for stage in outcome.stages:
                for warning in stage.warnings:
                    print(f"{outcome.root}: warning: {stage.name}: {warning}", file=sys.stderr)
        elif not outcome.error and any(s.name == "report" for s in outcome.stages):
            _print_report_path(outcome)
    failed = [o for o in outcomes if o.error]
    for outcome in failed if not args.json else ():
        print(f"psrig run: error: {outcome.error}", file=sys.stderr)
    return 1 if failed else 0


def _print_report_path(outcome):
    """The report's path after a run's stage lines (the file a person opens next)."""
    from ..core.errors import PsrigError
    from ..core.paths import REPORT
    from ..core.session import Session

    try:
        path = _output(Session.open(outcome.root), REPORT)
    except PsrigError:
        return
    if path:
        print(f"{outcome.root}: report: {path}", flush=True)


def session_summary(outcome):
    """One session's run as plain data (what ``--json`` prints).

    Returns
    -------
    dict
        ``session`` (path), ``ok``, ``error`` (or None), ``seconds`` (all stages), ``stages``
        [{name, ran, seconds, note, status, warnings, settings, outputs}], ``status_shares``
        {status name: share of the object's pixels} (when the normals stage has run),
        ``warnings`` ["stage: text"] and ``outputs`` {what: absolute path} of the files a person
        opens (report, normals, depth, meshes), those that exist.
    """
    from ..core.errors import PsrigError
    from ..core.paths import DEPTH, MESH, MESH_OBJ, NORMALS, REPORT
    from ..core.session import Session

    try:
        session = Session.open(outcome.root)
    except PsrigError:
        session = None
    from ..report.details import settings_used

    stages, warnings = [], []
    for stage in outcome.stages:
        record = (session.stage(stage.name) if session else None) or {}
        stages.append({"name": stage.name, "ran": stage.ran, "seconds": round(stage.seconds, 3),
                       "note": stage.note or None, "status": record.get("status"),
                       "warnings": list(stage.warnings), "settings": settings_used(stage.name, record),
                       "outputs": list(record.get("outputs") or [])})
        warnings += [f"{stage.name}: {w}" for w in stage.warnings]
    normals = (session.stage("normals") if session else None) or {}
    pixels = normals.get("pixels") or sum((normals.get("status_counts") or {}).values())
    shares = {name: round(count / pixels, 6) for name, count in (normals.get("status_counts") or {}).items()} \
        if pixels else {}
    files = {"report": REPORT, "normals": NORMALS, "depth": DEPTH, "mesh_ply": MESH, "mesh_obj": MESH_OBJ}
    outputs = {key: path for key, path in ((key, _output(session, rel)) for key, rel in files.items()) if path}
    return {"session": outcome.root, "ok": not outcome.error, "error": outcome.error or None,
            "seconds": round(sum(s.seconds for s in outcome.stages), 3), "stages": stages,
            "status_shares": shares, "warnings": warnings, "outputs": outputs}


def _details(summary):
    """``-v``'s lines after the stage lines: settings, outputs and status shares."""
    root = summary["session"]
    for stage in summary["stages"]:
        settings = ", ".join(f"{k}={v}" for k, v in stage["settings"].items()) or "defaults"
        yield f"{root}: {stage['name']}: settings: {settings}"
        if stage["outputs"]:
            shown = stage["outputs"][:6]
            more = f" and {len(stage['outputs']) - len(shown)} more" if len(stage["outputs"]) > len(shown) else ""
            yield f"{root}: {stage['name']}: outputs: {', '.join(shown)}{more}"
    if summary["status_shares"]:
        from ..photometric import share_text   # after a run: photometric stereo is loaded already

        shares = ", ".join(f"{name} {share_text(share, 1.0)}" for name, share in summary["status_shares"].items())
        yield f"{root}: normals: status: {shares}"
    for key, path in summary["outputs"].items():
        yield f"{root}: {key}: {path}"


def _output(session, rel):
    """The absolute path of a session file that exists, else None (also for a failed session
    whose folders the run refused: the summary must not fail where the run did)."""
    from ..core.errors import PsrigError

    try:
        path = session.path(rel) if session else None
    except PsrigError:
        return None
    return str(path.resolve()) if path is not None and path.is_file() else None
