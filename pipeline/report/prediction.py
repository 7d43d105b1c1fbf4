"""The report's held-out-light section: how well each model predicts frames it was not fitted to.

Reads ``normals/prediction.yaml`` and ``normals/prediction.exr`` (the normals stage's
:mod:`pipeline.photometric.prediction`) and shows the overall errors, a chart and a table of
every light's error for the biquadratic and the Lambertian fit, and the worst light's captured
frame, both predictions and the biquadratic's difference on the sample grid.
"""

import html as _html

import numpy as np

from ..core.errors import InputError
from ..core.imageio import read_image
from ..core.paths import PREDICTION_IMAGES
from ..photometric.prediction import prediction_line, read_prediction
from . import html
from .charts import SERIES_COLOURS, Chart
from .images import Scale, colour_bar, colour_map, robust_max, tone_map
from .maps import Figure

__all__ = ["prediction_section", "DIFFERENCE_TOP_PCT"]

#: the difference map's scale: -top .. +top percent of the captured frame's white
DIFFERENCE_TOP_PCT = 20.0


def prediction_section(session, write):
    """HTML of the section (a paragraph saying why when there is nothing to show)."""
    try:
        found = read_prediction(session)
    except InputError as err:   # the rest of the report is still worth writing
        return f"<p>Held-out-light prediction not shown: {_html.escape(str(err))}</p>"
    if found is None:
        return ("<p>No held-out-light prediction: the normals stage ran with <code>--holdout-folds 0</code> "
                "or before psrig had the check (<code>psrig normals --force</code> runs it).</p>")
    if found.get("verdict") != "checked":
        return f"<p>{_html.escape(prediction_line(found))}.</p>"
    text = (f"<p><b>{_html.escape(prediction_line(found))}</b> (relative RMS error of the predicted frames "
            f"against the captured ones, over the lit, unsaturated pixels that both fits solved). The lights were "
            f"split into {found['folds']} folds; each fold's frames were predicted by fits to the other lights on "
            f"{found['pixels']} object pixels (every {found['stride']}-th pixel), by the biquadratic model and by "
            f"Lambertian least squares on the same selected observations ({_html.escape(found['lambert_method'])}). "
            "Both fits use the low-frequency observations (paper Sec. 5), so neither predicts sharp "
            "specular peaks: on a shiny object they dominate both errors.</p>")
    return text + _chart(found) + _worst(session, found, write) + _table(found)


def _chart(found):
    lights = found["lights"]
    xs = np.arange(len(lights))
    series = {name: np.array([np.nan if e[f"{name}_pct"] is None else e[f"{name}_pct"] for e in lights])
              for name in ("biquadratic", "lambert")}
    top = max(float(np.nanmax(np.concatenate(list(series.values())))), 1.0) * 1.05
    chart = Chart((0, max(len(lights) - 1, 1)), (0.0, top), width=560, x_label="light (the frames' order)",
                  y_label="held-out error, % RMS")
    for (name, values), colour in zip(series.items(), SERIES_COLOURS):
        chart.line(xs, values, colour, dots=True, dash="2,3")
    overall = found["overall"]
    chart.legend([(f"biquadratic ({overall['biquadratic_pct']:.1f} % overall)", SERIES_COLOURS[0], False),
                  (f"Lambert ({overall['lambert_pct']:.1f} % overall)", SERIES_COLOURS[1], False)])
    return f'<div class="charts">{chart.svg("held-out prediction error per light")}</div>'


def _worst(session, found, write):
    path = session.path(PREDICTION_IMAGES)
    if not path.is_file():
        return ""
    stack = read_image(path)
    captured, biquadratic, lambert = (stack[:, :, i] for i in range(3))
    white = robust_max(captured[captured > 0]) if (captured > 0).any() else 1.0
    worst = next(e for e in found["lights"] if e["frame"] == found["worst_light"])
    label = f"{found['worst_light']} (light {worst['light']})"
    scored = captured > 0
    difference = np.where(scored, 100.0 * (biquadratic - captured) / white, np.nan)
    scale = Scale("prediction_difference", -DIFFERENCE_TOP_PCT, DIFFERENCE_TOP_PCT, "%", "RdBu_r")
    bars = {scale.name: write("report/prediction/difference_bar.png", colour_bar(scale))}
    figs = [Figure(write("report/prediction/captured.png", _enlarge(tone_map(captured, white))), f"{label}: captured"),
            Figure(write("report/prediction/biquadratic.png", _enlarge(tone_map(biquadratic, white))),
                   f"biquadratic, fitted without it ({worst['biquadratic_pct']} % RMS)"),
            Figure(write("report/prediction/lambert.png", _enlarge(tone_map(lambert, white))),
                   f"Lambert, fitted without it ({worst['lambert_pct']} % RMS)"),
            Figure(write("report/prediction/difference.png", _enlarge(colour_map(difference, scale))),
                   "biquadratic - captured, % of the frame's white (black: not scored)", scale=scale)]
    return (f"<p>The biquadratic's worst-predicted light, {_html.escape(label)}, on the sample grid:</p>"
            + html.figures(figs, bars))


def _enlarge(rgb, side=320):
    """Nearest-neighbour enlargement of a small grid image so that it shows at a readable size."""
    factor = max(1, side // max(rgb.shape[:2]))
    return np.repeat(np.repeat(rgb, factor, axis=0), factor, axis=1) if factor > 1 else rgb


def _table(found):
    def cell(value):
        return "-" if value is None else f"{value:.2f}"

    rows = [[_html.escape(str(e["frame"])), str(e["light"]), str(e["fold"]), str(e["pixels"]),
             cell(e["biquadratic_pct"]), cell(e["lambert_pct"])] for e in found["lights"]]
    table = html.table(["frame", "light", "fold", "pixels scored", "biquadratic % RMS", "Lambert % RMS"], rows)
    return html.details(f"Every light ({len(rows)})", table)
