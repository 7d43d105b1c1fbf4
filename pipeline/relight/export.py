"""``psrig export SESSION --relight DIR``: what another viewer needs to relight the object.

Writes, at full resolution, the fitted model of :mod:`pipeline.relight` (the normal, the RGB
albedo and the nine coefficients of the paper's Eq. 2 per pixel) and ``relight.json``, which says
exactly how to evaluate it: the frames, each file's channels in order and how to decode them,
the formula, and a worked example (one pixel under one light, with the value
:func:`pipeline.relight.shade` gives) to check an implementation against.

Formats: ``exr`` (float32, lossless; the default) or ``png`` (16-bit, each channel an affine code
``value = offset + scale * code / 65535`` with its offset and scale in the JSON).
"""

import json
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_write_text
from ..core.errors import InputError
from ..core.imageio import write_image, write_mask
from ..photometric.stage import PAPER_NAMES
from .model import MATERIAL, read_model, shade

__all__ = ["export_relight", "FORMATS", "COEFFICIENTS", "FORMULA", "SPEC_NAME"]

FORMATS = ("exr", "png")
SPEC_NAME = "relight.json"
#: the coefficients in the paper's order with the monomial each multiplies
COEFFICIENTS = (("A", "x^2 y^2"), ("B", "x^2 y"), ("C", "x^2"), ("D", "x y^2"), ("E", "x y"), ("F", "x"),
                ("G", "y^2"), ("H", "y"), ("I", "1"))
#: coefficients.exr's channel names: the normals stage's brdf.exr names, which sort in order A..I
CHANNELS = PAPER_NAMES
FORMULA = {
    "light": "l: unit vector toward a distant light, camera frame",
    "view": "v = (0, 0, 1): orthographic camera looking down -z",
    "half_vector": "h = (l + v) / |l + v|",
    "x": "x = n . h",
    "y": "y = l . h",
    "rho": "rho = A x^2 y^2 + B x^2 y + C x^2 + D x y^2 + E x y + F x + G y^2 + H y + I",
    "image": "I_c = albedo_c * rho * max(n . l, 0), for c in R, G, B (linear; light intensity 1)",
    "diffuse_only": "I_c = albedo_c * max(n . l, 0)",
    "outside_mask": "no model: mask = 0 (normals, albedo and coefficients are 0 there)",
}


def _png_channels(values, mask):
    """uint16 codes (H, W, C) of float ``values`` with per-channel offset and scale over ``mask``."""
    inside = values[mask] if mask.any() else np.zeros((1, values.shape[2]))
    low, high = inside.min(axis=0).astype(np.float64), inside.max(axis=0).astype(np.float64)
    scale = np.where(high > low, high - low, 1.0)
    codes = np.clip(np.round((values - low) / scale * 65535), 0, 65535).astype(np.uint16)
    codes[~mask] = 0
    return codes, [{"offset": float(o), "scale": float(s)} for o, s in zip(low, scale)]


def _example(model):
    """One object pixel (the mask's middle one) under one light, evaluated by :func:`shade`."""
    rows, cols = np.nonzero(model.mask)
    k = len(rows) // 2
    r, c = int(rows[k]), int(cols[k])
    light = np.array([0.3, 0.4, np.sqrt(1 - 0.25)])
    value = shade(model.normals[r, c][None], model.coefficients[r, c][None], model.albedo[r, c][None], light)[0]
    return {"pixel_row_col": [r, c], "light": light.round(6).tolist(),
            "normal": model.normals[r, c].astype(float).round(7).tolist(),
            "albedo_rgb": model.albedo[r, c].astype(float).round(7).tolist(),
            "coefficients_A_to_I": model.coefficients[r, c].astype(float).round(7).tolist(),
            "image_rgb": value.round(7).tolist()}


