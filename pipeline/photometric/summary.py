"""What the normals stage says of a run: its warnings and its one line.

:func:`normals_warnings` turns a run's status counts and its checks (the single-material check,
the frames' gains and light directions of :mod:`pipeline.photometric.frame_gains`, the outline
of :mod:`pipeline.photometric.outline`, the frames' registration of
:mod:`pipeline.photometric.registration`) into the warnings the stage records; the report, ``psrig
normals`` and ``psrig run`` show them. :func:`normals_summary` is the line printed per session.
"""

import numpy as np

from ..core.paths import EXCLUDE, LIGHTS
from .frame_gains import UNCALIBRATED_SHARE
from .methods import share_text
from .outline import SEEN_WHOLE, mirrored_axes, transposed_axes
from .prediction import prediction_line

__all__ = ["normals_warnings", "normals_summary", "uncertainty_text", "WARN_SHARES"]

#: shares of the object's pixels above which the summary warns, per status
WARN_SHARES = {"lambert_fallback": 0.2, "shared_shape": 0.2, "not_converged": 0.05, "too_few": 0.1,
               "shadowed": 0.1, "ill_posed": 0.0, "uncertain": 0.1}
_WARNINGS = {
    "lambert_fallback": "{share} of pixels fell back to Lambert: too few observations for the biquadratic "
                        "model ({lights} lights)",
    "shared_shape": "{share} of pixels were fitted with the object's shared shape alone: too few observations "
                    "for the full model ({lights} lights)",
    "not_converged": "{share} of pixels did not converge (their normal still turned after the last step)",
    "too_few": "{share} of pixels had fewer than 3 usable observations: no normal",
    "shadowed": "{share} of pixels were dark in every frame: no normal",
    "uncertain": "{share} of pixels are uncertain: their expected angular error is over the threshold "
                 "(normals/uncertainty.exr, the report's expected-error map); their normals are kept",
    "ill_posed": "{count} pixel(s) have no normal: their observations determine none facing the camera "
                 "(lights too close to coplanar there, or lit only indirectly)",
}


def normals_warnings(counts, lights, options, frame_gains=None, transfer=(), registration=None):
    """What a user should know of a normals run (list of str): statuses over their share of the
    object's pixels (:data:`WARN_SHARES`), a failed single-material check, and the frames
    rescaled to the others' brightness (``frame_gains``, the stage record's entry that
    :func:`pipeline.photometric.stage.frame_gains_record` makes; ``transfer`` the decode record's
    transfer functions, which a wrong one explains too), the frames' light directions, the
    outline check and the frames that do not register with the others (``registration``, the
    stage record's entry of :func:`pipeline.photometric.registration.check_registration`)."""
    pixels = max(sum(counts.values()), 1)
    # the share as the status line prints it: 99.6 % is not "100 % of pixels" beside 0.4 % of others
    warnings = [_WARNINGS[name].format(share=share_text(counts[name], pixels), count=counts[name], lights=lights)
                for name, limit in WARN_SHARES.items() if counts.get(name) and counts[name] / pixels > limit]
    check = options.get("shape_check") or {}
    if "fallback" in check:
        warnings.append(f"one shared shape does not fit the object (residual ratio {check['ratio']:g}, "
                        f"{check['expected']:g} expected for one material): several materials? Each pixel "
                        "was fitted with the Lambertian prior instead")
    frame_gains = frame_gains or {}
    warnings += _gain_warnings(frame_gains, lights, transfer)
    if not frame_gains.get("uncalibrated"):   # else the fit the directions rest on is off too
        warnings += _direction_warnings(frame_gains.get("directions") or {}, lights)
    warnings += _outline_warnings(options.get("outline_check"))
    warnings += _registration_warnings(registration or {}, lights)
    return warnings


