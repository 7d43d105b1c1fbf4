"""Loose image files -> a session: object (and sphere, outline) frames from glob patterns,
optionally a light file, intensities, an object mask and a sphere mask (:func:`import_images`).

Every file is checked before the session folder is made: it must decode (by content: any image
OpenImageIO reads, any camera raw LibRaw reads), all frames must have one size, and the lights
must match the frames (by file name for an .lp file, by order otherwise). What was matched,
skipped and assumed is recorded in the manifest (``rig: import:``) and returned for printing.
"""

import glob
import re
from pathlib import Path

from ..decode import frame_format, readable_formats
from ..decode.formats import FrameTooLarge, png_problem
from ..core.errors import InputError, PsrigError
from ..core.imageio import read_mask
from ..core.lightsio import flag_behind, lp_name, read_intensities, read_lights
from ..core.paths import SPHERE_MASK
from ..core.session import Session
from .write import add_frames, check_sizes, check_target, write_lights, write_mask_file, write_object_mask

__all__ = ["import_images", "expand_glob", "natural_key", "SPHERE_CROP_HINT", "SKIPPED_WORDS", "import_notes"]

#: words that mark a file as something other than a frame (a mask, a normal or albedo map, ...)
#: when they stand alone in its name (NAME.mask.tga, cat_normal.png, albedo-01.png)
SKIPPED_WORDS = ("mask", "masks", "albedo", "normal", "normals", "normalmap", "depth")
_WORDS = re.compile(r"[A-Za-z]+")


def natural_key(path):
    """Sort key that orders embedded numbers by value (img2 before img10)."""
    parts = re.split(r"(\d+)", str(path))
    return [(0, int(p), "") if p.isdigit() else (1, 0, p.lower()) for p in parts]


def _skipped(path):
    """True for a file named like a mask or a map rather than a frame."""
    return any(word.lower() in SKIPPED_WORDS for word in _WORDS.findall(Path(path).stem))


def expand_glob(pattern, what="--object", *, keep_all=False, exclude=()):
    """Files matching a glob pattern, naturally sorted, and the ones left out.

    Parameters
    ----------
    pattern : str, or list of str
        A list is taken in its order: each pattern expanded and sorted naturally, each plain
        file name as given (not skipped for its name); a file named twice is refused.
    what : str
        The option named in errors.
    keep_all : bool
        Keep files named like masks or maps (see :data:`SKIPPED_WORDS`).
    exclude : iterable of path
        Files never taken as frames (the mask files given).

    Returns
    -------
    files : list of Path
    skipped : list of Path
    """
    if not isinstance(pattern, (str, Path)):
        return _expand_list(pattern, what, keep_all, exclude)
    matched = sorted((Path(p) for p in glob.glob(str(pattern)) if Path(p).is_file()), key=natural_key)
    if not matched:
        raise InputError(f"{what} {pattern!r}: no files match this pattern")
    excluded = {Path(p).resolve() for p in exclude if p}
    skipped = [p for p in matched if p.resolve() in excluded or (not keep_all and _skipped(p))]
    files = [p for p in matched if p not in skipped]
    if not files:
        raise InputError(f"{what} {pattern!r}: every file it matches is named like a mask or a map "
                         f"({', '.join(p.name for p in skipped[:4])}); give --keep-all to use them as frames")
    return files, skipped


def _expand_list(patterns, what, keep_all, exclude):
    """:func:`expand_glob` of several patterns and file names, in the order given."""
    files, skipped = [], []
    for one in patterns:
        if any(char in str(one) for char in "*?["):
            found, left = expand_glob(one, what, keep_all=keep_all, exclude=exclude)
            files += found
            skipped += left
        elif Path(one).is_file():
            files.append(Path(one))
        else:
            raise InputError(f"{what} {one}: no such file")
    seen = {}
    for path in files:
        if path.resolve() in seen:
            raise InputError(f"{what}: {path} is given twice (as {seen[path.resolve()]} too); each frame once")
        seen[path.resolve()] = path
    return files, skipped


