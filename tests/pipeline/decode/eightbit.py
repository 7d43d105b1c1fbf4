"""8-bit versions of the shared DiLiGenT objects, linear or sRGB-encoded, as loose PNG files
without colour metadata (what ``--gamma auto`` must see through).

Each 16-bit frame is divided by its light's intensities (so the lights are all 1), scaled so
that 99.5 % of the object's values fit, clipped at 1, encoded by the transfer and quantised to
8 bits. Written beside them: ``lights.txt`` (one direction a line) and ``mask.png``.
"""

from pathlib import Path

import cv2
import numpy as np

from pipeline.core.gamma import encode_gamma

from tests import SHARED_DATA

DILIGENT = SHARED_DATA / "diligent"


def write_eightbit_diligent(name, transfer, out, *, lights=slice(None), crop=None):
    """Write the 8-bit frames of DiLiGenT object ``name`` ('ball', 'cat', 'reading') to ``out``.

    Parameters
    ----------
    transfer : 'linear', 'srgb' or float
        How the values are encoded.
    lights : slice
        Which of the 96 lights to keep (fewer lights: a faster test).
    crop : (slice, slice), optional
        Rows and columns to keep.

    Returns
    -------
    list of Path
        The frame files, in light order.
    """
    folder = DILIGENT / f"{name}PNG"
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = (folder / "filenames.txt").read_text().split()
    intensities = np.loadtxt(folder / "light_intensities.txt")
    directions = np.loadtxt(folder / "light_directions.txt")
    mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    crop = crop or (slice(None), slice(None))
    chosen = range(len(names))[lights]
    stack = np.stack([cv2.imread(str(folder / names[i]), cv2.IMREAD_UNCHANGED)[:, :, ::-1][crop]
                      .astype(np.float32) / 65535 / intensities[i] for i in chosen])
    mask = mask[crop]
    scale = np.percentile(stack[:, mask], 99.5)
    files = []
    for index, frame in zip(chosen, stack):
        codes = np.round(encode_gamma(np.clip(frame / scale, 0, 1), transfer) * 255).astype(np.uint8)
        path = out / f"{index + 1:03d}.png"
        cv2.imwrite(str(path), codes[:, :, ::-1])
        files.append(path)
    np.savetxt(out / "lights.txt", directions[list(chosen)])
    cv2.imwrite(str(out / "mask.png"), mask.astype(np.uint8) * 255)
    return files


PSBOX = SHARED_DATA / "psbox"


def write_eightbit_psbox(transfer, out):
    """PSBox's 12 object frames re-encoded: taken as linear (they are cropped from raw files
    dcraw derendered, by PSBox's README, and auto reads them as linear), scaled so 99.9 % fit,
    encoded by ``transfer`` and quantised to 8 bits. Writes ``lights.txt`` (PSBox's averaged
    directions, x y z a line) beside them; returns the frame files."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = sorted((PSBOX / "Objects").glob("*.png"))
    stack = np.stack([cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files]).astype(np.float32) / 255
    stack = np.clip(stack / np.percentile(stack, 99.9), 0, 1)
    written = []
    for index, frame in enumerate(stack):
        path = out / f"{index + 1:02d}.png"
        cv2.imwrite(str(path), np.round(encode_gamma(frame, transfer) * 255).astype(np.uint8))
        written.append(path)
    np.savetxt(out / "lights.txt", np.loadtxt(PSBOX / "light_directions.txt").T)
    return written