def _registration_warnings(found, lights):
    moved = found.get("moved") or {}
    if not moved:
        return []
    sizes = [float(np.hypot(*shift)) for shift in moved.values()]
    span = f"{min(sizes):.1f}-{max(sizes):.1f} px" if len(sizes) > 1 else f"{sizes[0]:.1f} px"
    if found.get("run_from") is not None:
        which = f"every frame from {found['run_from']} on ({len(moved)} of {lights})"
        why = "the object or the camera moved during the capture, before that frame"
    else:
        listed = ", ".join(list(moved)[:6]) + (f" and {len(moved) - 6} more" if len(moved) > 6 else "")
        which = f"frame(s) {listed} ({len(moved)} of {lights})"
        why = "the object or the camera moved while they were taken"
    said = f"{which}: the object sits {span} away from where the other frames and the normals put it " \
           f"(registered against the normals' rendering of each frame): {why}? "
    if found.get("aligned"):
        return [said + "They were aligned to the others by those shifts and the normals solved again "
                "(psrig normals --align-frames off: only say); capture them again to be sure"]
    why_not = f" (not aligned: {found['not_aligned']})" if found.get("not_aligned") else ""
    return [said + "Their pixels see other points of the surface, which blurs and biases the normals: capture "
            f"them again, or leave their lights out by hand ({EXCLUDE}){why_not}"]


def _outline_warnings(check):
    exchanged = transposed_axes(check)
    if exchanged is not None:
        turned = f", and {' and '.join(exchanged)} then the other way" if exchanged else ""
        swapped = check["swapped"]
        return [f"the normals at the object's outline agree with it only with their x and y exchanged "
                f"({swapped['x']:.0%} in x, {swapped['y']:.0%} in y, against {SEEN_WHOLE} on objects seen "
                f"whole): the light file's x and y are probably swapped{turned} (psrig's camera frame: x right, "
                "y up toward the top of the image, z toward the camera): exchange the light file's x and y "
                f"columns{', negate ' + ' and '.join(exchanged) + ' after,' if exchanged else ''} and import again"]
    mirrored = mirrored_axes(check)
    if not mirrored:
        return []
    axes = " and ".join(mirrored)
    shares = ", ".join(f"{check[axis]:.0%} in {axis}" for axis in mirrored)
    return [f"the normals at the object's outline point into the mask along {axes}: {shares} of the outline "
            f"pixels agree with it, against {SEEN_WHOLE} on objects seen whole. The light file's {axes} "
            f"{'axes probably point' if len(mirrored) > 1 else 'axis probably points'} the other way "
            "(psrig's camera frame: x right, y up toward the top of the image, z toward the camera): negate "
            f"{axes} in the light file and import again, unless the mask is not the object's silhouette"]


def _gain_warnings(frame_gains, lights, transfer=()):
    rescaled = frame_gains.get("rescaled") or {}
    if not rescaled:
        return []
    # the farthest from 1 first: a frame rescaled by 0.09x must not hide behind "... and 13 more"
    rescaled = dict(sorted(rescaled.items(), key=lambda item: -abs(np.log(max(item[1], 1e-12)))))
    gamma = _transfer_hint(transfer)
    if frame_gains.get("uncalibrated"):
        low, high = min(rescaled.values()), max(rescaled.values())
        farthest = ", ".join(f"{name} ({gain:.2f}x)" for name, gain in list(rescaled.items())[:3])
        return [f"{len(rescaled)} of {lights} frames are not as bright as the lights' intensities say "
                f"({low:.2f}x to {high:.2f}x the others; farthest {farthest}): were the intensities given "
                f"({LIGHTS})? The frames "
                "were rescaled to the others, but a brightness that changes steadily across the lights "
                "looks like a tilt of the whole object: calibrate the intensities, the normals may be off "
                f"by degrees (the lights' directions were not judged){gamma}"]
    listed = ", ".join(f"{name} ({gain:.2f}x)" for name, gain in list(rescaled.items())[:6])
    more = f" and {len(rescaled) - 6} more" if len(rescaled) > 6 else ""
    return [f"frame(s) {listed}{more}: brighter or darker than their lights' intensities in {LIGHTS} say, "
            "measured against the other frames; rescaled (a light that dimmed or misfired, a changed "
            f"exposure, or a wrong intensity?){gamma}"]


def _direction_warnings(directions, lights):
    off, swapped, dark = directions.get("off") or {}, directions.get("swapped") or [], directions.get("dark") or []
    said = [f"frame(s) {', '.join(dark)}: dark at almost every pixel that faces its light (did the light fire?); "
            "the shadow test left it out"] if dark else []
    if len(off) > UNCALIBRATED_SHARE * lights:
        return said + [f"{len(off)} of {lights} frames' lights are not where {LIGHTS} puts them, by the images "
                       f"(up to {max(v['angle'] for v in off.values()):.0f} degrees off): do the light file's order "
                       "and the frames' order match?"]
    said += [f"frames {a} and {b} look swapped: by the images each one's light is where {LIGHTS} puts the "
             "other's (are the frames and the light file in the same order?)" for a, b in swapped]
    paired = {name for pair in swapped for name in pair}
    for name, found in off.items():
        if name in paired:
            continue
        if "like" in found:
            said.append(f"frame {name}: by the images its light is frame {found['like']}'s (a frame captured twice, "
                        "or the frames' order shifted?)")
        else:
            where = ", ".join(f"{c:.2f}" for c in found["estimated"])
            said.append(f"frame {name}: by the images its light is {found['angle']:.0f} degrees from where "
                        f"{LIGHTS} puts it, at ({where}) (a wrong order, a light that moved, or a bad "
                        "calibration?)")
    return said


