"""The lights panel: a hemisphere plot of the light directions and a table of every light.

The plot looks down the camera axis (x right, y up, as the image shows the scene): a light at
the centre shines along the view, one on the rim grazes; rings mark 30, 60 and 90 degrees from
the axis. Each light is a dot coloured by its intensity (mean over the colour channels), with
its index; flagged lights are crossed in red, true directions (when known) are hollow rings.

The table lists each light's frame, direction, angle from the axis and azimuth, intensity,
every per-light list ``lights.yaml`` holds (residuals, uncertainties, ... whatever the
calibration recorded), the error against the truth and the flag's reason.
"""

import html

import numpy as np

__all__ = ["hemisphere_svg", "light_rows", "LIGHT_HEADER"]

_SIZE = 300
_R = 125


def _viridis(values):
    from matplotlib import colormaps

    return ["#%02x%02x%02x" % tuple(int(255 * c + 0.5) for c in colormaps["viridis"](v)[:3]) for v in values]


def _labelled(dirs, flags, spacing=11.0):
    """Indices of the lights whose number is written beside their dot: flagged ones first,
    then each one whose label would not land within ``spacing`` plot units of one already
    written (96 lights' numbers overlap into a blot)."""
    points = np.stack([_R * dirs[:, 0], -_R * dirs[:, 1]], axis=1)
    order = sorted(range(len(dirs)), key=lambda k: (k not in flags, k))
    placed = []
    for k in order:
        if not placed or np.min(np.linalg.norm(points[placed] - points[k], axis=1)) >= spacing:
            placed.append(k)
    return set(placed)


def hemisphere_svg(lights, truth=None):
    """The hemisphere plot of a LightSet as an ``<svg>`` string.

    Parameters
    ----------
    lights : pipeline.core.lightsio.LightSet
    truth : ndarray (K, 3), optional
        True directions, drawn as hollow rings.
    """
    dirs = np.asarray(lights.directions, float)
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    strength = np.asarray(lights.intensities, float).reshape(len(dirs), -1).mean(axis=1)
    low, high = float(strength.min()), float(strength.max())
    colours = _viridis((strength - low) / (high - low) if high > low else np.full(len(dirs), 0.5))
    c = _SIZE / 2
    parts = []
    for angle in (30, 60, 90):
        radius = _R * np.sin(np.radians(angle))
        # ring labels on the lower-right diagonal, clear of the axes' labels
        parts.append(f'<circle cx="{c}" cy="{c}" r="{radius:.1f}" fill="none" stroke="#bbb"/>'
                     f'<text x="{c + 0.72 * radius:.1f}" y="{c + 0.72 * radius + 3:.1f}" fill="#888" '
                     f'font-size="8">{angle}&#176;</text>')
    parts.append(f'<line x1="{c - _R}" y1="{c}" x2="{c + _R}" y2="{c}" stroke="#ddd"/>'
                 f'<line x1="{c}" y1="{c - _R}" x2="{c}" y2="{c + _R}" stroke="#ddd"/>'
                 f'<text x="{c + _R + 4}" y="{c + 4}">x</text><text x="{c - 3}" y="{c - _R - 6}">y</text>')
    if truth is not None and len(truth) == len(dirs):
        t = np.asarray(truth, float)
        t = t / np.linalg.norm(t, axis=1, keepdims=True)
        parts += [f'<circle cx="{c + _R * x:.1f}" cy="{c - _R * y:.1f}" r="6.5" fill="none" stroke="#000" '
                  f'stroke-width="0.8"/>' for x, y, _ in t]
    labelled = _labelled(dirs, lights.flags)
    for k, ((x, y, z), colour) in enumerate(zip(dirs, colours)):
        px, py = c + _R * x, c - _R * y
        polar = np.degrees(np.arccos(np.clip(z, -1, 1)))
        why = lights.flags.get(k)
        tip = f"light {k}: ({x:.3f}, {y:.3f}, {z:.3f}), {polar:.1f} deg from the axis, intensity {strength[k]:.3g}"
        tip += f"; flagged: {why}" if why else ""
        parts.append(f'<g><title>{html.escape(tip)}</title><circle cx="{px:.1f}" cy="{py:.1f}" r="4.5" '
                     f'fill="{colour}" stroke="#222" stroke-width="0.5"/>'
                     + (f'<text x="{px + 5:.1f}" y="{py - 4:.1f}" font-size="8">{k}</text>' if k in labelled else "")
                     + "</g>")
        if why:
            parts.append(f'<path d="M{px - 7:.1f},{py - 7:.1f} L{px + 7:.1f},{py + 7:.1f} M{px - 7:.1f},'
                         f'{py + 7:.1f} L{px + 7:.1f},{py - 7:.1f}" stroke="#d62728" stroke-width="2"/>')
    stops = "".join(f'<stop offset="{i / 8:.3f}" stop-color="{col}"/>'
                    for i, col in enumerate(_viridis(np.linspace(0, 1, 9))))
    if high > low:
        legend = (f'<defs><linearGradient id="intensity">{stops}</linearGradient></defs>'
                  f'<rect x="20" y="{_SIZE + 6}" width="{_SIZE - 40}" height="9" fill="url(#intensity)"/>'
                  f'<text x="20" y="{_SIZE + 27}">{low:.3g}</text>'
                  f'<text x="{_SIZE - 20}" y="{_SIZE + 27}" text-anchor="end">{high:.3g}</text>'
                  f'<text x="{c}" y="{_SIZE + 27}" text-anchor="middle">intensity (mean of channels)</text>')
    else:   # one value: a bar from it to itself says nothing
        legend = (f'<rect x="20" y="{_SIZE + 6}" width="9" height="9" fill="{colours[0]}"/>'
                  f'<text x="34" y="{_SIZE + 14}">every light\'s intensity is {low:.3g} (mean of channels)</text>')
    unlabelled = len(dirs) - len(labelled)
    marks = (f'<text x="4" y="12">red cross: flagged ({len(lights.flags)})'
             + ("; ring: true direction" if truth is not None else "")
             + (f"; {unlabelled} crowded labels left out (hover a dot)" if unlabelled else "") + "</text>")
    return (f'<svg class="hemisphere" xmlns="http://www.w3.org/2000/svg" width="{_SIZE}" height="{_SIZE + 34}" '
            f'viewBox="0 0 {_SIZE} {_SIZE + 34}" font-size="10" font-family="sans-serif" role="img">'
            f"<title>light directions seen from the camera</title>{marks}" + "".join(parts) + legend + "</svg>")


