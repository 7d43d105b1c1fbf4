"""The result maps of a session, read once, and their pictures on stated scales.

:func:`read_maps` gathers what the normals, integrate and eval stages left; :func:`choose_scales`
fixes the colour scales, for one session or for several compared side by side (the same scale
for all of them); :func:`map_figures` writes the pictures and names each one's scale, so that
the page can put a colour bar beside every false-colour map.

Fixed scales: angular error and expected angular error (the normals stage's uncertainty map)
0 .. 30 degrees (``max_deg``, the same scale so that they compare), residual 0 .. 0.1 of the albedo.
Depth has no natural scale (it is known up to an offset, or a scale under perspective): its
scale is the 1st .. 99th percentile of the heights, over all the sessions compared, in the
integration's unit. Albedo is a tone-mapped picture (no false colour), white stated.
"""

import html
from dataclasses import dataclass, field

import numpy as np

from ..evaluate import ERROR_TOP_DEG, normal_errors
from ..core.imageio import read_image, read_image_native, read_mask
from ..core.paths import (ALBEDO, DEPTH, LIT_OBSERVATIONS, NORMALS, NORMALS_MASK, OBSERVATIONS, RESIDUAL, SHADED, STATUS_MAP,
                     UNCERTAINTY)
from ..photometric import share_text
from .images import Scale, colour_bar, colour_map, normals_rgb, robust_max, status_legend, status_rgb, tone_map

__all__ = ["SessionMaps", "Figure", "read_maps", "choose_scales", "map_figures", "bar_figures", "RESIDUAL_TOP"]

#: top of the residual scale: RMS residual relative to the albedo
RESIDUAL_TOP = 0.1


@dataclass
class Figure:
    """One picture of the page: session-relative ``rel`` inside the report folder, a caption,
    the :class:`Scale` of its colours (a colour bar is drawn beside it) and a legend (HTML)."""

    rel: str
    caption: str
    scale: Scale = None
    legend: str = ""
    key: str = ""


@dataclass
class SessionMaps:
    """The maps a session has (None where it has not)."""

    normals: np.ndarray = None
    mask: np.ndarray = None
    truth: np.ndarray = None
    albedo: np.ndarray = None
    residual: np.ndarray = None
    status: np.ndarray = None
    errors: np.ndarray = None
    uncertainty: np.ndarray = None
    observations: np.ndarray = None
    lit: np.ndarray = None
    depth: np.ndarray = None
    shaded: np.ndarray = None
    depth_unit: str = "px"
    depth_scale: float = 1.0
    extra: dict = field(default_factory=dict)


def _read(session, rel, reader=read_image):
    path = session.path(rel)
    return reader(path) if path.is_file() else None


def read_maps(session):
    """A :class:`SessionMaps` of ``session``."""
    maps = SessionMaps()
    maps.mask = _read(session, NORMALS_MASK, read_mask)
    normals = _read(session, NORMALS)
    maps.normals = None if normals is None else normals[:, :, :3]
    truth = session.truth("normals")
    if truth is not None and truth.is_file() and truth.suffix.lower() == ".exr":
        maps.truth = read_image(truth)[:, :, :3]
    maps.albedo = _read(session, ALBEDO)
    uncertainty = _read(session, UNCERTAINTY)   # none from earlier versions, or too few lights
    maps.uncertainty = None if uncertainty is None else uncertainty[:, :, 0]
    residual = _read(session, RESIDUAL)
    maps.residual = None if residual is None else np.abs(residual).mean(axis=2)
    status = _read(session, STATUS_MAP, read_image_native)
    maps.status = None if status is None else status[:, :, 0].astype(np.int64)
    counts = _read(session, OBSERVATIONS, read_image_native)
    maps.observations = None if counts is None else counts[:, :, 0].astype(np.int64)
    lit = _read(session, LIT_OBSERVATIONS, read_image_native)   # sessions before it: none
    maps.lit = None if lit is None else lit[:, :, 0].astype(np.int64)
    if maps.normals is not None:
        maps.errors = normal_errors(session)[0]
    depth = _read(session, DEPTH)
    maps.depth = None if depth is None else depth[:, :, 0]
    maps.shaded = _read(session, SHADED)
    record = session.stage("integrate") or {}
    maps.depth_unit = "px" if not (record.get("params") or {}).get("K") else "relative depth"
    mesh = record.get("mesh") or {}
    if mesh.get("scale"):   # depth.exr in the unit a length given to integrate set (mm)
        maps.depth_unit, maps.depth_scale = mesh.get("unit") or "mm", float(mesh["scale"])
    return maps


