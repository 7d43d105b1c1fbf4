"""DiLiGenT object folders (Shi et al., CVPR 2016): reading one, and importing it as a session.

A folder holds 16-bit RGB PNGs listed in ``filenames.txt``, ``light_directions.txt`` (K x 3,
camera frame x right, y up, z toward the camera), ``light_intensities.txt`` (K x 3; divide each
channel by it), ``mask.png`` and optionally ``Normal_gt.mat`` (variable ``Normal_gt``, H x W x 3).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.imageio import read_mask
from ..core.lightsio import LightSet
from ..core.session import Session
from .write import add_frames, check_sizes, check_target, write_lights, write_object_mask, write_truth_lights, \
    write_truth_normals

__all__ = ["DiligentObject", "read_diligent", "read_normal_gt_mat", "import_diligent"]


@dataclass
class DiligentObject:
    """One DiLiGenT object.

    Attributes
    ----------
    files : list of Path
        Image files, in light order (K).
    directions : ndarray (K, 3)
    intensities : ndarray (K, 3)
    mask : ndarray (H, W) bool
    normals_gt : ndarray (H, W, 3) or None
    """

    name: str
    files: list
    directions: np.ndarray
    intensities: np.ndarray
    mask: np.ndarray
    normals_gt: np.ndarray = None

    def load_images(self, grey=True):
        """The frames as the command line's decode reads them, intensities divided out.

        Each file is decoded by :func:`pipeline.decode.image.decode_image` with the transfer
        function chosen as ``psrig decode`` chooses it (16-bit PNG without colour metadata:
        linear), and an observation is saturated where any channel is at the type's maximum:
        the same rule as decode's saturation masks, so a fit on these arrays sees what
        ``psrig normals`` sees on an imported session.

        Parameters
        ----------
        grey : bool
            True: the channel mean (K, H, W); False: (K, H, W, 3).

        Returns
        -------
        images : ndarray (K, H, W) or (K, H, W, 3) float32
            Linear values divided by the light intensities.
        valid : ndarray (K, H, W) bool
            False where the observation is saturated (pass it as ``estimate_normals``'s
            ``valid``).
        """
        from ..decode.image import decode_image

        stack, valid = [], []
        for path, intensity in zip(self.files, self.intensities):
            rgb, saturated, _ = decode_image(path)
            rgb = rgb / intensity.astype(np.float32)
            stack.append(rgb.mean(axis=2) if grey else rgb)
            valid.append(~saturated)
        return np.stack(stack), np.stack(valid)


def _table(path, columns):
    if not path.is_file():
        raise InputError(f"{path}: missing (a DiLiGenT folder has {path.name})")
    try:
        data = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise InputError(f"{path}: not a table of numbers ({exc})") from None
    if data.shape[1] != columns:
        raise InputError(f"{path}: expected {columns} columns, found {data.shape[1]}")
    return data


def read_normal_gt_mat(path):
    """Ground-truth normals (H, W, 3) from ``Normal_gt.mat``."""
    from scipy.io import loadmat

    try:
        data = loadmat(path)
    except Exception as exc:  # scipy raises several unrelated types for a bad file
        raise InputError(f"{path}: cannot read MATLAB file ({exc})") from None
    if "Normal_gt" not in data:
        raise InputError(f"{path}: no variable 'Normal_gt'")
    normals = np.asarray(data["Normal_gt"], dtype=np.float64)
    if normals.ndim != 3 or normals.shape[2] != 3:
        raise InputError(f"{path}: 'Normal_gt' must be H x W x 3, got {normals.shape}")
    return normals


def read_diligent(folder):
    """Read a DiLiGenT object folder (without loading the images)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such DiLiGenT folder")
    names_file = folder / "filenames.txt"
    if not names_file.is_file():
        raise InputError(f"{names_file}: missing (a DiLiGenT folder has filenames.txt)")
    names = [ln.strip() for ln in names_file.read_text().splitlines() if ln.strip()]
    files = [folder / n for n in names]
    for path in files:
        if not path.is_file():
            raise InputError(f"{path}: listed in filenames.txt but missing")
    directions = _table(folder / "light_directions.txt", 3)
    intensities = _table(folder / "light_intensities.txt", 3)
    for what, table in (("light_directions.txt", directions), ("light_intensities.txt", intensities)):
        if len(table) != len(files):
            raise InputError(f"{folder / what}: {len(table)} rows for {len(files)} images")
    mask = read_mask(folder / "mask.png")
    gt_path = folder / "Normal_gt.mat"
    normals = read_normal_gt_mat(gt_path) if gt_path.is_file() else None
    name = folder.name[:-3] if folder.name.endswith("PNG") else folder.name
    return DiligentObject(name, files, directions, intensities, mask, normals)


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
    obj = read_diligent(src)
    dest = check_target(dest)
    size = check_sizes(obj.files)
    if obj.mask.shape != size:
        raise InputError(f"{Path(src) / 'mask.png'}: mask is {obj.mask.shape[1]}x{obj.mask.shape[0]} "
                         f"but the images are {size[1]}x{size[0]}")
    if obj.normals_gt is not None and obj.normals_gt.shape[:2] != size:
        raise InputError(f"{Path(src) / 'Normal_gt.mat'}: normals are {obj.normals_gt.shape[1]}x"
                         f"{obj.normals_gt.shape[0]} but the images are {size[1]}x{size[0]}")
    source = "DiLiGenT light_directions.txt / light_intensities.txt"
    lights = LightSet(obj.directions, obj.intensities, source=source)
    session = Session.create(dest, rig={"name": "imported", "source": f"DiLiGenT {obj.name}"}, writer="import")
    frames = add_frames(session, "object", obj.files)
    write_lights(session, lights, frames)
    write_object_mask(session, obj.mask)
    write_truth_lights(session, lights)
    if obj.normals_gt is not None:
        write_truth_normals(session, obj.normals_gt, obj.mask)
    session.save()
    session.release()  # imported: the caller reads it, or opens it to write
    return session