#: per-light lists of lights.yaml in the unit of the light positions (``position_unit``)
_POSITION_KEYS = ("distance", "ray_miss")

#: the table's fixed columns (per-light lists of lights.yaml follow, then error and flag)
LIGHT_HEADER = ["light", "frame", "x", "y", "z", "from axis (deg)", "azimuth (deg)", "intensity"]


def light_rows(lights, frames, errors=None):
    """Header and rows (HTML-escaped cells) of the light table.

    Parameters
    ----------
    lights : LightSet
    frames : dict
        {light index: object frame id}.
    errors : list, optional
        Per-light angle against the truth (None for a light not scored).
    """
    count = len(lights)
    extra = {k: v for k, v in sorted(lights.extra.items())
             if isinstance(v, list) and len(v) == count and all(_scalar(x) for x in v)}
    unit = lights.extra.get("position_unit")
    named = [f"{key} ({unit})" if unit and key in _POSITION_KEYS else f"{key} (deg)" if key.endswith("_deg") else key
             for key in extra]
    header = LIGHT_HEADER + named + (["error vs truth (deg)"] if errors else []) + ["flag"]
    rows = []
    dirs = np.asarray(lights.directions, float)
    intensities = np.asarray(lights.intensities, float).reshape(count, -1)
    for k, (x, y, z) in enumerate(dirs):
        polar = np.degrees(np.arccos(np.clip(z / np.linalg.norm((x, y, z)), -1, 1)))
        azimuth = np.degrees(np.arctan2(y, x)) % 360
        cells = [str(k), html.escape(str(frames.get(k, ""))), f"{x:.4f}", f"{y:.4f}", f"{z:.4f}",
                 f"{polar:.2f}", f"{azimuth:.1f}", " / ".join(f"{v:.4g}" for v in intensities[k])]
        cells += [_cell(values[k]) for values in extra.values()]
        if errors:
            cells.append("" if errors[k] is None else f"{errors[k]:.3f}")
        why = lights.flags.get(k)
        cells.append(f'<span class="flag">{html.escape(why)}</span>' if why else "")
        rows.append(cells)
    return header, rows


def _scalar(value):
    return value is None or isinstance(value, (int, float, str, bool))


def _cell(value):
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape("" if value is None else str(value))