def _transfer_hint(transfer):
    """A wrong transfer function bends each frame by its brightness, which reads as gains too
    (DiLiGenT ball's linear frames decoded as sRGB: 23 of 96 frames rescaled): the decode
    record's non-linear curves are named."""
    curves = [str(name) for name in transfer if not str(name).lower().startswith("linear")]
    return f"; decode used {' / '.join(curves)}: if the frames hold linear values, decode with --gamma linear" \
        if curves else ""


def normals_summary(record):
    """One line of a normals record: pixels, the status shares, the light correction."""
    pixels = max(record.get("pixels") or 0, 1)
    counts = (record.get("status_counts") or {}).items()
    shares = ", ".join(f"{name} {share_text(count, pixels)}" for name, count in counts if count)
    anchor = record.get("specular_anchor") or {}
    cone = f"; lights' cone scaled by {anchor['cone_scale']:.3f} (specular anchor{_range_text(anchor)})" \
        if anchor.get("anchor") == "corrected" else ""
    by_hand = record.get("lights_left_out_by_hand") or {}
    left_out = [k for k in record.get("lights_left_out") or [] if str(k) not in by_hand]
    flagged = f"; lights left out (flagged in {LIGHTS}): {', '.join(map(str, left_out))}" if left_out else ""
    if by_hand:
        flagged += f"; lights left out by hand ({EXCLUDE}): {', '.join(by_hand)}"
    mask = (record.get("mask") or {}).get("text")
    doubt = doubtful(record)
    lead = f"{record.get('pixels', 0)} pixels, normals doubtful ({doubt}; see the warning); fit status" if doubt \
        else f"{record.get('pixels', 0)} pixels"
    rescaled = (record.get("frame_gains") or {}).get("rescaled") or {}
    gains = f"; {len(rescaled)} frame(s) rescaled to the others' brightness" if rescaled else ""
    found = record.get("registration") or {}
    aligned = f"; {len(found['moved'])} moved frame(s) aligned to the others" if found.get("aligned") else ""
    held = prediction_line(record.get("prediction"))
    held = f"; {held}" if held else ""
    return f"{lead}: {shares}{cone}{gains}{aligned}{flagged}{uncertainty_text(record)}{held}" + \
        (f"; {mask}" if mask else "")


def doubtful(record):
    """Why a normals record's result as a whole is in doubt although its pixels' fits are fine
    (the status shares say how each fit went, not whether the lights were right), or ''."""
    gains = record.get("frame_gains") or {}
    if gains.get("uncalibrated"):
        return "the frames' brightness does not follow the lights' intensities: the whole map may be tilted"
    lights = record.get("lights_used") or 0
    off = (gains.get("directions") or {}).get("off") or {}
    if lights and len(off) > UNCALIBRATED_SHARE * lights:
        return "the lights are not where the light file puts them, by the images"
    return ""


def uncertainty_text(record):
    """'; 82 % of pixels expected within 5 degrees, 6 % uncertain (over 20 degrees)', or why the
    run has no uncertainty map ('' for records of earlier versions, which have neither)."""
    found = record.get("uncertainty")
    if not found:
        return ""
    if "not_estimated" in found:
        return f"; uncertainty {found['not_estimated']}"
    pixels = max(found.get("pixels", 0), 1)
    within = share_text(round(found["within_5"] * pixels), pixels)
    over = share_text(round(found["over_threshold"] * pixels), pixels)
    return (f"; {within} of pixels expected within 5 degrees, {over} uncertain "
            f"(over {found['threshold_deg']:g} degrees)")


def _range_text(anchor):
    spread = anchor.get("cone_scale_range")
    return f"; {spread[0]:.3f}-{spread[1]:.3f} over resampled highlights" if spread else ""
