"""Importers: existing photometric-stereo data -> a session folder.

Two sources are understood:

- a DiLiGenT object folder (:func:`import_diligent`): images become object frames, the
  published light directions and intensities become ``calibration/lights.yaml`` (+ ``.lp``), the
  object mask becomes ``calibration/object_mask.png`` and the ground-truth normals go to
  ``truth/``;
- loose image files (:func:`import_images`): object (and sphere) frames from glob patterns,
  optionally a light file and an object mask.

Everything is checked before the session folder is created, so a bad import leaves nothing
behind. Source files are only read. Imported lights are recorded in the manifest under
``lights:`` (``source: imported``), which tells the calibrate stage there is nothing to do when
the session has no sphere frames.
"""

import glob
import re
from pathlib import Path

import numpy as np

from .errors import InputError, SessionError
from .imageio import image_size, read_mask, write_image, write_mask, write_normal_png
from .lightsio import LightSet, read_lights, write_lights_yaml, write_lp
from .progress import progress
from .session import Session

__all__ = ["import_diligent", "import_images", "expand_glob", "natural_key", "check_sizes",
           "LIGHTS", "LIGHTS_LP", "OBJECT_MASK"]

LIGHTS = "calibration/lights.yaml"
LIGHTS_LP = "calibration/lights.lp"
OBJECT_MASK = "calibration/object_mask.png"


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


def check_sizes(files, size=None, reference=None, hint=""):
    """Common (height, width) of image files; InputError naming the first odd file.

    ``size`` is the size already established by ``reference`` (a file of another group, e.g.
    the first object frame when checking sphere frames); by default the first of ``files``.
    ``hint`` ends the error message.
    """
    reference = files[0] if reference is None else reference
    for path in files:
        height, width, _ = image_size(path)
        if size is None:
            size = (height, width)
        elif (height, width) != tuple(size):
            raise InputError(f"{path}: image is {width}x{height} but {reference} is "
                             f"{size[1]}x{size[0]}; all frames must have the same size{hint}")
    return tuple(size)


def _check_target(dest):
    dest = Path(dest)
    if dest.exists() and (not dest.is_dir() or any(dest.iterdir())):
        raise SessionError(f"{dest}: exists and is not an empty folder; refusing to import into it")
    return dest


def _write_lights(session, lights, frames):
    """lights.yaml + lights.lp for the object frames; manifest ``lights`` says they are imported."""
    write_lights_yaml(session.path(LIGHTS), lights)
    write_lp(session.path(LIGHTS_LP), [Path(f["file"]).name for f in frames], lights.directions)
    session.manifest["lights"].update({"source": "imported", "file": LIGHTS, "lp": LIGHTS_LP,
                                       "count": len(lights), "origin": lights.source})


def _add_frames(session, kind, files):
    frames = []
    for index, path in enumerate(progress(files, desc=f"import {kind}", unit="frame")):
        frames.append(session.add_frame(kind, source=path, light=index, save=False))
    return frames


def import_diligent(src, dest):
    """Import a DiLiGenT object folder into a new session.

    Parameters
    ----------
    src : path
        A DiLiGenT object folder (``filenames.txt``, ``light_directions.txt``,
        ``light_intensities.txt``, ``mask.png``, optionally ``Normal_gt.mat``).
    dest : path
        Session folder to create (absent or empty).

    Returns
    -------
    Session
        With K object frames (16-bit PNG, light = row of the light files), lights (K, 3)
        directions and (K, 3) per-channel intensities, ``calibration/object_mask.png`` and,
        when the folder has it, ground truth ``normals`` / ``mask`` / ``lights`` in ``truth/``.
    """
    from .diligent import read_diligent

    obj = read_diligent(src)
    dest = _check_target(dest)
    size = check_sizes(obj.files)
    if obj.mask.shape != size:
        raise InputError(f"{Path(src) / 'mask.png'}: mask is {obj.mask.shape[1]}x{obj.mask.shape[0]} "
                         f"but the images are {size[1]}x{size[0]}")
    if obj.normals_gt is not None and obj.normals_gt.shape[:2] != size:
        raise InputError(f"{Path(src) / 'Normal_gt.mat'}: normals are {obj.normals_gt.shape[1]}x"
                         f"{obj.normals_gt.shape[0]} but the images are {size[1]}x{size[0]}")
    source = "DiLiGenT light_directions.txt / light_intensities.txt"
    lights = LightSet(obj.directions, obj.intensities, source=source)
    session = Session.create(dest, rig={"name": "imported", "source": f"DiLiGenT {obj.name}"})
    frames = _add_frames(session, "object", obj.files)
    _write_lights(session, lights, frames)
    _write_object_mask(session, obj.mask)
    write_lights_yaml(session.path("truth/lights.yaml"), lights)
    session.set_truth("lights", "truth/lights.yaml", save=False)
    if obj.normals_gt is not None:
        _write_truth_normals(session, obj.normals_gt, obj.mask)
    session.save()
    return session


def _write_object_mask(session, mask):
    write_mask(session.path(OBJECT_MASK), mask)
    session.manifest["lights"]["object_mask"] = OBJECT_MASK


def _write_truth_normals(session, normals, mask):
    """truth/normals.exr (0 outside the mask), normals.png and mask.png, recorded as truth."""
    normals = np.where(mask[..., None], normals, 0.0).astype(np.float32)
    write_image(session.path("truth/normals.exr"), normals)
    write_normal_png(session.path("truth/normals.png"), normals, mask)
    write_mask(session.path("truth/mask.png"), mask)
    session.set_truth("normals", "truth/normals.exr", save=False)
    session.set_truth("mask", "truth/mask.png", save=False)


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
    dest = _check_target(dest)
    session = Session.create(dest, rig={"name": "imported", "source": "image files"})
    frames = _add_frames(session, "object", objects)
    _add_frames(session, "sphere", spheres)
    for path in outlines:
        session.add_frame("outline", source=path, save=False)
    if light_set is not None:
        _write_lights(session, light_set, frames)
    if object_mask is not None:
        _write_object_mask(session, object_mask)
    session.save()
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
