"""The session stage: sphere frames -> calibration/lights.yaml, lights.lp, overlays.

Chrome spheres give the directions (and, with two of them, near-light positions); a matte
sphere in the same frames gives the per-light, per-channel intensities. An evenly lit photo of
the spheres (``outline``), when given, is where their circles are found.
"""

import time
from pathlib import Path

import numpy as np

from pipeline.core.gamma import encode_gamma
from pipeline.core.errors import ImageFileError, InputError, StageError
from pipeline.core.imageio import read_image, read_mask
from pipeline.core.session import file_sha256
from pipeline.core.lightsio import LightSet, exclusion_note, read_lights_yaml, write_lights_yaml, write_lp
from pipeline.core.paths import EXCLUDE, LIGHTS, LIGHTS_LP
from pipeline.settings.calibrate import CalibrateOptions
from pipeline.core.stage import Stage

from .intensities import target_intensities
from .overlays import write_overlay, write_sphere_overlays
from .positions import frame_offset
from .reuse import reuse_calibration
from .sphere import calibrate_sphere

__all__ = ["calibrate_session", "lights_without_spheres", "OVERLAY", "OVERLAY_OUTLINE", "CalibrateStage", "CALIBRATE"]

OVERLAY = "calibration/overlay.png"
OVERLAY_OUTLINE = "calibration/overlay_outline.png"


def _load(session, frames):
    """Linear frames (K, H, W, C) and saturation masks (K, H, W) of ``frames``."""
    images, sats = [], []
    for f in frames:
        path = session.linear_path(f)
        if not path.is_file():
            raise StageError(f"{path}: linear frame {f['id']!r} is missing; run psrig decode first")
        images.append(read_image(path))
        if images[-1].shape != images[0].shape:
            raise StageError(f"{path}: size {images[-1].shape} differs from the first sphere frame's "
                             f"{images[0].shape}")
        sat = session.saturation_path(f)
        sats.append(read_mask(sat) if sat.is_file() else np.zeros(images[-1].shape[:2], bool))
    return np.stack(images), np.stack(sats)


def _intensities(result, images, sats, K):
    """(K, C) intensities from the first matte target, or ones; and a note on how."""
    ones = np.ones((images.shape[0], images.shape[-1]))
    if not result.targets:
        return ones, "no matte target in view: intensities = 1"
    directions = np.where(np.isfinite(result.directions), result.directions, [0.0, 0.0, 1.0])
    values = target_intensities(images, directions, circle=result.targets[0].params, saturation=sats, K=K,
                                positions=result.positions, offset=frame_offset(images.shape[1:3]))
    bad = ~np.isfinite(values).all(1) | (values <= 0).any(1)
    for k in np.flatnonzero(bad):
        result.flags.setdefault(int(k), "the matte target was not lit enough to measure the intensity")
    values[bad] = np.nanmedian(values[~bad], axis=0) if (~bad).any() else 1.0
    return values, "matte sphere: least squares of pixel = I max(n.l, 0) + ambient, mean 1"


def _positions(result):
    """Positions (K, 3) with the untriangulated ones put at the median distance, or None."""
    if result.positions is None:
        return None
    pos = result.positions.copy()
    bad = ~np.isfinite(pos).all(1)
    dist = np.nanmedian(np.linalg.norm(pos[~bad], axis=1)) if (~bad).any() else 1.0
    directions = np.where(np.isfinite(result.directions), result.directions, [0.0, 0.0, 1.0])
    pos[bad] = directions[bad] * dist
    return pos


def _extra(result, note):
    rounded = lambda a, n=4: None if a is None else np.round(np.asarray(a, float), n).tolist()  # noqa: E731
    extra = {"method": result.method, "light_model": "near" if result.near else "directional",
             "light_model_reason": result.near_reason, "intensity_method": note,
             "residual_deg": rounded(result.residual_deg), "uncertainty_deg": rounded(result.uncertainty_deg),
             "spheres": result.kinds,
             "sphere_flags": [{int(k): v for k, v in f.items()} for f in result.sphere_flags]}
    if result.triangulated is not None:
        extra["distance"] = rounded(result.distances, 3)
        extra["ray_miss"] = rounded(result.position_error, 3)
    return extra