def export_relight(session, folder, fmt="exr"):
    """Write the session's fitted model and ``relight.json`` into ``folder``.

    Parameters
    ----------
    session : Session
        A session whose normals stage has run.
    folder : str or Path
        Created when missing.
    fmt : {'exr', 'png'}

    Returns
    -------
    dict
        The JSON written (its ``files`` name what was written).
    """
    if fmt not in FORMATS:
        raise InputError(f"export: format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    model = read_model(session)
    if not model.mask.any():
        raise InputError(f"{session.path('normals/mask.png')}: the model has no object pixel to export")
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: exists and is not a folder")
    root, target = session.root.resolve(), folder.resolve()
    # the session's own files have these names (normals/mask.png): never written over
    if target == root or (root in target.parents and target.relative_to(root).parts[0] != "export"):
        raise InputError(f"{folder}: inside the session, where its stages' files are; export to a folder "
                         f"of its own (or under {session.root / 'export'})")
    folder.mkdir(parents=True, exist_ok=True)
    names = [n for n, _ in COEFFICIENTS]
    files = {}
    write_mask(folder / "mask.png", model.mask)
    files["mask"] = {"file": "mask.png", "channels": ["mask"], "decode": "8-bit: 255 = object pixel, 0 = none"}
    if fmt == "exr":
        write_image(folder / "normals.exr", model.normals, channel_names=("normal.x", "normal.y", "normal.z"))
        write_image(folder / "albedo.exr", model.albedo, channel_names=("R", "G", "B"))
        write_image(folder / "coefficients.exr", model.coefficients, channel_names=CHANNELS)
        files["normals"] = {"file": "normals.exr", "channels": ["normal.x", "normal.y", "normal.z"],
                            "decode": "float32 as stored"}
        files["albedo"] = {"file": "albedo.exr", "channels": ["R", "G", "B"], "decode": "float32 as stored"}
        files["coefficients"] = {"file": "coefficients.exr",
                                 "channels": list(CHANNELS),
                                 "decode": "float32 as stored; the channel names sort in the order A..I"}
    else:
        normals = np.where(model.mask[..., None], (model.normals + 1.0) / 2.0, 0.0)
        write_image(folder / "normals.png", np.round(np.clip(normals, 0, 1) * 65535).astype(np.uint16), bits=16)
        files["normals"] = {"file": "normals.png", "channels": ["normal.x", "normal.y", "normal.z"],
                            "decode": "16-bit: n = 2 * code / 65535 - 1, then normalise"}
        codes, ranges = _png_channels(model.albedo, model.mask)
        write_image(folder / "albedo.png", codes, bits=16)
        files["albedo"] = {"file": "albedo.png", "channels": ["R", "G", "B"], "codes": ranges,
                           "decode": "16-bit linear (no sRGB curve): value = offset + scale * code / 65535"}
        for part in range(3):
            chosen = names[3 * part:3 * part + 3]
            codes, ranges = _png_channels(model.coefficients[:, :, 3 * part:3 * part + 3], model.mask)
            name = f"coefficients_{''.join(chosen)}.png"
            write_image(folder / name, codes, bits=16)
            files[f"coefficients_{''.join(chosen)}"] = {
                "file": name, "channels": chosen, "codes": ranges,
                "decode": "16-bit: value = offset + scale * code / 65535 (per channel)"}
    height, width = model.shape
    spec = {
        "format": "psrig-relight", "version": 1, "session": session.root.name, "width": width, "height": height,
        "method": model.method,
        "frames": {"camera": "x right, y up (image rows go down), z toward the camera; orthographic",
                   "pixels": "row 0 is the top of the image, column 0 its left; the files are full resolution"},
        "units": "linear, the light intensities divided out (a light of intensity 1)",
        "files": files,
        "coefficients": [{"name": n, "monomial": m} for n, m in COEFFICIENTS],
        "coefficients_note": ("relative to the albedo; psrig fitted them" if model.method == "biquadratic" else
                              f"relative to the albedo; converted from the {model.method!r} fit"
                              if model.family == "biquadratic" else
                              f"the normals were fitted with {model.method!r}, outside the biquadratic's family: "
                              "A..H = 0, I = 1 (Lambertian)"),
        "formula": FORMULA,
        "normals_material": dict(MATERIAL, formula="grey = diffuse * max(n.l, 0) + specular * max(n.h, 0)^exponent "
                                                   "where n.l > 0 (psrig's report, mode 'normals')"),
        "example": _example(model),
    }
    atomic_write_text(folder / SPEC_NAME, json.dumps(spec, indent=2) + "\n")
    return spec
