"""The sections of one session's report page, in page order.

Each function takes the session (and what was already read) and returns HTML; pictures are
written through ``write(rel, rgb)``. :func:`session_sections` assembles them.
"""

from ..evaluate import lights_imported
from ..core.lightsio import read_lights, read_lights_yaml
from ..core.paths import LIGHTS
from ..photometric.uncertainty import agreement_text
from ..core.session import STAGES
from .charts import error_by_observations, error_histogram
from .details import flatten, format_value, record_rows, settings_used, stage_warnings
from .html import details, escape, table
from .lights import hemisphere_svg, light_rows

__all__ = ["lights_in_use", "lights_origin", "header", "stages_table", "scores_section", "charts_section",
           "error_charts", "settings_cell",
           "lights_section", "details_section", "mesh_section", "all_warnings"]


def lights_in_use(session):
    """A LightSet of the lights the normals use (``calibration/lights.yaml``), or None."""
    path = session.path(LIGHTS)
    return read_lights_yaml(path) if path.is_file() else None


def lights_origin(session, lights):
    """Where the lights in use came from: the lights file's own account, not the manifest's
    ``lights.source`` (which stays 'nominal' after a calibration)."""
    if lights is None:
        recorded = session.manifest.get("lights", {}).get("source")
        return f"none yet (the manifest records {recorded!r} lights; run psrig calibrate)" if recorded else "none yet"
    origin = lights.source or "calibration/lights.yaml (no source recorded)"
    if lights_imported(session):
        origin = f"imported with the data ({origin})"
    flagged = f"; {len(lights.flags)} of {len(lights)} flagged and left out" if lights.flags else ""
    return f"{len(lights)} lights, {origin}{flagged}"


def header(session, lights, now):
    normals = session.stage("normals") or {}
    method = (normals.get("params") or {}).get("method", "not run")
    return (f"<p>Session <code>{escape(str(session.root.resolve()))}</code>: {len(session.frames())} frames; "
            f"<b>lights</b>: {escape(lights_origin(session, lights))}; <b>normals</b>: {escape(str(method))}; "
            f"report written {escape(now)}.</p>")


def all_warnings(session, lights):
    """[(stage, text)]: every record's warnings, and each flagged light (it is left out)."""
    found = stage_warnings(session, STAGES)
    if lights is not None:
        found += [("lights", f"light {k} flagged and left out: {why}") for k, why in sorted(lights.flags.items())]
    return found


def settings_cell(params):
    """A stage's settings (``params``), one ``key = value`` per line ('defaults' when none)."""
    rows = [f"<code>{escape(k)} = {escape(format_value(v))}</code>" for k, v in flatten(params or {})
            if not k.startswith("stages")]
    return "<br>".join(rows) or "defaults"


#: per stage, the record entries that say what the stage decided (its rule, its checks'
#: verdicts), shown beside its settings; every entry is in the stage records below
OUTCOMES = {
    "decode": ("compression", "subtracted.kind", "transfer_decision.message"),
    "calibrate": ("light_model", "flagged"),
    "normals": ("selection", "shared_shape_check", "specular_anchor", "lights_left_out", "uncertainty"),
    "integrate": ("mesh.unit", "mesh.faces_left_out_at_jumps"),
}


def _outcomes(name, record):
    wanted = OUTCOMES.get(name, ())
    rows = [f"<code>{escape(k)} = {escape(format_value(v) if v not in ({}, []) else 'none')}</code>"
            for k, v in flatten(record) if any(k == w or k.startswith(w + ".") for w in wanted)]
    return "<br>".join(rows)


def stages_table(session):
    rows = []
    for name in STAGES:
        record = session.stage(name)
        if record is None:
            # the report's own record is written after this page; a session without sphere
            # frames keeps its imported lights (what psrig run calls "up to date (kept)")
            kept = name == "calibrate" and not session.frames("sphere") and session.path(LIGHTS).is_file()
            rows.append([name, "this page" if name == "report" else "up to date (kept)" if kept else "not run",
                         "", "", "", escape(f"no sphere frames: the imported {LIGHTS} is kept") if kept else "",
                         ""])
            continue
        seconds = record.get("seconds")
        warned = len(record.get("warnings") or [])
        rows.append([name, escape(str(record.get("status", "ok"))), "" if seconds is None else f"{seconds:.2f} s",
                     escape(str(record.get("finished", ""))), settings_cell(settings_used(name, record)),
                     _outcomes(name, record), f'<span class="flag">{warned}</span>' if warned else "0"])
    return table(["stage", "status", "time", "finished", "settings", "outcome", "warnings"], rows)