def _outline_path(outline):
    """Absolute path of the outline photo (a relative one is taken from the current directory)."""
    path = Path(outline).expanduser().absolute()
    if not path.is_file():
        raise InputError(f"{outline}: outline photo not found")
    return path


def _params(circle, sphere_mask, K, outline=None, outline_frames=()):
    circles = None if circle is None else np.atleast_2d(np.asarray(circle, float)).tolist()
    # the mask may live outside the session: its hash goes with the parameters
    mask_hash = None
    if sphere_mask is not None:
        if not Path(sphere_mask).is_file():
            raise InputError(f"{sphere_mask}: sphere mask file not found")
        mask_hash = file_sha256(sphere_mask)
    params = {"circle": circles, "sphere_mask": None if sphere_mask is None else str(sphere_mask),
              "sphere_mask_sha256": mask_hash, "K": None if K is None else np.asarray(K, float).tolist()}
    # so is the outline photo's; these keys only appear when a photo is given or declined, so
    # the records of sessions calibrated without one stay current
    if outline is False:
        params["outline"] = False
    elif outline is not None:
        path = _outline_path(outline)
        params.update(outline=str(path), outline_sha256=file_sha256(path))
    elif outline_frames:
        params["outline_frames"] = [f["id"] for f in outline_frames]   # their files are inputs
    return params


def _session_outlines(session, circle, sphere_mask, outline):
    """The session's outline frames to find the circles on: all of them unless a photo, a
    circle or a mask is given, or ``outline`` is False."""
    if outline is not None or circle is not None or sphere_mask is not None:
        return []
    return session.stage_frames("outline")


def _gamma(session, frame):
    """The display gamma decode undid for ``frame`` (8-bit photos), or None (raw, 16-bit)."""
    decoded = (session.stage("decode") or {}).get("frames") or {}
    return (decoded.get(frame["id"]) or {}).get("gamma")


def _mean_outline(session, frames):
    """Mean of the outline frames (H, W, C) float32, on the scale their files were stored in.

    Decoded frames are linear, but an 8-bit photo is found on its display-encoded values, as
    when the same file is given with ``outline=``: the camera sharpened its edges on that scale
    (measured on PSBox's room-lit JPGs: circles found on the encoded values make the two
    probes' directions agree to 1.14 deg median, found on linear values to 1.55).
    """
    total = None
    for f in frames:
        image = read_image(session.linear_path(f))
        gamma = _gamma(session, f)
        if gamma is not None:
            image = encode_gamma(image, gamma)
        if total is not None and image.shape != total.shape:
            raise StageError(f"{session.linear_path(f)}: size {image.shape} differs from the first outline "
                             f"frame's {total.shape}")
        total = image.astype(np.float32) if total is None else total + image
    return total / len(frames)


def _edge_frames(session, frames, images):
    """Grey (K, H, W) of 8-bit sphere frames on their display-encoded values, else None.

    For the same reason as the outline photo's: through this stage, PSBox probe 1's circle
    found on the encoded light frames gives directions 0.46 deg (median) from the author's, on
    the linear ones 0.64.
    """
    gammas = [_gamma(session, f) for f in frames]
    if any(g is None for g in gammas):
        return None
    return np.stack([encode_gamma(image, g).mean(axis=-1) if image.ndim == 3 else encode_gamma(image, g)
                     for image, g in zip(images, gammas)])


def _read_outline(path, session, shape):
    """The outline photo (H, W, C) float32, checked against the linear frames' size (H, W)."""
    try:
        image = read_image(path)
    except ImageFileError as exc:
        raise InputError(f"outline photo: {exc}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read the outline photo ({exc})") from None
    if image.shape[:2] != tuple(shape):
        binning = ((session.stage("decode") or {}).get("params") or {}).get("binning", 1)
        hint = f" (decoded with binning {binning})" if binning not in (None, 1) else ""
        raise InputError(f"{path}: outline photo is {image.shape[1]}x{image.shape[0]} pixels but the sphere "
                         f"frames are {shape[1]}x{shape[0]}{hint}; it must come from the same camera "
                         "position at the frames' size")
    return image


