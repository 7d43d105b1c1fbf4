"""What every importer writes into the new session: the folder check, frames, lights, masks, truth.

Everything an importer reads is checked before :func:`check_target` lets it create the session
folder, so a bad import leaves nothing behind. Source files are only read. Imported lights are
recorded in the manifest under ``lights:`` (``source: imported``), which tells the calibrate
stage there is nothing to do when the session has no sphere frames.
"""

from pathlib import Path

import numpy as np

from ..core.errors import InputError, SessionError
from ..decode import frame_size
from ..core.imageio import write_image, write_mask, write_normal_png
from ..core.lightsio import write_lights_yaml, write_lp
from ..core.paths import LIGHTS, LIGHTS_LP, OBJECT_MASK, TRUTH_LIGHTS, TRUTH_MASK, TRUTH_NORMALS, TRUTH_NORMALS_PNG
from ..core.progress import progress

__all__ = ["check_target", "check_sizes", "add_frames", "write_lights", "write_truth_lights", "write_object_mask",
           "write_mask_file", "write_truth_normals"]


def check_sizes(files, size=None, reference=None, hint=""):
    """Common (height, width) of frame files as decoded; InputError naming the first odd file.

    ``size`` is the size already established by ``reference`` (a file of another group, e.g.
    the first object frame when checking sphere frames); by default the first of ``files``.
    ``hint`` ends the error message.
    """
    reference = files[0] if reference is None else reference
    for path in files:
        height, width = frame_size(path)   # as decode will make it: images and camera raws alike
        if size is None:
            size = (height, width)
        elif (height, width) != tuple(size):
            raise InputError(f"{path}: image is {width}x{height} but {reference} is "
                             f"{size[1]}x{size[0]}; all frames must have the same size{hint}")
    return tuple(size)


def check_target(dest):
    """``dest`` as a Path, refused unless it is absent or an empty folder."""
    dest = Path(dest)
    if dest.exists() and (not dest.is_dir() or any(dest.iterdir())):
        raise SessionError(f"{dest}: exists and is not an empty folder; refusing to import into it")
    return dest


def add_frames(session, kind, files):
    """Add ``files`` as frames of ``kind``, frame i lit by light i (not saved)."""
    frames = []
    for index, path in enumerate(progress(files, desc=f"import {kind}", unit="frame")):
        frames.append(session.add_frame(kind, source=path, light=index, save=False))
    return frames


def write_lights(session, lights, frames):
    """lights.yaml + lights.lp for the object frames; manifest ``lights`` says they are imported."""
    write_lights_yaml(session.path(LIGHTS), lights)
    write_lp(session.path(LIGHTS_LP), [Path(f["file"]).name for f in frames], lights.directions)
    session.manifest["lights"].update({"source": "imported", "file": LIGHTS, "lp": LIGHTS_LP,
                                       "count": len(lights), "origin": lights.source})


def write_truth_lights(session, lights):
    """The true lights of the session (``truth/lights.yaml``), recorded as truth (not saved)."""
    write_lights_yaml(session.path(TRUTH_LIGHTS), lights)
    session.set_truth("lights", TRUTH_LIGHTS, save=False)


def write_object_mask(session, mask):
    """The object mask (``calibration/object_mask.png``), named in the manifest (not saved)."""
    write_mask_file(session, OBJECT_MASK, mask, "object_mask")


def write_mask_file(session, rel, mask, key):
    """A mask written at ``rel`` and named in the manifest's ``lights:`` under ``key`` (not saved)."""
    write_mask(session.path(rel), mask)
    session.manifest["lights"][key] = rel


def write_truth_normals(session, normals, mask):
    """truth/normals.exr (0 outside the mask), normals.png and mask.png, recorded as truth."""
    normals = np.where(mask[..., None], normals, 0.0).astype(np.float32)
    write_image(session.path(TRUTH_NORMALS), normals)
    write_normal_png(session.path(TRUTH_NORMALS_PNG), normals, mask)
    write_mask(session.path(TRUTH_MASK), mask)
    session.set_truth("normals", TRUTH_NORMALS, save=False)
    session.set_truth("mask", TRUTH_MASK, save=False)
