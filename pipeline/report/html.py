"""HTML of the report pages: one self-contained page with relative links only.

Building blocks (each returns a string): :func:`table`, :func:`figure` (a picture with its
colour bar and legend beside it), :func:`figures`, :func:`warnings_box`, :func:`details`;
:func:`page` puts sections together with the style and the scripts.
"""

import html

__all__ = ["page", "table", "figure", "figures", "colour_bar", "warnings_box", "details", "href", "escape"]

escape = html.escape

_STYLE = """
body { font-family: sans-serif; margin: 1.5em; color: #222; max-width: 1400px; }
h2 { border-bottom: 1px solid #ddd; padding-bottom: 0.2em; margin-top: 1.6em; }
figure { display: inline-flex; margin: 0.4em; vertical-align: top; gap: 0.4em; }
figure .picture { text-align: center; }
figure img { max-width: 320px; border: 1px solid #ccc; }
figure.thumb img { max-width: 160px; }
figcaption { font-size: 0.8em; max-width: 320px; }
.bar { display: flex; flex-direction: column; align-items: center; font-size: 0.75em; }
.bar img { width: 14px; height: 200px; max-width: none; border: 1px solid #999; }
.legend { font-size: 0.8em; align-self: center; }
.swatch { display: inline-block; width: 1em; height: 1em; margin-right: 0.3em; border: 1px solid #999;
          vertical-align: middle; }
table { border-collapse: collapse; margin: 0.5em 0; }
td, th { border: 1px solid #ccc; padding: 0.2em 0.6em; text-align: left; font-size: 0.85em; vertical-align: top; }
th { background: #f4f4f4; }
code { font-size: 0.85em; }
.warnings { background: #fff4e5; border: 1px solid #f0b060; padding: 0.5em 1em; }
.warnings li { margin: 0.2em 0; }
.ok { color: #2a7a2a; }
.flag { color: #c0392b; }
.scores { display: flex; flex-wrap: wrap; gap: 0 2em; align-items: flex-start; }
.charts svg { margin: 0.3em 1em 0.3em 0; vertical-align: top; }
canvas.psrig-mesh { border: 1px solid #ccc; background: #f4f4f4; cursor: grab; touch-action: none; }
details summary { cursor: pointer; font-weight: bold; margin: 0.4em 0; }
.compare td { text-align: center; }
"""


def href(rel, base="report/"):
    """A link relative to the page's folder for a session-relative ``rel`` under ``base``."""
    return html.escape(rel[len(base):] if rel.startswith(base) else rel, quote=True)


def table(header, rows, css=""):
    """A table; ``rows`` hold HTML already (escape text cells before)."""
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>" for row in rows)
    cls = f' class="{css}"' if css else ""
    return f"<table{cls}><tr>{head}</tr>{body}</table>"


def colour_bar(scale, bars, base="report/"):
    """A colour bar with the top value above it and the bottom value below ("" without one)."""
    if scale is None or scale.name not in bars:
        return ""
    return (f'<div class="bar"><span>&ge; {html.escape(scale.label(scale.top))}</span>'
            f'<img src="{href(bars[scale.name], base)}" alt="colour bar {html.escape(scale.name)}">'
            f"<span>{'&le; ' if scale.bottom else ''}{html.escape(scale.label(scale.bottom))}</span></div>")


def figure(fig, bars, base="report/", css=""):
    """A picture with its caption, and beside it its colour bar (top value at the top) or legend."""
    src = href(fig.rel, base)
    legend = f'<div class="legend">{fig.legend}</div>' if fig.legend else ""
    return (f'<figure class="{css}"><div class="picture"><a href="{src}"><img src="{src}" '
            f'alt="{html.escape(fig.caption)}"></a><figcaption>{html.escape(fig.caption)}</figcaption></div>'
            f"{colour_bar(fig.scale, bars, base)}{legend}</figure>")


def figures(figs, bars=None, base="report/", css=""):
    return "\n".join(figure(f, bars or {}, base, css) for f in figs)


def warnings_box(found):
    """Every stage's warnings ([(stage, text)]), or a line saying there are none."""
    if not found:
        return '<p class="ok">No stage recorded a warning.</p>'
    items = "".join(f"<li><b>{html.escape(stage)}</b>: {html.escape(text)}</li>" for stage, text in found)
    return f'<div class="warnings"><b>{len(found)} warning(s)</b><ul>{items}</ul></div>'


def details(summary, body, open_=False):
    return f"<details{' open' if open_ else ''}><summary>{html.escape(summary)}</summary>{body}</details>"


def page(title, sections, scripts=()):
    """The whole page: ``sections`` [(heading or None, html)], ``scripts`` relative file names."""
    parts = [f"<h1>{html.escape(title)}</h1>"]
    for heading, body in sections:
        if heading:
            parts.append(f"<h2>{html.escape(heading)}</h2>")
        parts.append(body)
    tags = "".join(f'<script src="{html.escape(s, quote=True)}"></script>' for s in scripts)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>\n"
            + "\n".join(parts) + f"\n{tags}\n</body></html>\n")
