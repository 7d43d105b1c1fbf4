"""The report stage: ``report/index.html`` with the pictures a person checks.

The page opens from disk (relative links only, no server, no network) and shows: a thumbnail of
every decoded frame (tone-mapped from linear, one common white per frame kind so that light
intensities compare), the calibration overlays, the normal map, albedo, residual and status
maps, the angular-error map and the numbers of :func:`pipeline.evaluate.evaluate_session` when
the session has ground truth, the shaded depth render, and each stage's settings and timings.

Every picture is an 8-bit PNG copy inside ``report/`` (so the folder is self-contained); every
write is atomic. The stage is current while the files it shows and the other stages' records
are unchanged.
"""

import time

import numpy as np

from ..atomic import atomic_write_text
from ..errors import StageError
from ..imageio import read_image, read_image_native, read_mask, write_image
from .html import render_page
from .images import colour_map, normals_rgb, robust_max, shrink, status_rgb, tone_map
from ..paths import ALBEDO, ERROR_MAP, LIGHTS, NORMALS, NORMALS_MASK, REPORT, RESIDUAL, SHADED, STATUS_MAP
from ..session import STAGES

__all__ = ["report_session", "INDEX", "THUMB_SIDE"]

INDEX = REPORT
THUMB_SIDE = 160
_MAPS = (NORMALS, NORMALS_MASK, ALBEDO, RESIDUAL, STATUS_MAP, SHADED)


def _sources(session):
    """Session-relative files the report reads (that exist), in a stable order."""
    rels = [session.rel(session.linear_path(f)) for f in session.frames()
            if session.linear_path(f).is_file()]
    rels += sorted(session.rel(p) for p in session.path("calibration").glob("*.png"))
    rels += [r for r in (LIGHTS,) + _MAPS if session.path(r).is_file()]
    rels += sorted({session.rel(session.truth(k)) for k in session.manifest["truth"]
                    if session.truth(k).is_file()})
    return rels


def _write(session, rel, rgb, written):
    write_image(session.path(rel), rgb, bits=8)
    written.append(rel)
    return rel


def _thumbnails(session, written):
    """One thumbnail per decoded frame: [(kind, [(rel, caption)])]."""
    groups = {}
    for frame in session.frames():
        path = session.linear_path(frame)
        if path.is_file():
            groups.setdefault(frame["kind"], []).append((frame, shrink(read_image(path), THUMB_SIDE)))
    out = []
    for kind, items in groups.items():
        white = robust_max(np.concatenate([t.ravel() for _, t in items]))
        figures = []
        for frame, small in items:
            rel = _write(session, f"report/frames/{frame['id']}.png", tone_map(small, white), written)
            light = "" if frame.get("light") is None else f" (light {frame['light']})"
            figures.append((rel, f"{frame['id']}{light}"))
        out.append((kind, figures))
    return out


def _calibration_images(session, written):
    figures = []
    for path in sorted(session.path("calibration").glob("*.png")):
        image = read_image(path)
        rgb = (np.clip(image[:, :, :3] if image.shape[2] >= 3 else np.repeat(image[:, :, :1], 3, 2),
                       0, 1) * 255 + 0.5).astype(np.uint8)
        figures.append((_write(session, f"report/calibration/{path.name}", rgb, written), path.name))
    return figures


def _normal_maps(session, written):
    """(rel, caption) of the maps the normals, integrate and eval stages left."""
    figures = []
    path = session.path(NORMALS)
    mask_path = session.path(NORMALS_MASK)
    mask = read_mask(mask_path) if mask_path.is_file() else None
    if path.is_file():
        rgb = normals_rgb(read_image(path), mask)
        figures.append((_write(session, "report/maps/normals.png", rgb, written), "normals (n + 1) / 2"))
    truth = session.truth("normals")
    if truth is not None and truth.is_file() and truth.suffix.lower() == ".exr":
        rgb = normals_rgb(read_image(truth))
        figures.append((_write(session, "report/maps/normals_truth.png", rgb, written), "true normals"))
    path = session.path(ALBEDO)
    if path.is_file():
        albedo = read_image(path)
        figures.append((_write(session, "report/maps/albedo.png", tone_map(albedo, robust_max(albedo)),
                               written), "albedo"))
    path = session.path(RESIDUAL)
    if path.is_file():
        residual = np.abs(read_image(path)).mean(axis=2)
        top = robust_max(residual, 99)
        figures.append((_write(session, "report/maps/residual.png", colour_map(residual, top), written),
                        f"residual (0 .. {top:.3g})"))
    return figures


def _status_map(session, written):
    path = session.path(STATUS_MAP)
    if not path.is_file():
        return [], {}
    rgb, legend = status_rgb(read_image_native(path)[:, :, 0])
    return [(_write(session, "report/maps/status.png", rgb, written), "status codes")], legend


def _copy_png(session, src, dest, caption, written):
    path = session.path(src)
    if not path.is_file():
        return []
    image = read_image(path)
    rgb = (np.clip(image[:, :, :3] if image.shape[2] >= 3 else np.repeat(image[:, :, :1], 3, 2),
                   0, 1) * 255 + 0.5).astype(np.uint8)
    return [(_write(session, dest, rgb, written), caption)]


def report_session(session, *, force=False, evaluate=True):
    """Write ``report/index.html`` unless the report is up to date.

    Parameters
    ----------
    session : Session
    force : bool
        Rebuild even when current.
    evaluate : bool
        Score the session against its ground truth first (when it has any).

    Returns
    -------
    dict or None
        The stage record, or None when the report was current.
    """
    if not session.frames():
        raise StageError(f"{session.root}: the session has no frames to report on")
    sources = _sources(session)
    inputs = session.hash_inputs(sources)
    params = {"thumb": THUMB_SIDE, "evaluate": bool(evaluate),
              "stages": {n: (session.stage(n) or {}).get("finished") for n in STAGES if n != "report"}}
    if not force and session.stage_is_current("report", params, inputs):
        return None
    start = time.perf_counter()
    scores = _evaluate(session) if evaluate else {}
    written = []
    sections = _sections(session, scores, written)
    html = render_page(session, sections, scores)
    atomic_write_text(session.path(INDEX), html)
    written.append(INDEX)
    return session.record_stage("report", params, inputs, written, seconds=time.perf_counter() - start)


def _evaluate(session):
    from ..evaluate import evaluate_session

    if not session.manifest["truth"]:
        return {}
    return evaluate_session(session)


def _sections(session, scores, written):
    """{title: figures} plus the status legend, in page order."""
    status, legend = _status_map(session, written)
    sections = {"frames": _thumbnails(session, written),
                "calibration": _calibration_images(session, written),
                "maps": _normal_maps(session, written) + status,
                "legend": legend}
    if "normals" in scores:
        top = scores["normals"]["error_map_max_deg"]
        sections["maps"] += _copy_png(session, ERROR_MAP, "report/maps/error.png",
                                      f"angular error (0 .. {top:.1f} deg)", written)
    sections["maps"] += _copy_png(session, SHADED, "report/maps/shaded.png",
                                  "depth, shaded", written)
    return sections