def _overlays(session, images, result, photo=None):
    """Write the whole-view overlay, one close-up per sphere and, when the circles were found on
    an outline photo, the circles on it; returns their paths."""
    view = images.max(0)
    rels = [OVERLAY]
    write_overlay(session.path(OVERLAY), view, result.circles + result.targets, result.highlights, result.flags)
    if photo is not None:
        rels.append(OVERLAY_OUTLINE)
        write_overlay(session.path(OVERLAY_OUTLINE), photo, result.circles + result.targets, [], {})
    else:  # an earlier run's, on a photo no longer used: the report must not show it
        session.path(OVERLAY_OUTLINE).unlink(missing_ok=True)
    names = [f"calibration/overlay_chrome{s}.png" for s in range(len(result.circles))]
    names += [f"calibration/overlay_matte{s}.png" for s in range(len(result.targets))]
    spots = list(result.highlights) + [None] * len(result.targets)
    write_sphere_overlays([session.path(n) for n in names], view, result.circles + result.targets,
                          spots, result.flags)
    return rels + names


def _session_sphere_mask(session, circle, sphere_mask, outline):
    """The sphere mask stored at import (session-relative), unless the outlines are given
    another way."""
    rel = session.manifest["lights"].get("sphere_mask")
    if rel and circle is None and sphere_mask is None and not outline:
        return rel
    return None


def _file_flags(session):
    """{light: why} flagged in the session's lights.yaml as it is now ({} when absent or unreadable)."""
    try:
        return read_lights_yaml(session.path(LIGHTS)).flags if session.path(LIGHTS).is_file() else {}
    except Exception:  # a file broken by hand is rewritten; its flags cannot be kept
        return {}


def _hand_flags(session, count):
    """Flags added by hand to the lights.yaml the last calibration wrote: those in the file that
    the calibration did not make (its record's ``flagged``) and that name one of ``count``
    lights. Calibrate rewrites the file; these are carried into the new one."""
    record = session.stage("calibrate") or {}
    own = {int(k) for k in (record.get("flagged") or {})}
    return {k: v for k, v in _file_flags(session).items() if k not in own and 0 <= k < count}


def lights_without_spheres(session):
    """The lights of a session that has no sphere frames, and a note saying which they are.

    The rig's nominal directions, recorded at capture (``--no-sphere``), are written as
    ``calibration/lights.yaml`` (positions left out: a rig file's are in its own units, not the
    session frame near lights need); lights imported into it are kept. Both ``psrig calibrate``
    and ``psrig run`` take this one rule. StageError when there are neither.
    """
    recorded = session.manifest["lights"]
    if recorded.get("source") == "nominal" and recorded.get("directions"):
        lights = LightSet(recorded["directions"], source=f"nominal, uncalibrated: {recorded.get('origin', 'rig')}")
        # flags a user wrote into the file stay (the nominal lights carry none of their own)
        lights.flags = {k: v for k, v in _file_flags(session).items() if k < len(lights)}
        write_lights_yaml(session.path(LIGHTS), lights)
        return "no sphere frames: the rig's nominal (uncalibrated) lights are used"
    if session.path(LIGHTS).is_file():
        return f"no sphere frames: the imported {LIGHTS} is kept"
    raise StageError(f"{session.root}: no sphere frames and no {LIGHTS}; capture a chrome sphere, import "
                     f"lights (psrig import images --lights FILE) or take another session's (psrig calibrate "
                     f"SESSION --from CAL)")


