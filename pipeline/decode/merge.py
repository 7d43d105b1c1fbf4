"""The decode stage's exposure merge: the exposures of a bracket -> ``linear/<group>.exr``.

A merge task holds the exposures of one bracket group (:class:`pipeline.core.brackets.BracketGroup`)
in one of two forms, and the pool (:func:`pipeline.decode.pool.decode_task`) writes its result
like a decoded frame:

- lit frames (object, sphere, target): each exposure's raw file and the mean reference (dark
  or ambient) of its own shutter time. The worker decodes them in memory, subtracts, merges
  and writes only the merged frame: a 12 MP exposure is 144 MB, and keeping every exposure
  would triple ``linear/`` for a two-shutter bracket.
- dark, ambient and outline frames: their exposures are decoded to ``linear/<exposure>.exr``
  first (the references of each shutter time are means of them), and merged from there.

Merging (:func:`pipeline.decode.hdr.merge_exposures`) takes each pixel from the longest
unsaturated exposure, scaled to the session's reference shutter (the shortest of its
brackets). A merged frame is reused by a later run while what its task read is unchanged
(:func:`lit_inputs`, :func:`decoded_inputs`: one sha256 over the exposures' raw hashes and
references, or over their decoded outputs), so a re-shot exposure re-merges its group only.
"""

import hashlib
import json

from ..core.brackets import format_seconds
from ..core.errors import PsrigError
from .hdr import merge_exposures, ratio_error

__all__ = ["merge_linear", "merge_task", "lit_inputs", "decoded_inputs", "unmergeable", "TOLERANCE",
           "WARN_SHARE"]

#: A bracket whose exposures' measured ratio is further than this from their shutter ratio is
#: refused (see :mod:`pipeline.decode.hdr`) ...
TOLERANCE = 0.2
#: ... and one further than this merged, with a warning in the record.
WARN_SHARE = 0.05


def merge_task(session, group, members, reference, options, size):
    """The pool task merging ``group`` into its linear frame, scaled to ``reference`` (s).

    ``members``: one dict per exposure (in ``group.frames`` order) with ``id`` and ``shutter``
    (s), and either ``source`` (raw file) and ``reference`` (None or the mean dark/ambient
    frame's .npy paths, as for a decode task) or ``linear`` and ``saturation`` (its decoded
    outputs).
    """
    return {"id": group.id, "merge": members, "reference_shutter": reference,
            "linear": str(session.linear_path(group.id)), "saturation": str(session.saturation_path(group.id)),
            "options": options, "size": size}


def _digest(rows):
    return hashlib.sha256(json.dumps(rows, sort_keys=True, default=str).encode()).hexdigest()


def lit_inputs(group, inputs, references, reference):
    """One sha256 over what a lit group's merge reads: each exposure's id, file and raw hash
    (from the stage's ``inputs``), the reference frames of its shutter (``references``:
    {exposure id: [frame dicts]}) with their raw hashes, and the reference shutter (s)."""
    rows = [[f["id"], f["file"], inputs.get(f["file"]),
             [[r["id"], r["file"], inputs.get(r["file"])] for r in references[f["id"]]]]
            for f in group.frames]
    return _digest([rows, reference])


def decoded_inputs(session, group, hashes, reference):
    """One sha256 over the decoded outputs a merge of an unlit ``group`` reads (their hashes
    from ``hashes``, the run's {output rel: sha256}) and the reference shutter, or None when
    one of them is not there."""
    rels = [session.rel(path) for f in group.frames
            for path in (session.linear_path(f), session.saturation_path(f))]
    if not all(rel in hashes for rel in rels):
        return None
    return _digest([[[rel, hashes[rel]] for rel in rels], reference])


def unmergeable(group, failed):
    """Why ``group`` cannot be merged (exposures missing from the manifest or failed), or None."""
    missing = group.missing()
    if missing:
        return (f"frame {group.id!r}: {len(group.frames)} of the {group.of} exposures of its bracket are in "
                f"the session (index {', '.join(map(str, missing))} missing: the capture stopped mid-bracket); "
                "not merged: complete the capture with psrig capture --resume")
    broken = [f["id"] for f in group.frames if f["id"] in failed]
    if broken:
        reasons = "; ".join(failed[i] for i in broken)
        return f"frame {group.id!r}: not merged: {reasons}"
    return None


def merge_linear(task, exposures):
    """Merge a merge task's exposures (in a worker).

    Parameters
    ----------
    task : dict
        From :func:`merge_task`.
    exposures : list of (linear, saturated, info)
        Each member's linear frame (H, W, C) float32 (black and its reference removed), its
        saturation (H, W) bool and its decode info ({} when read from ``linear/``).

    Returns
    -------
    linear : ndarray (H, W, C) float32
        Scaled to ``task['reference_shutter']`` (1.0 = white at that shutter time).
    saturated : ndarray (H, W) bool
        Saturated in every exposure.
    info : dict
        ``merged_from`` (exposure ids), ``shutters`` ({id: s}), ``reference_shutter`` (s),
        ``from`` ({id: share of the pixels taken from it}), ``saturated_in_all`` (share),
        ``ratios`` (measured against expected, :func:`pipeline.decode.hdr.exposure_ratios`),
        ``warnings`` and, for exposures decoded here, ``exposures`` ({id: decode info}).
    """
    members = task["merge"]
    try:
        result = merge_exposures([e[0] for e in exposures], [m["shutter"] for m in members],
                                 [e[1] for e in exposures], reference=task["reference_shutter"],
                                 tolerance=TOLERANCE)
    except PsrigError as exc:
        raise PsrigError(f"frame {task['id']!r} (exposures {', '.join(m['id'] for m in members)}): {exc}") from None
    pixels = result.source.size
    counts = result.record["values_from"]
    info = {"merged_from": [m["id"] for m in members],
            "shutters": {m["id"]: m["shutter"] for m in members},
            "reference_shutter": task["reference_shutter"],
            "from": {m["id"]: round(counts[float(m["shutter"])] / pixels, 6) for m in members},
            "saturated_in_all": round(result.record["saturated_in_all"] / pixels, 6),
            "ratios": result.record["ratios"],
            "warnings": [_ratio_warning(task["id"], entry) for entry in result.record["ratios"]
                         if ratio_error(entry) > WARN_SHARE]}
    decoded = {m["id"]: e[2] for m, e in zip(members, exposures) if "source" in m}
    if decoded:
        info["exposures"] = decoded
    return result.image, result.saturated, info


def _ratio_warning(group_id, entry):
    short, long = entry["shutters"]
    return (f"frame {group_id!r}: the exposure at {format_seconds(long)} is {entry['measured']:.3f} x the one at "
            f"{format_seconds(short)}, its shutter time says {entry['expected']:.3f} x; merged as the shutter "
            "times say")