def _shown(pattern):
    """A pattern, or a list of them, as the notes show it."""
    if isinstance(pattern, (str, Path)):
        return repr(str(pattern))
    return " ".join(map(str, pattern[:3])) + (f" ... ({len(pattern)} given)" if len(pattern) > 3 else "")


#: what to do with sphere photos cropped apart from the object's (PSBox ships them so)
SPHERE_CROP_HINT = ("; sphere photos cropped apart from the object's can be calibrated in a session of their "
                    "own (psrig import images CAL --object SPHERES --sphere SPHERES, then psrig decode CAL "
                    "and psrig calibrate CAL) and the light directions given to this one with "
                    "psrig calibrate SESSION --from CAL (directions only: positions found on another "
                    "crop would sit in its pixels, not these)")


def _check_decodable(files):
    """InputError naming every file that neither OpenImageIO nor LibRaw reads."""
    bad = []
    for path in files:
        try:
            found = frame_format(path)
        except FrameTooLarge:
            raise   # it is decodable, but not here: said apart
        except PsrigError:
            bad.append(path)
            continue
        if found.name == "png" and (problem := png_problem(path)) is not None:
            raise InputError(f"{path}: the PNG file is {problem}; copy it again from its source")
    if bad:
        names = ", ".join(str(p) for p in bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        raise InputError(f"{len(bad)} file(s) cannot be decoded: {names}; {readable_formats()}")


def _colour(found):
    """'grey' or 'colour' of a frame's FrameFormat (camera raws are colour)."""
    return "colour" if found.kind == "raw" or (found.channels or 3) >= 3 else "grey"


def _mixed_colour(files):
    """What is wrong when grey and colour frames are mixed (decode would make the grey ones
    white colour frames, and the albedo's colour would differ by frame), or ''."""
    kinds = {}
    for path in files:
        kinds.setdefault(_colour(frame_format(path)), path)
    if len(kinds) < 2:
        return ""
    return (f"{kinds['grey']} is a grey image but {kinds['colour']} is in colour; the frames of a group "
            "must all be grey or all colour")


def _unexpected(files, others):
    """Files of ``files`` whose number (the last in the name) none of ``others`` carries; the
    last ones beyond the count when names carry no numbers."""
    def number(path):
        found = re.findall(r"\d+", Path(path).stem)
        return int(found[-1]) if found else None
    theirs = {number(p) for p in others}
    if None in theirs or any(number(p) is None for p in files):
        return files[len(others):]
    return [p for p in files if number(p) not in theirs]


def _count_error(what, pattern, files, objects):
    extra, missing = _unexpected(files, objects), _unexpected(objects, files)
    parts = []
    if extra:
        parts.append(f"unexpected: {', '.join(p.name for p in extra[:8])}" + (" ..." if len(extra) > 8 else ""))
    if missing:
        parts.append(f"object frames without one: {', '.join(p.name for p in missing[:8])}"
                     + (" ..." if len(missing) > 8 else ""))
    return InputError(f"{what} {pattern!r}: {len(files)} frames for {len(objects)} object frames; one per light "
                      f"is needed ({'; '.join(parts) or 'the numbers in the names do not tell which'})")


def _matched(kind, pattern, files, skipped):
    line = f"{kind}: {len(files)} file(s) match {_shown(pattern)}: {files[0].name}"
    line += f" ... {files[-1].name}" if len(files) > 1 else ""
    if skipped:
        line += (f"; skipped {len(skipped)} named like masks or maps ({', '.join(p.name for p in skipped[:4])}"
                 f"{' ...' if len(skipped) > 4 else ''}; --keep-all keeps them)")
    return line


def import_images(dest, object_glob, *, sphere_glob=None, mask=None, lights=None, outline=None,
                  intensities=None, sphere_mask=None, keep_all=False):
    """Import loose image files into a new session.

    Parameters
    ----------
    dest : path
        Session folder to create (absent or empty).
    object_glob : str
        Glob of the object frames; naturally sorted. Files named like masks or maps
        (:data:`SKIPPED_WORDS`) are left out unless ``keep_all``.
    sphere_glob : str, optional
        Glob of chrome-sphere frames, same light order and count as the object frames.
    mask : path, optional
        Object mask image (white = object), same size as the frames.
    lights : path, optional
        Any light file :func:`pipeline.core.lightsio.read_lights` reads (``FILE:NAME`` for an array
        of a .mat, .npz or OpenCV file). An .lp file pairs its lines with the object frames by
        file name; other files give light i to the i-th object frame.
    outline : str, optional
        Glob of evenly (room-)lit photos of the sphere(s), rig lights off, same camera position
        and size as the frames: stored as ``outline`` frames, on which calibration finds the
        sphere circles (their mean when several).
    intensities : path, optional
        Per-light intensities (K rows of 1 or 3 values), for lights given without them.
    sphere_mask : path, optional
        Mask of the sphere(s) in the sphere frames (one blob per sphere), stored in the session;
        the calibrate stage uses it instead of finding the spheres.
    keep_all : bool
        Keep files named like masks or maps.

    Returns
    -------
    Session
        Its manifest's ``rig: import:`` records the patterns, what they matched and skipped,
        and notes on what was assumed (:func:`import_notes`).
    """
    given_masks = [mask, sphere_mask]
    objects, skipped = expand_glob(object_glob, "--object", keep_all=keep_all, exclude=given_masks)
    notes = [_matched("object", object_glob, objects, skipped)]
    groups = {"object": {"pattern": object_glob, "files": objects, "skipped": skipped}}
    spheres, outlines = [], []
    if sphere_glob:
        spheres, skipped = expand_glob(sphere_glob, "--sphere", keep_all=keep_all, exclude=given_masks)
        notes.append(_matched("sphere", sphere_glob, spheres, skipped))
        groups["sphere"] = {"pattern": sphere_glob, "files": spheres, "skipped": skipped}
    if outline:
        if not sphere_glob:
            raise InputError(f"--outline {outline!r}: an outline photo is for sphere frames; give --sphere too")
        outlines, skipped = expand_glob(outline, "--outline", keep_all=True)
        groups["outline"] = {"pattern": outline, "files": outlines, "skipped": skipped}
    _check_decodable(objects + spheres + outlines)
    for files in (objects, spheres):
        mixed = _mixed_colour(files)
        if mixed and not keep_all:
            raise InputError(f"{mixed} (convert them)")
        if mixed:   # --keep-all: the files were asked for as they are; said, and recorded
            notes.append(f"warning: {mixed}")
    size = check_sizes(objects)
    if spheres:
        check_sizes(spheres, size, reference=objects[0], hint=SPHERE_CROP_HINT)
        if len(spheres) != len(objects):
            raise _count_error("--sphere", sphere_glob, spheres, objects)
    if outlines:
        check_sizes(outlines, size, reference=objects[0])
    light_set = _light_file(lights, objects, intensities, notes) if lights else None
    if intensities and not lights:
        raise InputError(f"--intensities {intensities}: give the light directions too (--lights FILE)")
    object_mask = _read_mask_file(mask, size, "mask") if mask else None
    spheres_mask = _read_mask_file(sphere_mask, size, "sphere mask") if sphere_mask else None
    dest = check_target(dest)
    session = Session.create(dest, rig={"name": "imported", "source": "image files",
                                        "import": _record(groups, notes)}, writer="import")
    frames = add_frames(session, "object", objects)
    add_frames(session, "sphere", spheres)
    for path in outlines:
        session.add_frame("outline", source=path, save=False)
    if light_set is not None:
        write_lights(session, light_set, frames)
    if object_mask is not None:
        write_object_mask(session, object_mask)
    if spheres_mask is not None:
        write_mask_file(session, SPHERE_MASK, spheres_mask, "sphere_mask")
    session.save()
    session.release()  # imported: the caller reads it, or opens it to write
    return session


def import_notes(session):
    """The lines an import recorded: what it matched, skipped and assumed."""
    return list(((session.manifest.get("rig") or {}).get("import") or {}).get("notes") or [])


def _record(groups, notes):
    return {"groups": {kind: {"pattern": g["pattern"], "count": len(g["files"]), "first": g["files"][0].name,
                              "last": g["files"][-1].name, "skipped": [p.name for p in g["skipped"]]}
                       for kind, g in groups.items()},
            "notes": list(notes)}


def _by_name(path, lights, objects):
    """``lights`` reordered to the object frames by the .lp file's names; InputError naming
    the lines that match no frame and the frames without a line."""
    index = {}
    for k, name in enumerate(lights.filenames):
        index.setdefault(lp_name(name), k)
    folded = {}
    for name, k in index.items():
        folded.setdefault(name.lower(), k)
    order = [index.get(p.name, folded.get(p.name.lower())) for p in objects]
    unmatched = sorted(set(range(len(lights))) - {k for k in order if k is not None})
    missing = [p.name for p, k in zip(objects, order) if k is None]
    if missing or unmatched:
        names = [lights.filenames[k] for k in unmatched]
        raise InputError(f"{path}: its names and the object frames do not pair up: "
                         + "; ".join(filter(None, [
                             f"lines naming no object frame: {', '.join(names[:6])}" + (" ..." if len(names) > 6 else "")
                             if names else "",
                             f"object frames without a line: {', '.join(missing[:6])}" + (" ..." if len(missing) > 6 else "")
                             if missing else ""])))
    lights.directions = lights.directions[order]
    lights.intensities = lights.intensities[order]
    lights.filenames = [lights.filenames[k] for k in order]
    return order != list(range(len(order)))


def _light_file(path, objects, intensities, notes):
    lights = read_lights(path, count=len(objects))
    if len(lights) != len(objects):
        raise InputError(f"{path}: {len(lights)} lights but {len(objects)} object frames "
                         f"({objects[0].name} ... {objects[-1].name}); one light per frame is needed")
    if lights.filenames:
        reordered = _by_name(path, lights, objects)
        notes.append(f"lights: paired with the frames by the names in {Path(path).name}"
                     + (" (in another order than the frames')" if reordered else ""))
    if intensities:
        if (lights.intensities != 1).any():
            raise InputError(f"--intensities {intensities}: {path} gives intensities already; give them once")
        lights.intensities = read_intensities(intensities, len(lights))
        lights.source += f"; intensities from {Path(str(intensities)).name}"
        notes.append(f"intensities: {lights.intensities.shape[1]} per light from {Path(str(intensities)).name}")
    elif (lights.intensities == 1).all():
        notes.append("intensities: none given, all 1 (give --intensities FILE if the lights differ in "
                     "brightness)")
    else:
        notes.append(f"intensities: {lights.intensities.shape[1]} per light from {Path(str(path)).name}")
    behind = flag_behind(lights, str(path))
    if behind:
        notes.append(f"lights: {len(behind)} with z <= 0 (behind the surface) flagged in lights.yaml and left "
                     f"out of the normals: {', '.join(str(k) for k in behind[:10])}")
    return lights


def _read_mask_file(path, size, what):
    if not Path(path).is_file():
        raise InputError(f"{path}: {what} file not found")
    mask = read_mask(path)
    if mask.shape != size:
        raise InputError(f"{path}: {what} is {mask.shape[1]}x{mask.shape[0]} but the frames are "
                         f"{size[1]}x{size[0]}")
    if not mask.any():
        raise InputError(f"{path}: the {what} is empty (no white pixel)")
    return mask
