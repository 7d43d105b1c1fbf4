"""Which dark or ambient frames are subtracted from which lit frames, and their mean.

Lit frames (object, sphere, target) have the mean of the session's decoded ambient frames
shot for their kind subtracted (it holds the dark signal too), else the mean of its dark
frames. In a bracketed session (:mod:`pipeline.core.brackets`) each exposure has the references
shot at its own shutter time subtracted, never another's: a dark or ambient signal grows with
the exposure.
"""

from pathlib import Path

import numpy as np

from ..core.atomic import atomic_path
from ..core.brackets import format_seconds, frame_shutter, same_shutter
from ..core.imageio import read_image, read_mask
from ..core.session import LIT_KINDS

__all__ = ["REFERENCE_KINDS", "references", "previous_references", "shutter_label", "write_reference"]

#: Kinds subtracted from lit frames, in order of preference.
REFERENCE_KINDS = ("ambient", "dark")


def references(unlit, infos, lit_kind, shutter=None):
    """(kind, [frames], problem) to subtract from lit frames of ``lit_kind`` shot at ``shutter``
    (s; None: not bracketed): the decoded ambient frames shot for that kind (an ambient
    frame's ``applies_to``; every lit kind when it has none) at the same shutter, else the dark
    ones. A dark or ambient signal grows with the exposure, so none is subtracted across
    shutter times: when the session's only references were shot at other ones, ``problem``
    says so (and the frames are not decoded)."""
    def applies(frame, kind):
        return frame["kind"] == kind and (kind != "ambient" or lit_kind in frame.get("applies_to", LIT_KINDS))

    candidates = [f for f in unlit if any(applies(f, kind) for kind in REFERENCE_KINDS)]
    here = [f for f in candidates if same_shutter(frame_shutter(f), shutter)]
    for kind in REFERENCE_KINDS:
        chosen = [f for f in here if applies(f, kind) and f["id"] in infos]
        if chosen:
            return kind, chosen, None
    if here or not candidates:
        return None, [], None  # none at all, or this shutter's could not be decoded (failed)
    shot = sorted({"single exposures" if frame_shutter(f) is None else f"shot at {format_seconds(frame_shutter(f))}"
                   for f in candidates})
    like = "a single exposure" if shutter is None else f"shot at {format_seconds(shutter)}"
    problem = (f"no ambient or dark frame {like} like it to subtract (the session's are "
               f"{' and '.join(shot)}: {', '.join(f['id'] for f in candidates[:4])}); a dark or ambient "
               "signal grows with the exposure, so one of another shutter time is not subtracted: shoot "
               "them with the same exposures as the lit frames")
    return None, [], problem


def previous_references(previous, lit_kind):
    """Frame ids a previous decode record subtracted from single-exposure ``lit_kind`` frames."""
    subtracted = previous.get("subtracted", {})
    return subtracted.get("by_kind", {}).get(lit_kind, subtracted).get("frames")


def shutter_label(frame):
    """A bracketed frame's shutter as the manifest records it (``'1/60'``), else None."""
    bracket = frame.get("bracket")
    return None if bracket is None else str(bracket["shutter"])


def write_reference(session, frames, kind, folder):
    """Mean linear image and union saturation of reference frames, saved as .npy in ``folder``
    (in the session's scratch, which the next writer sweeps if this run is killed)."""
    total, saturated = None, None
    for frame in frames:
        linear = read_image(session.linear_path(frame))
        flags = read_mask(session.saturation_path(frame))
        total = linear.astype(np.float64) if total is None else total + linear
        saturated = flags if saturated is None else saturated | flags
    Path(folder).mkdir(parents=True, exist_ok=True)
    paths = {"kind": kind, "mean": str(Path(folder) / "mean.npy"),
             "saturated": str(Path(folder) / "saturated.npy")}
    with atomic_path(paths["mean"]) as tmp:
        np.save(tmp, (total / len(frames)).astype(np.float32))
    with atomic_path(paths["saturated"]) as tmp:
        np.save(tmp, saturated)
    return paths
