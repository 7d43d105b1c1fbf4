"""Small SVG charts drawn inline in the report (no image files, no scripts): the angular-error
histogram and the error against the number of observations, for one session or several.

Each function returns an ``<svg>`` string; axes carry ticks and units, and every series is
named in a legend when there are several.
"""

import html

import numpy as np

__all__ = ["Chart", "error_histogram", "error_by_observations", "SERIES_COLOURS"]

#: line colours of the series of a comparison (matplotlib's tab10, as hex)
SERIES_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


def _nice_ticks(low, high, count=5):
    """Round tick values covering low .. high."""
    span = max(high - low, 1e-12)
    raw = span / count
    step = 10 ** np.floor(np.log10(raw))
    step *= min((m for m in (1, 2, 2.5, 5, 10) if m * step >= raw), default=10)
    return np.arange(np.ceil(low / step) * step, high + step * 1e-9, step)


class Chart:
    """An SVG plot area: data coordinates ``x`` .. and ``y`` .. mapped into a width x height
    box with margins for the axes."""

    def __init__(self, x_range, y_range, width=420, height=240, x_label="", y_label=""):
        self.x0, self.x1 = x_range
        self.y0, self.y1 = y_range
        self.width, self.height = width, height
        self.left, self.right, self.top, self.bottom = 52, 12, 14, 40
        self.parts = []
        self.entries = []
        self.x_label, self.y_label = x_label, y_label

    def px(self, x):
        span = max(self.x1 - self.x0, 1e-12)
        return self.left + (np.asarray(x, float) - self.x0) / span * (self.width - self.left - self.right)

    def py(self, y):
        span = max(self.y1 - self.y0, 1e-12)
        return self.height - self.bottom - (np.asarray(y, float) - self.y0) / span * (
            self.height - self.top - self.bottom)

    def bars(self, lefts, rights, heights, colour, title=None):
        for a, b, h in zip(lefts, rights, heights):
            if h <= 0:
                continue
            x, y = self.px(a), self.py(h)
            tip = f"<title>{html.escape(title(a, b, h))}</title>" if title else ""
            self.parts.append(f'<rect x="{x:.1f}" y="{y:.1f}" width="{max(self.px(b) - x - 0.5, 0.5):.1f}" '
                              f'height="{self.py(self.y0) - y:.1f}" fill="{colour}">{tip}</rect>')

    def line(self, xs, ys, colour, dots=False, dash=None):
        good = np.isfinite(np.asarray(ys, float))
        points = " ".join(f"{self.px(x):.1f},{self.py(y):.1f}" for x, y, g in zip(xs, ys, good) if g)
        style = f' stroke-dasharray="{dash}"' if dash else ""
        self.parts.append(f'<polyline points="{points}" fill="none" stroke="{colour}" stroke-width="1.6"{style}/>')
        if dots:
            self.parts += [f'<circle cx="{self.px(x):.1f}" cy="{self.py(y):.1f}" r="2.2" fill="{colour}"/>'
                           for x, y, g in zip(xs, ys, good) if g]

    def marks(self, xs, ys, colour, top, what):
        """Up-pointing triangles at the top of the axis where ``ys`` exceed ``top`` (drawn
        clipped), each with its value as a tooltip."""
        for x, y in zip(xs, ys):
            if np.isfinite(y) and y > top:
                px, py = self.px(x), self.py(top)
                self.parts.append(f'<path d="M{px - 3.5:.1f},{py + 5:.1f} L{px + 3.5:.1f},{py + 5:.1f} L{px:.1f},'
                                  f'{py - 1:.1f} Z" fill="{colour}"><title>{html.escape(what)} at {x:g}: {y:.1f} deg '
                                  f'(above the axis)</title></path>')

    def legend(self, entries):
        """entries: [(label, colour, style)], listed under the plot (long labels fit there);
        style False: solid line, True: dashed, 'bar': a filled box, 'mark': a triangle."""
        self.entries = list(entries)

    def svg(self, title):
        axes = [f'<line x1="{self.left}" y1="{self.py(self.y0):.1f}" x2="{self.width - self.right}" '
                f'y2="{self.py(self.y0):.1f}" stroke="#333"/>',
                f'<line x1="{self.left}" y1="{self.top}" x2="{self.left}" y2="{self.py(self.y0):.1f}" stroke="#333"/>']
        for t in _nice_ticks(self.x0, self.x1):
            axes.append(f'<text x="{self.px(t):.1f}" y="{self.height - self.bottom + 14}" '
                        f'text-anchor="middle">{t:g}</text>')
        for t in _nice_ticks(self.y0, self.y1, 4):
            axes.append(f'<text x="{self.left - 4}" y="{self.py(t) + 4:.1f}" text-anchor="end">{t:g}</text>'
                        f'<line x1="{self.left}" y1="{self.py(t):.1f}" x2="{self.width - self.right}" '
                        f'y2="{self.py(t):.1f}" stroke="#ddd"/>')
        axes.append(f'<text x="{(self.left + self.width - self.right) / 2:.0f}" y="{self.height - 6}" '
                    f'text-anchor="middle">{html.escape(self.x_label)}</text>')
        axes.append(f'<text transform="translate(12,{(self.top + self.height - self.bottom) / 2:.0f}) rotate(-90)" '
                    f'text-anchor="middle">{html.escape(self.y_label)}</text>')
        for i, (label, colour, dash) in enumerate(self.entries):
            y = self.height + 12 + 14 * i
            if dash == "bar":
                sample = f'<rect x="{self.left + 3}" y="{y - 9}" width="12" height="9" fill="{colour}"/>'
            elif dash == "mark":
                sample = (f'<path d="M{self.left + 5:.1f},{y:.1f} L{self.left + 13:.1f},{y:.1f} L{self.left + 9:.1f},'
                          f'{y - 8:.1f} Z" fill="{colour}"/>')
            else:
                style = ' stroke-dasharray="4,3"' if dash else ""
                sample = (f'<line x1="{self.left}" y1="{y - 4}" x2="{self.left + 18}" y2="{y - 4}" stroke="{colour}" '
                          f'stroke-width="2"{style}/>')
            axes.append(f'{sample}<text x="{self.left + 24}" y="{y}">{html.escape(label)}</text>')
        height = self.height + (14 * len(self.entries) + 14 if self.entries else 0)
        return (f'<svg class="chart" xmlns="http://www.w3.org/2000/svg" width="{self.width}" '
                f'height="{height}" viewBox="0 0 {self.width} {height}" role="img" '
                f'font-size="10" font-family="sans-serif"><title>{html.escape(title)}</title>'
                + "".join(axes) + "".join(self.parts) + "</svg>")


