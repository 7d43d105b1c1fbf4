"""The report stage: ``report/index.html`` with what a person checks, at a glance.

The page opens from disk (relative links, no server, no network) and shows, in order: where
the lights in use came from; every stage's warnings; the stages with their times and settings;
the errors against ground truth when the session has it (numbers, a histogram, the error
against the number of lit observations and of those used); the result maps on stated scales, each false-colour
map with its colour bar (angular error 0 .. 30 degrees unless told), the status map in the one
status palette with names and pixel shares; the depth as a colour map, shaded, and in an
interactive 3-D view; the lights as a hemisphere plot and a table; the calibration overlays;
the object mask's outline over the brightest object frame, with where the mask came from;
a thumbnail of every frame; and every stage record in full (settings, outcomes, warnings).

Every picture is an 8-bit PNG inside ``report/`` and every write is atomic. The stage is
current while the files it shows and the other stages' records are unchanged.
"""

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..core.atomic import atomic_write_text
from ..core.errors import StageError
from ..evaluate import ERROR_TOP_DEG
from ..core.imageio import read_image, read_workers, write_image
from ..core.paths import (ALBEDO, DEPTH, LIGHTS, LIT_OBSERVATIONS, NORMALS, NORMALS_MASK, OBSERVATIONS, PREDICTION,
                     PREDICTION_IMAGES, REPORT, RESIDUAL, SHADED, STATUS_MAP, UNCERTAINTY)
from ..core.session import STAGES, now_iso
from ..settings.report import ReportOptions
from ..core.stage import Stage
from . import html, sections
from .images import robust_max, shrink, tone_map
from .maps import Figure, bar_figures, choose_scales, map_figures, read_maps
from .mesh_view import mesh_payload, write_mesh_view
from .prediction import prediction_section
from .relight_view import relight_payload, relight_section, write_relight_view

__all__ = ["report_session", "INDEX", "THUMB_SIDE", "LAYOUT"]

INDEX = REPORT
THUMB_SIDE = 160
#: longer side of the mask figure (its outline over the brightest object frame)
MASK_SIDE = 480
#: the page's layout version: a report of an older layout is rebuilt
LAYOUT = 3
_MAPS = (NORMALS, NORMALS_MASK, ALBEDO, RESIDUAL, UNCERTAINTY, STATUS_MAP, OBSERVATIONS, LIT_OBSERVATIONS, DEPTH,
         SHADED, PREDICTION, PREDICTION_IMAGES)


def _sources(session):
    """Session-relative files the report reads (that exist), in a stable order."""
    rels = [session.rel(session.linear_path(f)) for f in session.stage_frames()
            if session.linear_path(f).is_file()]
    rels += sorted(session.rel(p) for p in session.path("calibration").glob("*.png"))
    rels += [r for r in (LIGHTS,) + _MAPS if session.path(r).is_file()]
    rels += sorted({session.rel(session.truth(k)) for k in session.manifest["truth"]
                    if session.truth(k).is_file()})
    return rels


def _writer(session, written):
    def write(rel, rgb):
        write_image(session.path(rel), rgb, bits=8)
        written.append(rel)
        return rel
    return write


def _thumbnails(session, write, peak=None):
    """One thumbnail per decoded frame: [(kind, [Figure])], one white per frame kind.

    ``peak`` (a dict), when given, gets under 'image' the per-pixel brightest of the object
    frames shrunk to :data:`MASK_SIDE` (what the mask figure draws its outline on)."""
    groups = {}
    frames = [f for f in session.stage_frames() if session.linear_path(f).is_file()]  # a bracket: its merge

    def shrunk(frame):
        image = read_image(session.linear_path(frame))
        big = shrink(image, MASK_SIDE) if peak is not None and frame["kind"] == "object" else None
        return shrink(image, THUMB_SIDE), big

    # frames read and shrunk by threads (OpenImageIO's read releases the GIL), one full frame
    # per thread in memory; map keeps the frames' order
    with ThreadPoolExecutor(read_workers(), thread_name_prefix="psrig-thumbs") as pool:
        for frame, (small, big) in zip(frames, pool.map(shrunk, frames)):
            if big is not None:
                peak["image"] = big if "image" not in peak else np.maximum(peak["image"], big)
            groups.setdefault(frame["kind"], []).append((frame, small))
    out = []
    whites = {kind: robust_max(np.concatenate([t.ravel() for _, t in items])) for kind, items in groups.items()}
    lit = next((k for k in ("object", "sphere", "target") if k in whites), None)
    for kind, items in groups.items():
        # a dark frame on its own white is amplified noise in false colour: unlit frames are
        # shown grey on the lit frames' scale, as dark as they are
        unlit = kind in ("dark", "ambient") and lit is not None
        white = whites[lit] if unlit else whites[kind]
        figures = []
        for frame, small in items:
            shown = small.mean(axis=2, keepdims=True) if unlit else small
            rel = write(f"report/frames/{frame['id']}.png", tone_map(shown, white))
            light = "" if frame.get("light") is None else f" (light {frame['light']})"
            scale = f", grey, on the {lit} frames' scale" if unlit else ""
            figures.append(Figure(rel, f"{frame['id']}{light}{scale}"))
        out.append((kind, figures))
    return out