def calibrate_session(session, *, circle=None, sphere_mask=None, K=None, outline=None, force=False,
                      from_session=None, echo=print):
    """Calibrate the lights of ``session`` from its sphere frames.

    Parameters
    ----------
    session : pipeline.core.session.Session
    circle : (cx, cy, r), list of them, or None
        Sphere outlines, pixels; found when None.
    sphere_mask : path or None
        PNG mask of the sphere(s): one blob (or label) per sphere.
    K : ndarray (3, 3) or None
        Intrinsics; orthographic when None.
    outline : path, None or False
        An evenly (room-)lit photo of the spheres from the same camera position, at the linear
        frames' size (any format psrig reads), on which the circles are found; relative paths
        are taken from the current directory. Its path and sha256 go into the stage
        parameters, so a changed photo reruns the stage. None (default): the session's own
        ``outline`` frames when it has any (their mean; not with ``circle`` or
        ``sphere_mask``), else the light frames. False: the light frames even when the session
        has outline frames.
    force : bool
        Recompute even when the stage record is current.
    from_session : path or None
        Another session whose calibration (its ``calibration/lights.yaml``) to use instead of
        this session's sphere frames: one sphere session for many object sessions. Its path and
        the sha256 of its lights.yaml are recorded, so a recalibrated source reruns this stage.
    echo : callable
        Where messages go.

    A sphere mask stored at import (``calibration/sphere_mask.png``) is used when no circle,
    mask or outline photo is given; it is then one of the stage's inputs.

    Returns
    -------
    SphereCalibration, or None when skipped (up to date, or no sphere frames: then
    :func:`lights_without_spheres`).
    """
    if from_session is not None:
        if circle is not None or sphere_mask is not None or outline:
            raise InputError("--from: the lights come from the other session; give no circle, mask or outline")
        return reuse_calibration(session, from_session, force=force, echo=echo)
    # one frame per light and kind: an exposure bracket is its merged frame
    frames = sorted(session.stage_frames("sphere"), key=lambda f: f["light"])
    if not frames:
        echo(f"{session.root}: {lights_without_spheres(session)}")
        return None
    stored_mask = _session_sphere_mask(session, circle, sphere_mask, outline)
    outlines = _session_outlines(session, circle, sphere_mask or stored_mask, outline)
    if outline is False and not session.frames("outline"):
        outline = None   # nothing to decline: the record stays that of a plain calibration
    params = _params(circle, sphere_mask, K, outline, outlines)
    needed = frames + outlines
    missing = [session.linear_path(f) for f in needed if not session.linear_path(f).is_file()]
    if missing:
        raise StageError(f"{missing[0]}: missing ({len(missing)} of {len(needed)} sphere and outline frames not "
                         "decoded); run `psrig decode` first")
    rels = [session.rel(session.linear_path(f)) for f in needed]
    rels += [session.rel(session.saturation_path(f)) for f in frames if session.saturation_path(f).is_file()]
    if stored_mask:
        rels.append(stored_mask)
    # which light each frame was shot under, and the object frames' names in lights.lp
    inputs = {**session.hash_inputs(rels), **session.manifest_input(
        "calibrate", needed + session.stage_frames("object"), ("id", "kind", "light", "file", "source"))}
    if not force and session.stage_is_current("calibrate", params, inputs):
        echo(f"{session.root}: calibrate is up to date")
        note = exclusion_note(session)
        if note:
            echo(note)
        return None
    start = time.perf_counter()
    images, sats = _load(session, frames)
    mask = read_mask(sphere_mask if stored_mask is None else session.path(stored_mask)) \
        if sphere_mask is not None or stored_mask else None
    if outlines:
        photo = _mean_outline(session, outlines)
    elif outline:
        photo = _read_outline(params["outline"], session, images.shape[1:3])
    else:
        photo = None
    result = calibrate_sphere(images, circle, mask, saturation=sats, K=K, outline=photo,
                              edge_frames=_edge_frames(session, frames, images))
    intensities, note = _intensities(result, images, sats, K)
    order = [f["light"] for f in frames]
    flags = {order[k]: f"frame {frames[k]['id']}: {why}" for k, why in sorted(result.flags.items())}
    if len(flags) == len(frames):
        reasons = sorted({why for why in result.flags.values()})
        raise StageError(f"{session.root}: none of the {len(frames)} lights could be calibrated on the sphere at "
                         f"({result.circle.cx:.1f}, {result.circle.cy:.1f}) r {result.circle.r:.1f} "
                         f"({'; '.join(reasons[:3])}); check the circle or mask, or the sphere frames")
    directions = np.where(np.isfinite(result.directions), result.directions, [0.0, 0.0, 1.0])
    by_hand = _hand_flags(session, len(directions))
    lights = LightSet(directions, intensities, positions=_positions(result), flags={**by_hand, **flags},
                      source=f"chrome sphere calibration ({result.method}); {note}",
                      extra=_extra(result, note))
    if result.triangulated is not None:
        # the unit of positions, distance and ray_miss (calibration.sphere.SphereCalibration)
        lights.extra["position_unit"] = "px" if K is None else "sphere radii"
    write_lights_yaml(session.path(LIGHTS), lights)
    objects = {f["light"]: f for f in session.stage_frames("object")}
    names = [objects[i].get("source", objects[i]["file"].split("/")[-1]) if i in objects else frames[k]["id"]
             for k, i in enumerate(order)]
    write_lp(session.path(LIGHTS_LP), names, directions)
    outputs = [LIGHTS, LIGHTS_LP] + _overlays(session, images, result, photo)
    session.record_stage("calibrate", params, inputs, outputs, seconds=time.perf_counter() - start,
                         flagged=flags, light_model=lights.extra["light_model"],
                         **({"flags_by_hand": by_hand} if by_hand else {}))
    if flags:
        echo(f"{len(flags)} flagged light(s): " + "; ".join(f"light {k}: {why}" for k, why in flags.items()))
    if not result.targets:
        echo("no matte target in the sphere frames: intensities all 1 (the lights are taken as equally bright; "
             "a matte white sphere beside the chrome one measures them)")
    if by_hand:
        echo(f"{LIGHTS}: kept {len(by_hand)} flag(s) added by hand (" + "; ".join(
            f"light {k}: {why}" for k, why in by_hand.items()) + f"); calibrate rewrites that file: put them in "
             f"{EXCLUDE}, which no stage writes")
    note = exclusion_note(session)
    if note:
        echo(note)
    return result