def _histogram(errors, top, bins):
    values = np.asarray(errors, float)
    values = values[np.isfinite(values)]
    edges = np.linspace(0, top, bins + 1)
    counts = np.histogram(np.minimum(values, top), edges)[0].astype(float)
    over = float(np.sum(values > top))
    counts[-1] -= over  # the clipped ones are the overflow bar, not the last bin
    total = max(values.size, 1)
    return edges, counts / total * 100, over / total * 100


def error_histogram(series, top, bins=30):
    """Histogram of angular errors (share of pixels per bin), 0 .. ``top`` degrees plus one bar
    of the errors above ``top``.

    Parameters
    ----------
    series : list of (label, errors)
        ``errors`` (any shape, NaN ignored) in degrees; one series is drawn as bars, several as
        lines on the same axes.
    top : float
        Degrees; the same for every session compared.
    """
    hists = [(label, *_histogram(errors, top, bins)) for label, errors in series]
    width = top / bins
    peak = max([h.max() for _, _, h, _ in hists] + [o for *_, o in hists] + [1e-9])
    chart = Chart((0, top + 2 * width), (0, peak * 1.1), x_label=f"angular error (deg); last bar: > {top:g}",
                  y_label="pixels (%)")
    if len(hists) == 1:
        _, edges, shares, over = hists[0]
        chart.bars(edges[:-1], edges[1:], shares, "#4c72b0",
                   title=lambda a, b, h: f"{a:g}-{b:g} deg: {h:.2f} % of the pixels")
        chart.bars([top + width], [top + 2 * width], [over], "#c44e52",
                   title=lambda a, b, h: f"above {top:g} deg: {h:.2f} % of the pixels")
    else:
        for (label, edges, shares, over), colour in zip(hists, SERIES_COLOURS):
            centres = (edges[:-1] + edges[1:]) / 2
            chart.line(list(centres) + [top + 1.5 * width], list(shares) + [over], colour, dots=True)
        chart.legend([(label, colour, False) for (label, *_), colour in zip(hists, SERIES_COLOURS)])
    return chart.svg("angular error histogram")