def _mask_figure(session, write, peak):
    """The object mask's outline (yellow) over the brightest of the object frames, captioned
    with where the mask came from (the normals record's ``mask``); None without both."""
    import cv2

    record = (session.stage("normals") or {}).get("mask") or {}
    if peak is None or not session.path(NORMALS_MASK).is_file():
        return None
    mask = read_image(session.path(NORMALS_MASK))[:, :, 0] > 0.5
    rgb = tone_map(peak, robust_max(peak))
    small = cv2.resize(mask.astype(np.uint8), (rgb.shape[1], rgb.shape[0]), interpolation=cv2.INTER_NEAREST)
    edge = small.astype(bool) & ~cv2.erode(small, np.ones((3, 3), np.uint8)).astype(bool)
    rgb[edge] = (255, 220, 0)
    caption = record.get("text") or "mask"
    if record.get("warning"):
        caption += " (warning: " + record["warning"] + ")"
    return Figure(write("report/mask.png", rgb), caption + "; outline over the brightest of the object frames")


def _calibration_images(session, write):
    figures = []
    for path in sorted(session.path("calibration").glob("*.png")):
        image = read_image(path)
        rgb = (np.clip(image[:, :, :3] if image.shape[2] >= 3 else np.repeat(image[:, :, :1], 3, 2),
                       0, 1) * 255 + 0.5).astype(np.uint8)
        figures.append(Figure(write(f"report/calibration/{path.name}", rgb), path.name))
    return figures


def report_session(session, *, force=False, evaluate=True, max_deg=ERROR_TOP_DEG):
    """Write ``report/index.html`` unless the report is up to date.

    Parameters
    ----------
    session : Session
    force : bool
        Rebuild even when current.
    evaluate : bool
        Score the session against its ground truth first (when it has any).
    max_deg : float
        Top of the angular-error scale, degrees (30 unless told; the same for every session,
        so that reports compare).

    Returns
    -------
    dict or None
        The stage record, or None when the report was current.
    """
    if not session.frames():
        raise StageError(f"{session.root}: the session has no frames to report on")
    if not max_deg or max_deg <= 0:
        raise StageError(f"--max-deg {max_deg}: the top of the error scale must be a positive angle")
    inputs = session.hash_inputs(_sources(session))
    params = {"thumb": THUMB_SIDE, "evaluate": bool(evaluate), "max_deg": float(max_deg), "layout": LAYOUT,
              "stages": {n: (session.stage(n) or {}).get("finished") for n in STAGES if n != "report"}}
    if not force and session.stage_is_current("report", params, inputs):
        return None
    start = time.perf_counter()
    scores = _evaluate(session, max_deg) if evaluate else {}
    written = []
    text, scripts = _page(session, scores, max_deg, _writer(session, written))
    written += [f"report/{name}" for name in scripts]
    atomic_write_text(session.path(INDEX), text)
    written.append(INDEX)
    return session.record_stage("report", params, inputs, written, seconds=time.perf_counter() - start)


def _evaluate(session, max_deg):
    from ..evaluate import evaluate_session

    if not session.manifest["truth"]:
        return {}
    return evaluate_session(session, max_deg=max_deg)


