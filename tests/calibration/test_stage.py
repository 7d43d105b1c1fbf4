"""The calibrate stage on 8-bit sphere frames: circles found on the values the camera wrote."""

import numpy as np
import pytest
import yaml

from calibration.sphere import calibrate_sphere
from pipeline.cli import main
from pipeline.core.gamma import encode_gamma
from pipeline.core.errors import InputError
from pipeline.core.imageio import read_image, write_image
from pipeline.core.session import Session
from tests.calibration.sim_session import linear_frames, sphere_scene


def _circles(kinds):
    return np.array(sorted((k["cx"], k["cy"], k["r"]) for k in kinds))


def test_8_bit_sphere_frames_are_searched_on_their_encoded_values(tmp_path):
    scene = sphere_scene(6)
    images, _ = linear_frames(scene)
    folder = tmp_path / "jpegs"
    folder.mkdir()
    for k, image in enumerate(images):
        write_image(folder / f"f{k}.png", encode_gamma(image, "srgb"), bits=8)
    root = tmp_path / "s"
    glob = str(folder / "f*.png")
    assert main(["import", "images", str(root), "--object", glob, "--sphere", glob]) == 0
    assert main(["decode", str(root)]) == 0
    assert main(["calibrate", str(root)]) == 0
    got = _circles(yaml.safe_load(Session.open(root).path("calibration/lights.yaml").read_text())["spheres"])
    codes = np.stack([read_image(p) for p in sorted(folder.glob("f*.png"), key=lambda p: int(p.stem[1:]))])
    on_codes = _circles(calibrate_sphere(codes).kinds)
    assert np.allclose(got, on_codes, atol=2e-3), (got, on_codes)
    # the linear values give other circles: the test tells the two scales apart
    session = Session.open(root)
    linear = np.stack([read_image(session.linear_path(f))
                       for f in sorted(session.frames("sphere"), key=lambda f: f["light"])])
    assert np.abs(_circles(calibrate_sphere(linear).kinds) - on_codes).max() > 0.02


def test_edge_frames_of_another_shape_are_refused():
    images, _ = linear_frames(sphere_scene(6))
    with pytest.raises(InputError, match=r"edge frames: shape \(5, "):
        calibrate_sphere(images, edge_frames=images[:5])
