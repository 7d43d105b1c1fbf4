"""Loose image files -> a session: object (and sphere, outline) frames from glob patterns,
optionally a light file and an object mask (:func:`import_images`).
"""

import glob
import re
from pathlib import Path

from ..errors import InputError
from ..imageio import read_mask
from ..lightsio import read_lights
from ..session import Session
from .write import add_frames, check_sizes, check_target, write_lights, write_object_mask

__all__ = ["import_images", "expand_glob", "natural_key", "SPHERE_CROP_HINT"]


def natural_key(path):
    """Sort key that orders embedded numbers by value (img2 before img10)."""
    parts = re.split(r"(\d+)", str(path))
    return [(0, int(p), "") if p.isdigit() else (1, 0, p.lower()) for p in parts]


def expand_glob(pattern, what="--object"):
    """Files matching a glob pattern, naturally sorted; InputError naming the pattern if none."""
    files = sorted((Path(p) for p in glob.glob(str(pattern)) if Path(p).is_file()), key=natural_key)
    if not files:
        raise InputError(f"{what} {pattern!r}: no files match this pattern")
    return files


#: what to do with sphere photos cropped apart from the object's (PSBox ships them so)
SPHERE_CROP_HINT = ("; sphere photos cropped apart from the object's can be calibrated in a session of their "
                    "own (psrig import images CAL --object SPHERES --sphere SPHERES, then psrig decode CAL "
                    "and psrig calibrate CAL) and the light directions given to this one with "
                    "--lights CAL/calibration/lights.lp (directions only: positions found on another "
                    "crop would sit in its pixels, not these)")


def import_images(dest, object_glob, *, sphere_glob=None, mask=None, lights=None, outline=None):
    """Import loose image files into a new session.

    Parameters
    ----------
    dest : path
        Session folder to create (absent or empty).
    object_glob : str
        Glob of the object frames; naturally sorted, frame i is lit by light i.
    sphere_glob : str, optional
        Glob of chrome-sphere frames, same light order and count as the object frames.
    mask : path, optional
        Object mask image (white = object), same size as the frames.
    lights : path, optional
        Light directions: ``.yaml``, RTI ``.lp`` or text (``x y z`` per line, optional count
        line); K rows for K object frames.
    outline : str, optional
        Glob of evenly (room-)lit photos of the sphere(s), rig lights off, same camera position
        and size as the frames: stored as ``outline`` frames, on which calibration finds the
        sphere circles (their mean when several).

    Returns
    -------
    Session
    """
    objects = expand_glob(object_glob, "--object")
    size = check_sizes(objects)
    spheres = []
    if sphere_glob:
        spheres = expand_glob(sphere_glob, "--sphere")
        check_sizes(spheres, size, reference=objects[0], hint=SPHERE_CROP_HINT)
        if len(spheres) != len(objects):
            raise InputError(f"--sphere {sphere_glob!r}: {len(spheres)} sphere frames for "
                             f"{len(objects)} object frames; one per light is needed")
    outlines = []
    if outline:
        if not sphere_glob:
            raise InputError(f"--outline {outline!r}: an outline photo is for sphere frames; give --sphere too")
        outlines = expand_glob(outline, "--outline")
        check_sizes(outlines, size, reference=objects[0])
    light_set = _read_light_file(lights, len(objects)) if lights else None
    object_mask = _read_mask_file(mask, size) if mask else None
    dest = check_target(dest)
    session = Session.create(dest, rig={"name": "imported", "source": "image files"}, writer="import")
    frames = add_frames(session, "object", objects)
    add_frames(session, "sphere", spheres)
    for path in outlines:
        session.add_frame("outline", source=path, save=False)
    if light_set is not None:
        write_lights(session, light_set, frames)
    if object_mask is not None:
        write_object_mask(session, object_mask)
    session.save()
    session.release()  # imported: the caller reads it, or opens it to write
    return session


def _read_light_file(path, count):
    lights = read_lights(path)
    if len(lights) != count:
        raise InputError(f"{path}: {len(lights)} lights but {count} object frames; "
                         "one light per frame is needed")
    return lights


def _read_mask_file(path, size):
    if not Path(path).is_file():
        raise InputError(f"{path}: mask file not found")
    mask = read_mask(path)
    if mask.shape != size:
        raise InputError(f"{path}: mask is {mask.shape[1]}x{mask.shape[0]} but the frames are "
                         f"{size[1]}x{size[0]}")
    if not mask.any():
        raise InputError(f"{path}: the mask is empty (no white pixel)")
    return mask