def status_palette():
    """Status names and the (256, 3) colour table of the normals stage (one palette)."""
    from ..photometric import STATUS_NAMES
    from ..photometric.stage import STATUS_COLOURS

    return STATUS_NAMES, STATUS_COLOURS


def _page(session, scores, max_deg, write):
    """The page's HTML and the script files it loads (inside report/)."""
    lights = sections.lights_in_use(session)
    maps = read_maps(session)
    scales = choose_scales([maps], max_deg)
    bars = bar_figures(scales, "report/maps", write)
    names, colours = status_palette()
    figures = map_figures(maps, scales, "report/maps", write, names, colours)
    depth_keys = ("depth", "shaded")
    body = [(None, sections.header(session, lights, now_iso())),
            ("Warnings", html.warnings_box(sections.all_warnings(session, lights))),
            ("Stages", sections.stages_table(session))]
    if scores:
        body.append(("Errors against ground truth",
                     sections.scores_section(scores) + sections.charts_section(maps, scales["error"])))
    body.append(("Results", html.figures([f for f in figures if f.key not in depth_keys], bars)))
    scripts = ()
    if session.path(NORMALS).is_file():
        relit, scripts = _relighting(session, lights)
        body.append(("Relighting: the fitted model under a light you move", relit))
        body.append(("Held-out lights: does the fit predict frames it was not given?",
                     prediction_section(session, write)))
    depth_figs = [f for f in figures if f.key in depth_keys]
    if depth_figs or maps.depth is not None:
        view = ""
        # the 3-D view takes orthographic heights in pixels (depth.exr may be in mm)
        payload = None if maps.depth is None else mesh_payload(maps.depth / maps.depth_scale, maps.normals, maps.albedo,
                                                               _integration_K(session))
        if payload is not None:
            scripts = scripts + write_mesh_view(session.path("report"), "depth", payload)
            view = sections.mesh_section("depth", payload, session.stage("integrate"))
        body.append(("Depth", html.figures(depth_figs, bars) + view))
    body.append(("Lights", sections.lights_section(session, lights, scores)))
    overlays = _calibration_images(session, write)
    if overlays:
        body.append(("Calibration", html.figures(overlays)))
    peak = {}
    thumbnails = _thumbnails(session, write, peak)
    mask = _mask_figure(session, write, peak.get("image"))
    if mask is not None:
        body.append(("Mask", html.figures([mask])))
    for kind, thumbs in thumbnails:
        body.append((f"Frames: {kind} ({len(thumbs)})", html.figures(thumbs, css="thumb")))
    body.append(("Stage records", sections.details_section(session)))
    return html.page(f"psrig report: {session.root.name}", body, scripts), scripts


def _relighting(session, lights):
    """The relighting view's HTML and its scripts (a paragraph and none when the model cannot
    be read)."""
    from ..core.errors import InputError
    from ..relight import read_model

    try:
        model = read_model(session)
    except InputError as err:
        return f"<p>No relighting view: {html.escape(str(err))}</p>", ()
    frames = [(f["id"], f["light"], f"frames/{f['id']}.png") for f in session.stage_frames("object")
              if f.get("light") is not None and session.linear_path(f).is_file()
              and lights is not None and f["light"] < len(lights)]
    payload = relight_payload(model, None if lights is None else lights.directions, frames)
    if payload is None:
        return "<p>No relighting view: the normals have no object pixel.</p>", ()
    return relight_section("model", payload), write_relight_view(session.path("report"), "model", payload)


def _integration_K(session):
    K = ((session.stage("integrate") or {}).get("params") or {}).get("K")
    return None if K is None else np.asarray(K, float)


class ReportStage(Stage):
    """The ``report`` stage (:class:`pipeline.core.stage.Stage`): :func:`report_session`."""

    name = "report"
    Options = ReportOptions
    reads = ("every other stage's outputs and record", "truth/ (ground truth, when the session has it)")

    def work(self, session, options, *, force, jobs):
        return report_session(session, force=force, **options) is not None, ""

    def replay(self, record):
        params = (record or {}).get("params") or {}
        return {k: params[k] for k in ("max_deg", "evaluate") if k in params}


#: the stage object the runner and the scheduler run
REPORT = ReportStage()