def _value(v, key=""):
    if isinstance(v, float) and (key.startswith("under_") or key == "coverage"):
        return f"{v:.1%}"  # shares of the pixels
    return f"{v:.4g}" if isinstance(v, float) else escape(format_value(v))


#: depth scores that are lengths, in the ground truth's unit
_DEPTH_LENGTHS = ("mean_abs", "median_abs", "rms")


def scores_section(scores):
    parts = []
    if "normals" in scores:
        rows = [[escape(k), _value(v, k) if k != "uncertainty" else escape(agreement_text(v))]
                for k, v in scores["normals"].items() if k != "error_map"]
        parts.append("<h3>Normals against ground truth (degrees)</h3>" + table(["metric", "value"], rows))
    if "lights" in scores:
        lt = scores["lights"]
        if lt.get("evaluated") is False:
            parts.append(f"<h3>Light directions</h3><p>Imported, not evaluated: {escape(lt['reason'])}.</p>")
        else:
            rows = [[escape(k), _value(v)] for k, v in flatten(lt) if k != "per_light_deg"]
            parts.append("<h3>Light directions against ground truth (degrees)</h3>" + table(["metric", "value"], rows))
    if "depth" in scores:
        # the errors are in the ground truth's unit (the estimate is fitted to it)
        rows = [[escape(k + (" (ground truth's unit)" if k in _DEPTH_LENGTHS else "")), _value(v)]
                for k, v in scores["depth"].items()]
        parts.append("<h3>Depth against ground truth</h3>" + table(["metric", "value"], rows))
    return '<div class="scores">' + "\n".join(f"<div>{p}</div>" for p in parts) + "</div>"


def charts_section(maps, scale):
    """One session's error charts (:func:`error_charts`)."""
    return error_charts([("errors", maps)], scale.top)


def error_charts(series, top):
    """The error histogram, and the error against the lit observations and against the ones
    used, for ``series`` [(label, SessionMaps)] with errors and those maps ('' when none has
    errors)."""
    errors = [(label, maps.errors) for label, maps in series if maps.errors is not None]
    if not errors:
        return ""
    charts = [error_histogram(errors, top)]
    for counted in ("lit", "used"):
        counts = [(label, maps.errors, maps.lit if counted == "lit" else maps.observations)
                  for label, maps in series if maps.errors is not None]
        counts = [(label, e, c) for label, e, c in counts if c is not None and c.shape == e.shape]
        if counts:
            charts.append(error_by_observations(counts, top, counted))
    return f'<div class="charts">{"".join(charts)}</div>'


def lights_section(session, lights, scores):
    if lights is None:
        return "<p>No lights yet.</p>"
    truth = session.truth("lights")
    true_dirs = read_lights(truth).directions if truth is not None and truth.is_file() else None
    if lights_imported(session):
        true_dirs = None  # the same lights: nothing to draw apart
    frames = {f["light"]: f["id"] for f in session.stage_frames("object") if f.get("light") is not None}
    errors = (scores.get("lights") or {}).get("per_light_deg")
    header_, rows = light_rows(lights, frames, errors)
    return (f'<div class="charts">{hemisphere_svg(lights, true_dirs)}</div>'
            + table(header_, rows))


def details_section(session):
    parts = []
    for name in STAGES:
        record = session.stage(name)
        if record is None:
            continue
        rows = [[kind, f"<code>{key}</code>", value] for kind, key, value in record_rows(record)]
        warned = record.get("warnings") or []
        body = table(["", "key", "value"], rows)
        if warned:
            body += "<p>Warnings:</p><ul>" + "".join(f"<li>{escape(str(w))}</li>" for w in warned) + "</ul>"
        parts.append(details(f"{name}: {len(rows)} entries" + (f", {len(warned)} warning(s)" if warned else ""),
                             body, open_=name == "normals"))
    return "\n".join(parts)


def mesh_section(key, payload, record):
    """The 3-D view's canvas and controls; the scripts are added to the page."""
    mesh = (record or {}).get("mesh") or {}
    unit = mesh.get("unit", "px")
    note = (f"The integrated surface, every {payload['step']} pixel(s) a vertex "
            f"(the full mesh, {mesh.get('vertices', '?')} vertices in {escape(str(unit))}, is depth/mesh.ply "
            f"and depth/mesh.obj); shading from the photometric normals under a headlight.")
    return (f'<p>{note}</p><canvas id="view-{key}" class="psrig-mesh" data-mesh="{key}" width="560" height="420" '
            f'tabindex="0" aria-label="3-D view of the mesh"></canvas>'
            f'<p><button type="button" id="view-{key}-reset">reset view</button> '
            f'<label><input type="checkbox" id="view-{key}-colour"> albedo colour</label></p>'
            f'<p id="view-{key}-note"><noscript>The 3-D view needs JavaScript.</noscript></p>')

