"""The demo's report in a real browser (headless Chromium): no console error, every picture
loads, and the 3-D view draws the mesh (WebGL, and the 2-D canvas fallback), rotates and zooms."""

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.core.imageio import read_image
from tests.pipeline.report.browser import chromium_path, open_page

BACKGROUND = np.array([244, 244, 244])


@pytest.fixture(scope="module")
def demo_report(tmp_path_factory):
    chromium_path()  # skip (or fail under CI) before the demo's minute of work
    folder = tmp_path_factory.mktemp("browser") / "demo"
    assert main(["demo", str(folder)]) == 0
    return folder / "report" / "index.html"


def canvas_pixels(page, path):
    """RGB (h, w, 3) of a screenshot of the 3-D view's canvas."""
    page.locator("canvas.psrig-mesh").screenshot(path=str(path))
    return np.round(read_image(path)[:, :, :3] * 255).astype(int)


def drawn_share(rgb):
    """Share of the canvas that is not background: the mesh."""
    return float(np.mean(np.abs(rgb - BACKGROUND).max(axis=2) > 12))


@pytest.mark.slow
@pytest.mark.parametrize("renderer", ["default", "canvas2d"])
def test_demo_report_loads_without_error_and_the_3d_view_draws(demo_report, tmp_path, renderer):
    url = demo_report.resolve().as_uri() + ("#canvas2d" if renderer == "canvas2d" else "")
    with open_page(url) as (page, problems):
        page.wait_for_selector("canvas.psrig-mesh[data-drawn='1']", timeout=20000)
        used = page.eval_on_selector("canvas.psrig-mesh", "c => c.dataset.renderer")
        assert used in ("webgl", "canvas2d") and (renderer == "default" or used == "canvas2d")
        broken = page.eval_on_selector_all("img", "imgs => imgs.filter(i => !i.complete || !i.naturalWidth)"
                                                  ".map(i => i.src)")
        assert broken == []
        front = canvas_pixels(page, tmp_path / "front.png")
        assert drawn_share(front) > 0.2, f"{used}: the 3-D view drew too little"
        h, w = front.shape[:2]
        assert np.abs(front[h // 2, w // 2] - BACKGROUND).max() > 12  # the mesh is centred
        box = page.locator("canvas.psrig-mesh").bounding_box()
        page.mouse.move(box["x"] + 100, box["y"] + 200)
        page.mouse.down()
        page.mouse.move(box["x"] + 300, box["y"] + 120, steps=6)
        page.mouse.up()
        page.wait_for_timeout(200)
        turned = canvas_pixels(page, tmp_path / "turned.png")
        page.mouse.wheel(0, -400)
        page.wait_for_timeout(200)
        zoomed = canvas_pixels(page, tmp_path / "zoomed.png")
        assert np.abs(turned - front).max() > 50 and drawn_share(zoomed) > drawn_share(turned)
        assert problems == [], problems