class CalibrateStage(Stage):
    """The ``calibrate`` stage (:class:`pipeline.core.stage.Stage`): :func:`calibrate_session`, another
    session's calibration (``from_session``), or :func:`lights_without_spheres`."""

    name = "calibrate"
    Options = CalibrateOptions
    reads = ("linear/ sphere and outline frames", "a sphere mask (given or stored at import)",
             "another session's calibration/lights.yaml (from_session)")

    def work(self, session, options, *, force, jobs):
        # lights left out by hand (calibration/exclude.yaml) are said on every run, ran or not
        by_hand = exclusion_note(session)
        if options.get("from_session"):   # one sphere session's calibration for this one
            ran = calibrate_session(session, force=force, echo=lambda line: None, **options) is not None
            return ran, "; ".join(filter(None, [f"lights from {options['from_session']}", by_hand]))
        if not session.frames("sphere"):
            before = session.stage(self.name)
            note = lights_without_spheres(session)
            return session.stage(self.name) is not before, "; ".join(filter(None, [note, by_hand]))
        # what the calibration says (flagged lights) becomes the stage's note; its own "is up to
        # date" line would repeat the runner's
        said = []
        ran = calibrate_session(session, force=force, echo=said.append, **options) is not None
        return ran, "; ".join(said) if ran else by_hand

    def replay(self, record):
        params = (record or {}).get("params")
        if not params:
            return {}
        # hashes are recorded beside the files they check; the stage recomputes them (and
        # outline_frames names the session's outline frames, which the stage finds itself)
        kwargs = {k: v for k, v in params.items()
                  if not k.endswith("_sha256") and k != "outline_frames" and v is not None}
        if "K" in kwargs:
            kwargs["K"] = np.asarray(kwargs["K"], float)
        return kwargs


#: the stage object the runner and the scheduler run
CALIBRATE = CalibrateStage()
