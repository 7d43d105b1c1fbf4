"""HTML of the session report: a single self-contained page with relative links only."""

import html

from ..session import STAGES, now_iso

__all__ = ["render_page"]

_STYLE = """
body { font-family: sans-serif; margin: 1.5em; color: #222; }
figure { display: inline-block; margin: 0.3em; text-align: center; vertical-align: top; }
figure img { max-width: 320px; border: 1px solid #ccc; }
figure.thumb img { max-width: 160px; }
figcaption { font-size: 0.8em; }
table { border-collapse: collapse; margin: 0.5em 0; }
td, th { border: 1px solid #ccc; padding: 0.2em 0.6em; text-align: left; font-size: 0.9em; }
code { font-size: 0.85em; }
"""


def _href(rel):
    """Path relative to report/ of a session-relative path inside report/."""
    return html.escape(rel[len("report/"):] if rel.startswith("report/") else rel, quote=True)


def _figures(figures, css=""):
    items = []
    for rel, caption in figures:
        src = _href(rel)
        items.append(f'<figure class="{css}"><a href="{src}"><img src="{src}" alt="{html.escape(caption)}">'
                     f"</a><figcaption>{html.escape(caption)}</figcaption></figure>")
    return "\n".join(items)


def _table(header, rows):
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _settings(params):
    return "<br>".join(f"<code>{html.escape(str(k))} = {html.escape(str(v))}</code>"
                       for k, v in (params or {}).items() if k != "stages") or "defaults"


def _stages_table(session):
    rows = []
    for name in STAGES:
        record = session.stage(name)
        if record is None:
            rows.append([name, "not run", "", "", ""])
            continue
        seconds = record.get("seconds")
        rows.append([name, html.escape(str(record.get("status", "ok"))),
                     "" if seconds is None else f"{seconds:.2f} s",
                     html.escape(str(record.get("finished", ""))), _settings(record.get("params"))])
    return _table(["stage", "status", "time", "finished", "settings"], rows)


def _scores_html(scores):
    parts = []
    if "normals" in scores:
        n = scores["normals"]
        rows = [[html.escape(k), f"{v:.4g}" if isinstance(v, float) else html.escape(str(v))]
                for k, v in n.items() if k not in ("error_map",)]
        parts.append("<h3>Normals against ground truth (degrees)</h3>" + _table(["metric", "value"], rows))
    if "lights" in scores:
        lt = scores["lights"]
        rows = [[k, f"{lt[k]:.4f}"] for k in ("mean_deg", "median_deg", "max_deg")]
        rows.append(["worst light", str(lt["worst_light"])])
        parts.append("<h3>Light directions against ground truth (degrees)</h3>" + _table(["metric", "value"], rows))
    if "depth" in scores:
        d = scores["depth"]
        rows = [[html.escape(k), f"{v:.4g}" if isinstance(v, float) else html.escape(str(v))]
                for k, v in d.items()]
        parts.append("<h3>Depth against ground truth</h3>" + _table(["metric", "value"], rows))
    return "\n".join(parts)


def _legend(legend, names):
    """Colour swatches of the status codes, named when the normals stage recorded names."""
    if not legend:
        return ""
    names = names if isinstance(names, dict) else {}
    swatches = "".join(f'<span style="background: rgb{rgb}; padding: 0 1em; margin-right: 0.3em">'
                       f"</span>{html.escape(str(names.get(code, names.get(str(code), f'code {code}'))))} "
                       for code, rgb in legend.items())
    return f"<p>Status map: {swatches}</p>"


def render_page(session, sections, scores):
    """The report page as a string.

    Parameters
    ----------
    session : Session
    sections : dict
        ``frames`` [(kind, [(rel, caption)])], ``calibration`` and ``maps`` [(rel, caption)],
        ``legend`` {status code: (r, g, b)}; rel are session-relative paths inside report/.
    scores : dict
        The result of :func:`pipeline.evaluate.evaluate_session` (may be empty).
    """
    title = html.escape(f"psrig report: {session.root.name}")
    lights = session.manifest.get("lights", {})
    body = [f"<h1>{title}</h1>",
            f"<p>Session <code>{html.escape(str(session.root.resolve()))}</code>, "
            f"{len(session.frames())} frames, lights: {html.escape(str(lights.get('source', 'calibrated')))}; "
            f"report written {now_iso()}.</p>",
            "<h2>Stages</h2>", _stages_table(session)]
    if scores:
        body += ["<h2>Errors against ground truth</h2>", _scores_html(scores)]
    body += ["<h2>Results</h2>", _figures(sections["maps"]), _legend(sections["legend"], (session.stage("normals") or {}).get("status_codes"))]
    if sections["calibration"]:
        body += ["<h2>Calibration</h2>", _figures(sections["calibration"])]
    for kind, figures in sections["frames"]:
        body += [f"<h2>Frames: {html.escape(kind)} ({len(figures)})</h2>", _figures(figures, "thumb")]
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{title}</title><style>{_STYLE}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")
