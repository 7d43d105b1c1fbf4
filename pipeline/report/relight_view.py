"""The report's relighting view: drag a virtual light over the hemisphere and see the fitted model.

The model (:mod:`pipeline.relight`: per pixel a unit normal, the nine coefficients of Eq. 2 and
the RGB albedo) is written for the view on a grid of every ``step``-th pixel, at most
:data:`MAX_SIDE` pixels on the long side (sampled, not averaged: the view draws the fitted values
themselves; the full resolution is ``psrig export --relight``), as a script ``relight_<key>.js``
(``window.PSRIG_RELIGHT[key] = {...}``, float32 arrays in base64, object pixels only) beside a
copy of the viewer ``relight.js`` (:file:`relight.js` in this package: WebGL with float textures,
per-pixel evaluation in the fragment shader, or a 2-D canvas evaluating the same formula in
JavaScript). Scripts load from ``file://``: the view works from disk, with no server and no
network. The nearest captured frame is the report's own thumbnail (``frames/<id>.png``).
"""

import base64
import html
from pathlib import Path

import numpy as np

from ..relight import shade
from .images import robust_max
from .mesh_view import write_view_files

__all__ = ["relight_payload", "write_relight_view", "relight_section", "viewer_source", "MAX_SIDE", "VIEWER",
           "START_LIGHT", "display_white"]

#: longest side of the view's grid, pixels (a 256 x 192 grid of object pixels is ~1.5 MB of script)
MAX_SIDE = 256
#: the viewer, shipped with psrig (package data)
VIEWER = Path(__file__).with_name("relight.js")
#: the light the view opens with (upper left, 30 degrees off the view axis)
START_LIGHT = (-0.35, 0.35, 0.866)


def viewer_source():
    """The relighting viewer's JavaScript."""
    return VIEWER.read_text(encoding="utf-8")


def _b64(array):
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii")


def display_white(model):
    """The linear value shown as white: the 99th percentile of the model's brightest channel
    under a light on the view axis (the view's exposure control scales it)."""
    inside = model.mask
    lit = shade(model.normals[inside], model.coefficients[inside], model.albedo[inside], (0.0, 0.0, 1.0))
    value = robust_max(lit.max(axis=1), 99.0) if lit.size else 1.0
    return float(value) if np.isfinite(value) and value > 0 else 1.0


def relight_payload(model, lights=None, frames=None, max_side=MAX_SIDE):
    """The view's data for a :class:`pipeline.relight.FittedModel`, or None without object pixels.

    Parameters
    ----------
    model : FittedModel
        Full resolution; sampled here to every ``step``-th pixel.
    lights : ndarray (K, 3), optional
        The captured frames' light directions (the hemisphere's dots, the nearest frame).
    frames : list of (str, int, str), optional
        Per light: frame id, light index, and the thumbnail's path relative to the page.

    Returns
    -------
    dict
        ``width``, ``height``, ``step``, ``pixels``; ``mask`` (uint8, h x w), ``values``
        (float32, pixels x 16: nx, ny, nz, 1, A..I, albedo R, G, B, in row-major pixel order),
        both base64; ``white`` (linear value shown white), ``method``, ``light`` (the start),
        ``lights`` and ``frames``.
    """
    step = max(1, int(np.ceil(max(model.shape) / max_side)))
    grid = model.grid(step)
    inside = grid.mask
    if not inside.any():
        return None
    count = int(inside.sum())
    values = np.concatenate([grid.normals[inside], np.ones((count, 1), np.float32), grid.coefficients[inside],
                             grid.albedo[inside]], axis=1).astype(np.float32)
    lights = [] if lights is None else np.round(np.asarray(lights, float), 5).tolist()
    return {"width": int(inside.shape[1]), "height": int(inside.shape[0]), "step": step, "pixels": count,
            "mask": _b64(inside.astype(np.uint8)), "values": _b64(values), "white": display_white(grid),
            "method": model.method, "family": model.family, "light": list(START_LIGHT), "lights": lights,
            "frames": [{"id": i, "light": int(k), "thumb": t} for i, k, t in (frames or [])]}


def write_relight_view(folder, key, payload):
    """Write ``folder/relight_<key>.js`` and ``folder/relight.js``; returns their file names."""
    return write_view_files(folder, "PSRIG_RELIGHT", f"relight_{key}.js", key, payload, VIEWER)


def _nearest_frame(payload):
    """The thumbnail of the captured frame whose light is nearest the view's start (None without
    frames)."""
    lights, frames = payload["lights"], payload["frames"]
    known = [f for f in frames if f["light"] < len(lights)]
    if not known:
        return None
    start = np.asarray(payload["light"], float)
    return max(known, key=lambda f: float(np.dot(lights[f["light"]], start)))["thumb"]


def relight_section(key, payload):
    """The view's canvases, mode buttons, exposure and readout (the scripts are added to the page)."""
    scale = max(1, 480 // max(payload["width"], payload["height"]))
    width, height = payload["width"] * scale, payload["height"] * scale
    fitted = payload["family"] == "biquadratic"
    modes = [("model", "the model" if fitted else f"the model ({html.escape(payload['method'])}: drawn Lambertian)"),
             ("diffuse", "diffuse only (albedo &times; n&middot;l)"), ("normals", "normals, fixed material")]
    start = _nearest_frame(payload)
    frame = ""
    if start is not None:
        modes.append(("frame", "nearest captured frame"))
        frame = (f'<img id="relight-{key}-frame" src="{html.escape(start, quote=True)}" alt="nearest captured frame" '
                 f'hidden style="width:{width}px;height:{height}px;border:1px solid #ccc">')
    buttons = " ".join(f'<label><input type="radio" name="relight-{key}-mode" value="{m}"'
                       f'{" checked" if m == "model" else ""}> {text}</label>' for m, text in modes)
    note = (f"The fitted model per pixel (every {payload['step']} pixel(s), {payload['pixels']} pixels), "
            "rendered for a light you drag over the hemisphere (on the disc, or on the image); dots on the "
            "disc are the captured lights. Full resolution: <code>psrig export SESSION --relight DIR</code>.")
    return (f"<p>{note}</p>"
            f'<div class="relight" style="display:flex;gap:1em;align-items:flex-start;flex-wrap:wrap">'
            f'<div><canvas id="relight-{key}" class="psrig-relight" data-relight="{key}" '
            f'width="{payload["width"]}" height="{payload["height"]}" tabindex="0" '
            f'style="width:{width}px;height:{height}px;image-rendering:pixelated;touch-action:none;'
            f'border:1px solid #ccc;cursor:crosshair" aria-label="relit object"></canvas>'
            f'{frame}</div>'
            f'<div><canvas id="relight-{key}-dome" class="psrig-dome" width="200" height="200" '
            f'style="touch-action:none;cursor:crosshair" aria-label="light direction: drag"></canvas>'
            f'<p id="relight-{key}-readout" style="font-family:monospace;font-size:0.85em"></p>'
            f'<p>{buttons}</p><p><label>exposure <input type="range" id="relight-{key}-exposure" min="-3" '
            f'max="3" step="0.1" value="0"></label></p></div></div>'
            f'<p id="relight-{key}-note"><noscript>The relighting view needs JavaScript.</noscript></p>')