def choose_scales(all_maps, max_deg=ERROR_TOP_DEG):
    """{name: Scale or white level} shared by every session of ``all_maps``."""
    depths = [m.depth[np.isfinite(m.depth)] for m in all_maps if m.depth is not None]
    depths = np.concatenate(depths) if depths else np.zeros(0)
    low, high = (np.percentile(depths, [1, 99]) if depths.size else (0.0, 1.0))
    if high <= low:
        high = low + 1.0
    units = {m.depth_unit for m in all_maps if m.depth is not None} or {"px"}
    albedos = [m.albedo[m.mask] if m.mask is not None and m.albedo.shape[:2] == m.mask.shape else m.albedo
               for m in all_maps if m.albedo is not None]
    return {"error": Scale("error", 0.0, float(max_deg), "deg", "viridis"),
            "uncertainty": Scale("uncertainty", 0.0, float(max_deg), "deg", "viridis"),
            "residual": Scale("residual", 0.0, RESIDUAL_TOP, "of albedo", "magma"),
            "depth": Scale("depth", float(low), float(high), " / ".join(sorted(units)), "cividis"),
            "albedo_white": robust_max(np.concatenate([a.ravel() for a in albedos])) if albedos else 1.0}


def _above(values, scale):
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(np.mean(values > scale.top)) if values.size else 0.0


def map_figures(maps, scales, folder, write, names=None, colours=None):
    """Write the pictures of one session's maps; returns [Figure] in page order.

    Parameters
    ----------
    maps : SessionMaps
    scales : dict
        :func:`choose_scales`'s.
    folder : str
        Session-relative folder the pictures go to (e.g. 'report/maps').
    write : callable
        ``write(rel, rgb)`` writes an 8-bit picture and returns ``rel``.
    names, colours : dict, ndarray (256, 3)
        Status names (:data:`pipeline.photometric.STATUS_NAMES`) and the status palette.
    """
    figures = []
    if maps.normals is not None:
        figures.append(Figure(write(f"{folder}/normals.png", normals_rgb(maps.normals, maps.mask)),
                              "normals, RGB = (n + 1) / 2", key="normals"))
    if maps.truth is not None:
        figures.append(Figure(write(f"{folder}/normals_truth.png", normals_rgb(maps.truth)), "true normals",
                              key="truth"))
    if maps.errors is not None:
        scale = scales["error"]
        figures.append(Figure(write(f"{folder}/error.png", colour_map(maps.errors, scale)),
                              f"angular error; {_above(maps.errors, scale):.1%} of pixels above {scale.top:g} deg",
                              scale, key="error"))
    if maps.uncertainty is not None:
        scale = scales["uncertainty"]
        figures.append(Figure(write(f"{folder}/uncertainty.png", colour_map(maps.uncertainty, scale)),
                              f"expected angular error (uncertainty, without ground truth); "
                              f"{_above(maps.uncertainty, scale):.1%} of pixels above {scale.top:g} deg",
                              scale, key="uncertainty"))
    if maps.status is not None and names is not None:
        rows = status_legend(maps.status, names, colours)
        total = sum(row[3] for row in rows)
        legend = "".join(f'<span class="swatch" style="background: rgb{rgb}"></span>{name} '
                         f"{html.escape(share_text(pixels, total))} <small>({pixels} px)</small><br>"
                         for _, name, rgb, pixels, _ in rows)
        figures.append(Figure(write(f"{folder}/status.png", status_rgb(maps.status, colours)),
                              "status of each pixel's fit", legend=legend, key="status"))
    if maps.albedo is not None:
        white = scales["albedo_white"]
        kind = "RGB" if maps.albedo.shape[2] >= 3 else "grey"
        figures.append(Figure(write(f"{folder}/albedo.png", tone_map(maps.albedo, white)),
                              f"albedo ({kind}), white = {white:.3g}", key="albedo"))
    if maps.residual is not None:
        scale = scales["residual"]
        figures.append(Figure(write(f"{folder}/residual.png", colour_map(maps.residual, scale)),
                              "residual, RMS relative to the albedo", scale, key="residual"))
    if maps.depth is not None:
        scale = scales["depth"]
        figures.append(Figure(write(f"{folder}/depth.png", colour_map(maps.depth, scale)),
                              "depth (height toward the camera)", scale, key="depth"))
    if maps.shaded is not None:
        grey = (np.clip(maps.shaded[:, :, :1], 0, 1) * 255 + 0.5).astype(np.uint8).repeat(3, axis=2)
        figures.append(Figure(write(f"{folder}/shaded.png", grey), "depth, shaded", key="shaded"))
    return figures


def bar_figures(scales, folder, write):
    """{scale name: rel} of a colour-bar picture per false-colour scale."""
    return {name: write(f"{folder}/bar_{name}.png", colour_bar(scale))
            for name, scale in scales.items() if isinstance(scale, Scale)}
