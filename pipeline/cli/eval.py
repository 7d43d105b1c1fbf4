"""``psrig eval SESSION [--json]``: errors against the session's ground truth."""

import json
import sys

from .writing import open_session
__all__ = ["register", "format_summary"]


def register(subparsers):
    """Add the ``eval`` sub-command."""
    parser = subparsers.add_parser(
        "eval", help="errors against ground truth, when the session has it",
        description="Score normals (angular error), lights (per-light angle) and depth (mean "
                    "absolute error after an offset or scale fit) against the session's ground "
                    "truth; writes normals/eval.yaml and normals/error.png. Also shows the normals "
                    "stage's held-out-light prediction (normals/prediction.yaml), which needs no "
                    "ground truth.")
    parser.add_argument("session", metavar="SESSION", help="session folder")
    parser.add_argument("--json", action="store_true", help="print the numbers as JSON")
    parser.add_argument("--max-deg", type=float, default=30.0,
                        help="top of the error map's colour scale, degrees (default 30, the same "
                             "for every session so that maps compare)")
    parser.set_defaults(func=run)


def run(args):
    from ..evaluate import evaluate_session
    from ..photometric.prediction import prediction_line, read_prediction

    session = open_session(args.session, args)
    result = evaluate_session(session, max_deg=args.max_deg)
    held_out = read_prediction(session)
    if args.json:
        print(json.dumps(dict(result, **({"prediction": held_out} if held_out else {})), indent=2))
    elif result:
        print(format_summary(result))
    if held_out and not args.json:
        print(prediction_line(held_out))
    if not result and not held_out:   # a script must not take "nothing evaluated" for a pass
        print(f"psrig eval: error: {session.root}: nothing to evaluate ({_why_nothing(session)})", file=sys.stderr)
        return 1
    return 0


def _why_nothing(session):
    """Why a session has nothing to evaluate: no ground truth, or no result for the truth it has."""
    truth = sorted(k for k in session.manifest["truth"] if k != "mask" and session.truth(k) is not None
                   and session.truth(k).is_file())
    if not truth:
        return "the session has no ground truth; psrig import diligent brings a data set's"
    return f"ground truth for {', '.join(truth)}, but no result to compare yet; run psrig run {session.root} first"


def format_summary(result):
    """One line per evaluated item, as printed by ``psrig eval`` and ``psrig demo``."""
    lines = []
    if "normals" in result:
        n = result["normals"]
        lines.append(f"normals: mean {n['mean_deg']:.2f} deg, median {n['median_deg']:.2f} deg, "
                     f"p90 {n['p90_deg']:.2f} deg, under 5/10/20 deg: {n['under_5_deg']:.1%} / "
                     f"{n['under_10_deg']:.1%} / {n['under_20_deg']:.1%} over {n['pixels']} pixels")
    if "normals" in result and "uncertainty" in result["normals"]:
        from ..photometric.uncertainty import agreement_text

        lines.append(f"uncertainty: {agreement_text(result['normals']['uncertainty'])}")
    if "lights" in result:
        lines.append(_lights_line(result["lights"]))
    if "depth" in result:
        d = result["depth"]
        article = "an" if d["fit"] == "offset" else "a"
        lines.append(f"depth: mean abs {d['mean_abs']:.3f}, median abs {d['median_abs']:.3f} "
                     f"(in the ground truth's unit, after {article} {d['fit']} fit)")
    return "\n".join(lines)


def _lights_line(lights):
    if lights.get("evaluated") is False:
        return "lights: imported, not evaluated (they are the ground truth's own)"
    if "mean_deg" not in lights:
        return f"lights: not evaluated, every light flagged ({len(lights.get('flagged', []))})"
    line = (f"lights: mean {lights['mean_deg']:.3f} deg, median {lights['median_deg']:.3f} deg, "
            f"max {lights['max_deg']:.3f} deg (light {lights['worst_light']})")
    if "intensities" in lights:
        i = lights["intensities"]
        line += f"; intensities mean {i['mean_pct']:.2f} %, max {i['max_pct']:.2f} % (light {i['worst_light']})"
    if lights.get("flagged"):
        line += f"; {len(lights['flagged'])} flagged light(s) left out"
    return line
