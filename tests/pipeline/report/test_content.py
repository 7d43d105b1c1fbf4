"""What the report tells: stated scales with colour bars, one status palette with names and
shares, every stage's warnings and record, where the lights came from, the lights plot and
table, the error charts."""

import re

import numpy as np

from pipeline import runner
from pipeline.core.imageio import read_image, write_image
from pipeline.core.lightsio import read_lights_yaml, write_lights_yaml
from pipeline.core.paths import LIGHTS, LIT_OBSERVATIONS, OBSERVATIONS, STATUS_MAP
from pipeline.photometric import STATUS, STATUS_NAMES
from pipeline.photometric.methods import STATUS_PALETTE
from pipeline.report import report_session
from pipeline.report.images import Scale, colour_bar, colour_map
from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session


def page(session, **options):
    report_session(session, force=True, **options)
    return session.path("report/index.html").read_text(encoding="utf-8")


def test_false_colour_maps_have_stated_fixed_scales_and_colour_bars(processed):
    text = page(processed)
    for name in ("error", "residual", "depth"):
        assert f'src="maps/bar_{name}.png"' in text or name == "residual"
    assert "&ge; 30 deg" in text and "0 deg" in text
    bar = read_image(processed.path("report/maps/bar_error.png"))
    assert bar.shape[0] > bar.shape[1]  # upright, top value at the top: the top row is the top colour
    top = colour_map(np.array([[30.0]]), Scale("error", 0, 30))[0, 0] / 255
    np.testing.assert_allclose(bar[0, 0], top, atol=1 / 255)
    # the same errors on another session's scale read the same: the top is fixed, not per image
    assert "&ge; 12 deg" in page(processed, max_deg=12.0)


def test_colour_bar_runs_from_the_top_value_down():
    scale = Scale("x", 0.0, 10.0)
    bar = colour_bar(scale, height=5, width=2)
    np.testing.assert_array_equal(bar[0, 0], colour_map(np.array([[10.0]]), scale)[0, 0])
    np.testing.assert_array_equal(bar[-1, 0], colour_map(np.array([[0.0]]), scale)[0, 0])


def test_status_legend_names_shares_and_the_one_palette_even_for_a_new_code(processed):
    codes = np.zeros((40, 40), np.uint8)
    codes[5:25, 5:35] = STATUS["ok"]
    codes[25:35, 5:35] = STATUS["lambert_fallback"]
    codes[35:38, 5:35] = 9  # a status the report does not know yet
    write_image(processed.path(STATUS_MAP), codes, bits=8)
    text = page(processed)
    assert "code 0" not in text and "code 1 " not in text
    inside = 20 * 30 + 10 * 30 + 3 * 30
    assert f"ok {600 / inside:.1%}" in text and f"lambert_fallback {300 / inside:.1%}" in text
    assert f"code 9 {90 / inside:.1%}" in text
    assert f"background: rgb{STATUS_PALETTE['lambert_fallback']}" in text
    drawn = np.round(read_image(processed.path("report/maps/status.png"))[30, 10] * 255).astype(int)
    assert tuple(drawn) == STATUS_PALETTE[STATUS_NAMES[STATUS["lambert_fallback"]]]


def test_every_stage_warning_and_record_key_is_shown(processed):
    record = processed.stage("normals")
    record["warnings"] = ["one material assumed: the check could not tell <two>"]
    record["selection"] = {"rule": "robust", "reject_k": 2.5, "t_shadow": 0.1}
    record["specular_anchor"] = {"anchor": "on", "mismatch_deg": 1.25}
    processed.save()
    text = page(processed)
    assert "one material assumed: the check could not tell &lt;two&gt;" in text
    assert re.search(r"<b>normals</b>: one material assumed", text)
    for key in ("selection.rule", "selection.reject_k", "specular_anchor.mismatch_deg"):
        assert f"<code>{key}</code>" in text
    assert "1.25" in text and "robust" in text
    # the stages table gives the rule and the verdicts beside the settings, not only the method
    stages = text.split("<h2>Stages</h2>")[1].split("<h2>")[0]
    assert "<code>selection.rule = robust</code>" in stages and "<code>specular_anchor.anchor = on</code>" in stages


def test_header_names_the_lights_in_use_not_the_manifest_source(processed):
    processed.manifest["lights"]["source"] = "nominal"
    processed.save()
    lights = read_lights_yaml(processed.path(LIGHTS))
    lights.source = "chrome sphere calibration (test)"
    lights.flags = {3: "highlight clipped"}
    write_lights_yaml(processed.path(LIGHTS), lights)
    text = page(processed)
    header = text[text.index("<p>Session"):text.index("</p>", text.index("<p>Session"))]
    assert "chrome sphere calibration (test)" in header and "nominal" not in header
    assert "1 of 8 flagged" in header
    assert "light 3 flagged and left out: highlight clipped" in text  # in the warnings too
    svg = text[text.index('<svg class="hemisphere"'):text.index("</svg>", text.index('<svg class="hemisphere"'))]
    assert svg.count("<circle") >= 8 + 3 and 'stroke="#d62728"' in svg  # one dot per light, rings, a red cross
    assert '<span class="flag">highlight clipped</span>' in text


def test_imported_lights_are_said_to_be_imported(processed):
    assert processed.manifest["lights"]["source"] == "imported"  # as the importer left it
    write_lights_yaml(processed.path("truth/lights.yaml"), read_lights_yaml(processed.path(LIGHTS)))
    processed.set_truth("lights", "truth/lights.yaml")
    text = page(processed)
    assert "imported with the data" in text and "Imported, not evaluated" in text


def test_error_histogram_and_error_against_observations(processed):
    text = page(processed)
    assert "angular error histogram" in text and "observations used" not in text  # the stub writes no counts
    counts = np.where(read_image(processed.path("normals/mask.png"))[:, :, 0] > 0.5, 6, 0).astype(np.uint16)
    counts[:, 20:] = np.where(counts[:, 20:], 8, 0)
    write_image(processed.path(OBSERVATIONS), counts, bits=16)
    text = page(processed)
    assert "angular error against the observations used" in text and "lit observations" not in text
    # where the light reached each pixel, beside what the fit used (issue 21)
    write_image(processed.path(LIT_OBSERVATIONS), counts + np.uint16(2) * (counts > 0), bits=16)
    text = page(processed)
    assert "angular error against the lit observations (above the shadow threshold)" in text
    assert "angular error against the observations used" in text


def test_a_session_with_frames_only_still_reports(tmp_path, monkeypatch):
    session = make_session(tmp_path, "early")
    runner.run_session(session.root, stop="decode")
    text = page(Session.open(session.root))
    assert "Frames: object (8)" in text and 'class="psrig-mesh"' not in text and "not run" in text


def test_the_3d_view_of_a_perspective_mesh(processed):
    from pipeline.integrate import integrate_session

    K = np.array([[60.0, 0, 20], [0, 60.0, 20], [0, 0, 1]])
    integrate_session(processed, K=K, force=True)
    text = page(processed)
    assert 'data-mesh="depth"' in text and "up to scale" in text
    script = processed.path("report/mesh_depth.js").read_text()
    assert '"faces": ' in script and '"vertices": ' in script
