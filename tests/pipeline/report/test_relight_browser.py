"""The report's relighting view in a real browser (headless Chromium): the canvas read back after
psrigRelight.setLight at three directions matches the fitted model evaluated in numpy
(pipeline.relight.shade), in WebGL and in the 2-D canvas fallback; dragging (mouse and touch)
moves the light."""

import base64
import io

import numpy as np
import pytest
from PIL import Image

from pipeline.cli import main
from pipeline.experiments.synthetic import cook_torrance_images, hemisphere_lights, sphere_normals
from pipeline.core.gamma import encode_gamma
from pipeline.relight import read_model, shade
from pipeline.core.session import Session
from tests.pipeline.photometric.ps_synthetic import import_stack
from tests.pipeline.report.browser import chromium_path, open_page

DIRECTIONS = ((0.0, 0.0, 1.0), (0.5, 0.3, 0.81), (-0.6, -0.2, 0.77))


@pytest.fixture(scope="module")
def glossy_report(tmp_path_factory):
    """A glossy sphere (Cook-Torrance, 40 lights) run through psrig to its report, its normals
    fitted on every non-shadowed observation (--t-low 1: the default selection leaves the lobe
    out and fits a nearly Lambertian rho, which would not exercise the coefficients; no shape prior:
    each pixel its own coefficients)."""
    chromium_path()
    folder = tmp_path_factory.mktemp("relight")
    normals, mask = sphere_normals(72)
    lights = hemisphere_lights(40, seed=5, min_elevation_deg=25)
    images = 0.8 * cook_torrance_images(normals, mask, lights, roughness=0.35)
    root = str(import_stack(folder, "glossy", np.clip(images, 0, 1), mask, lights))
    assert main(["run", root, "-q"]) == 0
    assert main(["normals", root, "--t-low", "1", "--shape-prior", "0", "--force", "--holdout-folds", "0"]) == 0
    assert main(["report", root]) == 0
    return Session.open(root)


def canvas_rgb(page):
    """The relighting canvas read back (toDataURL): (h, w, 3) uint8, the grid's own pixels."""
    url = page.evaluate("() => document.querySelector('canvas.psrig-relight').toDataURL('image/png')")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB")).astype(int)


def expected_rgb(model, light, white, mode="model"):
    """The model evaluated in numpy, displayed as the view displays it (sRGB of value / white)."""
    inside = model.mask
    value = shade(model.normals[inside], model.coefficients[inside], model.albedo[inside], light, mode)
    gain = 1.0 if mode == "normals" else 1.0 / white
    return np.round(encode_gamma(value * gain, "srgb") * 255).astype(int)


@pytest.mark.parametrize("renderer", ["default", "canvas2d"])
def test_the_relit_canvas_matches_the_model_in_numpy(glossy_report, renderer):
    session = glossy_report
    model = read_model(session)
    assert model.method == "biquadratic"
    # the fit's coefficients are not Lambert's: the test exercises rho
    assert np.abs(model.coefficients[model.mask][:, :8]).mean() > 0.05
    url = session.path("report/index.html").resolve().as_uri() + ("#canvas2d" if renderer == "canvas2d" else "")
    with open_page(url) as (page, problems):
        page.wait_for_selector("canvas.psrig-relight[data-drawn='1']", timeout=20000)
        used = page.eval_on_selector("canvas.psrig-relight", "c => c.dataset.renderer")
        assert used in ("webgl", "canvas2d") and (renderer == "default" or used == "canvas2d")
        data = page.evaluate("() => { const d = window.PSRIG_RELIGHT.model; return [d.step, d.white]; }")
        grid = model.grid(int(data[0]))
        for mode in ("model", "diffuse", "normals"):
            page.evaluate(f"() => window.psrigRelight.setMode('{mode}')")
            for light in DIRECTIONS if mode == "model" else DIRECTIONS[1:2]:
                page.evaluate(f"() => window.psrigRelight.setLight({light[0]}, {light[1]}, {light[2]})")
                got = canvas_rgb(page)
                assert got.shape[:2] == grid.mask.shape
                want = expected_rgb(grid, light, data[1], mode)
                difference = np.abs(got[grid.mask] - want).mean() / 255
                assert difference < 0.02, f"{used} {mode} {light}: mean abs difference {difference:.2%} of white"
                assert want.std() > 10   # a picture with contrast, not a flat field
            readout = page.inner_text(f"#relight-model-readout")
            assert "light (" in readout and "nearest captured" in readout
        assert problems == [], problems


def test_dragging_moves_the_light_with_mouse_and_touch(glossy_report):
    url = glossy_report.path("report/index.html").resolve().as_uri()
    with open_page(url) as (page, problems):
        page.wait_for_selector("canvas.psrig-relight[data-drawn='1']", timeout=20000)
        broken = page.eval_on_selector_all("img", "imgs => imgs.filter(i => !i.complete || !i.naturalWidth)"
                                                  ".map(i => i.src)")
        assert broken == []   # the hidden nearest-frame picture too
        dome = page.locator("#relight-model-dome")
        dome.scroll_into_view_if_needed()
        box = dome.bounding_box()
        before = page.evaluate("() => window.psrigRelight.views.model.light")
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.down()
        page.mouse.move(box["x"] + box["width"] * 0.85, box["y"] + box["height"] / 2, steps=5)
        page.mouse.up()
        after = page.evaluate("() => window.psrigRelight.views.model.light")
        assert after[0] > 0.5 and abs(after[1]) < 0.1 and after != before
        # a finger on the image: pointer events of type touch
        page.evaluate("""() => {
            const c = document.querySelector('canvas.psrig-relight'), b = c.getBoundingClientRect();
            const at = (x, y, type) => c.dispatchEvent(new PointerEvent(type, {clientX: b.left + x * b.width,
                clientY: b.top + y * b.height, pointerType: 'touch', pointerId: 7, bubbles: true}));
            at(0.5, 0.5, 'pointerdown'); at(0.5, 0.2, 'pointermove'); at(0.5, 0.2, 'pointerup');
        }""")
        touched = page.evaluate("() => window.psrigRelight.views.model.light")
        assert touched[1] > 0.4 and abs(touched[0]) < 0.1
        page.evaluate("() => window.psrigRelight.setMode('frame')")
        assert page.locator("#relight-model-frame").is_visible()
        assert page.evaluate("() => document.getElementById('relight-model-frame').complete && "
                             "document.getElementById('relight-model-frame').naturalWidth > 0")
        assert problems == [], problems
