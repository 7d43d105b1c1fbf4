"""Several sessions (or one object processed with several methods) side by side on the same
scales: ``psrig report A B ... --out DIR`` writes ``DIR/index.html``.

One column per session, one row per map (normals, true normals, angular error, status, albedo,
residual, depth, shaded), every row on one scale (:func:`pipeline.report.maps.choose_scales`
over all the sessions: the error's top is fixed, the depth's range spans them all, one albedo
white) with its colour bar; a table of each session's method, settings, lights, status shares,
errors and warnings; the error histograms and the error against the observations used, one
line per session. The folder is self-contained (copies of the pictures) and opens from disk.
"""

from pathlib import Path

from ..core.atomic import atomic_write_text
from ..core.errors import InputError
from ..evaluate import ERROR_TOP_DEG, evaluate_session
from ..core.imageio import write_image
from ..photometric import share_text
from ..core.session import now_iso
from . import html, sections
from .details import flatten, format_value, settings_used
from .maps import bar_figures, choose_scales, map_figures, read_maps

__all__ = ["compare_sessions", "prepare_compare_folder", "MARK", "ROWS"]

#: the file that marks a folder as a comparison (so that a rerun may overwrite it)
MARK = ".psrig-compare"
#: map rows in page order: (figure key, heading)
ROWS = (("normals", "normals"), ("truth", "true normals"), ("error", "angular error"),
        ("uncertainty", "expected error"), ("status", "status"),
        ("albedo", "albedo"), ("residual", "residual"), ("depth", "depth"), ("shaded", "depth, shaded"))


def prepare_compare_folder(out):
    """``out`` ready for a comparison: new, empty, or an earlier comparison; else refused, so
    that nothing of a user's is overwritten."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / MARK).is_file())):
        raise InputError(f"{out}: exists and is not an earlier comparison; choose a new or empty --out folder")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / MARK, "psrig report comparison\n")
    return out


def _labels(sessions):
    names = [s.root.name for s in sessions]
    if len(set(names)) < len(names):  # the same object processed twice: tell them by their parents
        names = [f"{s.root.parent.name}/{s.root.name}" for s in sessions]
    methods = [((s.stage("normals") or {}).get("params") or {}).get("method", "no normals") for s in sessions]
    differ = _differing_settings(sessions)
    return [f"{name} ({'; '.join([method] + extra)})" for name, method, extra in zip(names, methods, differ)]


def _differing_settings(sessions):
    """Per session, 'stage key=value' of the settings (as used) in which the sessions differ,
    but the normals method (in the label already): sessions that differ by --gamma must not
    look alike."""
    settings = [{f"{stage} {key}": format_value(value)
                 for stage in ("decode", "calibrate", "normals", "integrate")
                 for key, value in flatten(settings_used(stage, s.stage(stage)))
                 if not key.endswith("sha256") and f"{stage} {key}" != "normals method"}
                for s in sessions]
    keys = sorted({k for one in settings for k in one})
    varying = [k for k in keys if len({one.get(k) for one in settings}) > 1]
    return [[f"{k}={one.get(k, 'not set')}" for k in varying] for one in settings]


def _summary_table(sessions, labels, scores):
    rows = []
    for session, label, score in zip(sessions, labels, scores):
        normals = session.stage("normals") or {}
        settings = sections.settings_cell(normals.get("params")) if normals else "not run"
        counts = normals.get("status_counts") or {}
        total = sum(counts.values()) or 1
        shares = "<br>".join(f"{html.escape(k)} {html.escape(share_text(v, total))}" for k, v in counts.items() if v)
        n = score.get("normals") or {}
        error = (f"mean {n['mean_deg']:.2f}, median {n['median_deg']:.2f}, p90 {n['p90_deg']:.2f} deg"
                 if n else "no ground truth")
        lights = sections.lights_in_use(session)
        warned = len(sections.all_warnings(session, lights))
        rows.append([html.escape(label), settings, html.escape(sections.lights_origin(session, lights)),
                     shares, error, str(warned)])
    return html.table(["session", "normals settings", "lights", "status", "error vs truth", "warnings"], rows)


def compare_sessions(sessions, out, *, max_deg=ERROR_TOP_DEG):
    """Write the comparison page of ``sessions`` (opened Sessions) into ``out``.

    Returns
    -------
    Path
        ``out/index.html``.
    """
    if len(sessions) < 2:
        raise InputError("a comparison needs two sessions or more")
    out = prepare_compare_folder(out)
    labels = _labels(sessions)
    all_maps = [read_maps(s) for s in sessions]
    scales = choose_scales(all_maps, max_deg)

    def write(rel, rgb):
        write_image(out / rel, rgb, bits=8)
        return rel

    bars = bar_figures(scales, "bars", write)
    names, colours = _palette()
    columns = [{f.key: f for f in map_figures(maps, scales, f"s{i}", write, names, colours)}
               for i, maps in enumerate(all_maps)]
    scores = [evaluate_session(s, max_deg=max_deg, write=False) if s.manifest["truth"] else {} for s in sessions]
    body = [(None, f"<p>{len(sessions)} sessions on the same scales; written {html.escape(now_iso())}.</p>"),
            ("Sessions", _summary_table(sessions, labels, scores)),
            ("Maps", _maps_table(labels, columns, bars))]
    charts = sections.error_charts(list(zip(labels, all_maps)), scales["error"].top)
    if charts:
        body.append(("Errors against ground truth", charts))
    index = out / "index.html"
    atomic_write_text(index, html.page("psrig comparison: " + ", ".join(labels), body))
    return index


def _palette():
    from .stage import status_palette

    return status_palette()


def _maps_table(labels, columns, bars):
    rows = []
    for key, heading in ROWS:
        cells = [col.get(key) for col in columns]
        if not any(cells):
            continue
        first = next(c for c in cells if c is not None)
        row = [f"<b>{html.escape(heading)}</b>{html.colour_bar(first.scale, bars, base='')}"]
        row += [html.figure(c, {}, base="") if c is not None else "not there" for c in cells]
        rows.append(row)
    return html.table([""] + labels, rows, css="compare")
