"""The report stage: ``report/index.html`` with what a person checks, at a glance.

The page opens from disk (relative links, no server, no network) and shows, in order: where
the lights in use came from; every stage's warnings; the stages with their times and settings;
the errors against ground truth when the session has it (numbers, a histogram, the error
against the number of lit observations and of those used); the result maps on stated scales, each false-colour
map with its colour bar (angular error 0 .. 30 degrees unless told), the status map in the one
status palette with names and pixel shares; the depth as a colour map, shaded, and in an
interactive 3-D view; the lights as a hemisphere plot and a table; the calibration overlays;
a thumbnail of every frame; and every stage record in full (settings, outcomes, warnings).

Every picture is an 8-bit PNG inside ``report/`` and every write is atomic. The stage is
current while the files it shows and the other stages' records are unchanged.
"""

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..atomic import atomic_write_text
from ..errors import StageError
from ..evaluate import ERROR_TOP_DEG
from ..imageio import read_image, read_workers, write_image
from ..paths import (ALBEDO, DEPTH, LIGHTS, LIT_OBSERVATIONS, NORMALS, NORMALS_MASK, OBSERVATIONS, REPORT,
                     RESIDUAL, SHADED, STATUS_MAP)
from ..session import STAGES, now_iso
from . import html, sections
from .images import robust_max, shrink, tone_map
from .maps import Figure, bar_figures, choose_scales, map_figures, read_maps
from .mesh_view import mesh_payload, write_mesh_view

__all__ = ["report_session", "INDEX", "THUMB_SIDE", "LAYOUT"]

INDEX = REPORT
THUMB_SIDE = 160
#: the page's layout version: a report of an older layout is rebuilt
LAYOUT = 2
_MAPS = (NORMALS, NORMALS_MASK, ALBEDO, RESIDUAL, STATUS_MAP, OBSERVATIONS, LIT_OBSERVATIONS, DEPTH, SHADED)


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


def _thumbnails(session, write):
    """One thumbnail per decoded frame: [(kind, [Figure])], one white per frame kind."""
    groups = {}
    frames = [f for f in session.stage_frames() if session.linear_path(f).is_file()]  # a bracket: its merge
    # frames read and shrunk by threads (OpenImageIO's read releases the GIL), one full frame
    # per thread in memory; map keeps the frames' order
    with ThreadPoolExecutor(read_workers(), thread_name_prefix="psrig-thumbs") as pool:
        smalls = pool.map(lambda f: shrink(read_image(session.linear_path(f)), THUMB_SIDE), frames)
        for frame, small in zip(frames, smalls):
            groups.setdefault(frame["kind"], []).append((frame, small))
    out = []
    for kind, items in groups.items():
        white = robust_max(np.concatenate([t.ravel() for _, t in items]))
        figures = []
        for frame, small in items:
            rel = write(f"report/frames/{frame['id']}.png", tone_map(small, white))
            light = "" if frame.get("light") is None else f" (light {frame['light']})"
            figures.append(Figure(rel, f"{frame['id']}{light}"))
        out.append((kind, figures))
    return out


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
    depth_figs = [f for f in figures if f.key in depth_keys]
    if depth_figs or maps.depth is not None:
        view = ""
        payload = None if maps.depth is None else mesh_payload(maps.depth, maps.normals, maps.albedo,
                                                               _integration_K(session))
        if payload is not None:
            scripts = write_mesh_view(session.path("report"), "depth", payload)
            view = sections.mesh_section("depth", payload, session.stage("integrate"))
        body.append(("Depth", html.figures(depth_figs, bars) + view))
    body.append(("Lights", sections.lights_section(session, lights, scores)))
    overlays = _calibration_images(session, write)
    if overlays:
        body.append(("Calibration", html.figures(overlays)))
    for kind, thumbs in _thumbnails(session, write):
        body.append((f"Frames: {kind} ({len(thumbs)})", html.figures(thumbs, css="thumb")))
    body.append(("Stage records", sections.details_section(session)))
    return html.page(f"psrig report: {session.root.name}", body, scripts), scripts


def _integration_K(session):
    K = ((session.stage("integrate") or {}).get("params") or {}).get("K")
    return None if K is None else np.asarray(K, float)