def _by_count(errors, counts):
    errors, counts = np.asarray(errors, float).ravel(), np.asarray(counts).ravel()
    good = np.isfinite(errors) & (counts > 0)
    levels = np.unique(counts[good])
    mean = np.array([errors[good & (counts == n)].mean() for n in levels])
    median = np.array([np.median(errors[good & (counts == n)]) for n in levels])
    pixels = np.array([np.sum(good & (counts == n)) for n in levels])
    return levels, mean, median, pixels


#: what an observation count counts: its axis label
COUNTED = {"used": "observations used by the fit", "lit": "lit observations (above the shadow threshold)"}


def error_by_observations(series, top, counted="used"):
    """Mean (solid) and median (dashed) angular error against a per-pixel observation count,
    with the share of pixels at each count as grey bars (one series).

    Parameters
    ----------
    series : list of (label, errors (H, W), counts (H, W) int)
    top : float
        Degrees at the top of the error axis (larger means are drawn at the top).
    counted : {'used', 'lit'}
        What the counts are (:data:`COUNTED`): the observations the fit used, or the pixel's
        observations above the shadow threshold (where the light reached it).
    """
    data = [(label, *_by_count(e, c)) for label, e, c in series]
    data = [d for d in data if len(d[1])]
    if not data:
        return ""
    high = max(d[1].max() for d in data)
    chart = Chart((0, high + 1), (0, top), x_label=COUNTED[counted], y_label="angular error (deg)")
    bar_entry = []
    if len(data) == 1:
        _, levels, mean, median, pixels = data[0]
        share = pixels / pixels.sum()
        # the bars have no axis of their own: the tallest is drawn at 90 % of the plot's height
        scale = top * 0.9 / max(share.max(), 1e-12)
        chart.bars(levels - 0.4, levels + 0.4, share * scale, "#e4e4e4",
                   title=lambda a, b, h: f"{(a + b) / 2:.0f} observations: {100 * h / scale:.2f} % of the pixels")
        bar_entry = [(f"pixels at each count (grey bars, not on the degree axis: the tallest is "
                      f"{100 * share.max():.1f} % of the pixels)", "#c8c8c8", "bar")]
    entries, clipped = [], False
    for (label, levels, mean, median, pixels), colour in zip(data, SERIES_COLOURS):
        chart.line(levels, np.minimum(mean, top), colour, dots=True)
        chart.line(levels, np.minimum(median, top), colour, dash="4,3")
        chart.marks(levels, mean, colour, top, f"{label} mean")
        chart.marks(levels, median, colour, top, f"{label} median")
        clipped |= bool(np.any(mean > top) or np.any(median > top))
        entries += [(f"{label} mean", colour, False), (f"{label} median", colour, True)]
    if len(data) == 1:
        entries = [("mean", SERIES_COLOURS[0], False), ("median", SERIES_COLOURS[0], True)]
    if clipped:
        entries.append((f"above {top:g} deg: drawn at the top (hover for the value)", "#555", "mark"))
    chart.legend(entries + bar_entry)
    return chart.svg(f"angular error against the {COUNTED[counted]}")
