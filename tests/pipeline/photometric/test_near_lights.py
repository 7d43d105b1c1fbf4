"""Near point lights: per-pixel directions and falloff in photometric stereo."""

import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.photometric import PointLights
from pipeline.photometric import estimate_normals


def _scene(distance=150.0, shape=(64, 80), k=12):
    """A Lambertian hemisphere-normal field on the plane z = 0 under point lights."""
    h, w = shape
    rows, cols = np.mgrid[0:h, 0:w]
    x, y = cols - (w - 1) / 2.0, (h - 1) / 2.0 - rows
    r = 0.45 * min(h, w)
    d2 = (x * x + y * y) / (r * r)
    mask = d2 < 0.8
    nz = np.sqrt(np.clip(1 - d2, 0, None))
    normals = np.where(mask[..., None], np.stack([x / r, y / r, nz], -1), 0.0)
    angles = np.linspace(0, 2 * np.pi, k, endpoint=False)
    tilt = np.radians(np.where(np.arange(k) % 2, 30.0, 50.0))
    dirs = np.stack([np.sin(tilt) * np.cos(angles), np.sin(tilt) * np.sin(angles), np.cos(tilt)], 1)
    lights = PointLights(dirs * distance, shape)
    flat = np.flatnonzero(np.ones(shape, bool))
    per_pixel, falloff = lights.at(flat)
    shading = np.einsum("nkc,nc->nk", per_pixel, normals.reshape(-1, 3)) * falloff
    images = (0.8 * np.clip(shading, 0, None)).T.reshape(k, h, w)
    return images.astype(np.float32), lights, mask, normals


def _mean_error(result, normals, mask):
    cos = np.clip(np.sum(result.normals * normals, axis=-1), -1, 1)
    return float(np.degrees(np.arccos(cos[mask])).mean())


def test_point_lights_recover_normals_that_directions_get_wrong():
    images, lights, mask, normals = _scene()
    near = estimate_normals(images, lights, mask, method="lambert-low")
    far = estimate_normals(images, lights.central_directions, mask, method="lambert-low")
    assert _mean_error(near, normals, mask) < 0.05
    assert _mean_error(far, normals, mask) > 2.0


def test_point_lights_with_the_biquadratic_method():
    images, lights, mask, normals = _scene()
    result = estimate_normals(images, lights, mask)
    assert _mean_error(result, normals, mask) < 0.5


def test_falloff_is_one_at_the_origin_and_directions_are_unit():
    lights = PointLights([[0, 0, 100.0], [50, 0, 100], [0, 50, 100]], (5, 5))
    directions, falloff = lights.at([12])  # the centre pixel of a 5 x 5 image
    assert np.allclose(falloff, 1.0)
    assert np.allclose(np.linalg.norm(directions, axis=-1), 1.0)
    assert np.allclose(directions[0], lights.central_directions)


def test_bad_point_lights_are_named():
    images, lights, mask, _ = _scene()
    with pytest.raises(InputError, match="light positions for"):
        estimate_normals(images[:5], lights, mask[:, :])
    with pytest.raises(InputError, match="near lights are for images"):
        estimate_normals(images[:, :32], lights, mask[:32])
    with pytest.raises(InputError, match="not finite"):
        PointLights([[0, 0, np.nan]] * 3, (4, 4))


def test_normals_stage_uses_calibrated_positions(tmp_path):
    """A session whose lights.yaml has positions: the stage's near model beats directions."""
    from pipeline.decode import decode_session
    from pipeline.core.imageio import read_image, write_image, write_mask
    from pipeline.importers import import_images
    from pipeline.core.lightsio import LightSet, read_lights_yaml, write_lights_yaml
    from pipeline.photometric import normals_session

    images, lights, mask, normals = _scene()
    src = tmp_path / "src"
    src.mkdir()
    for k, image in enumerate(images):
        write_image(src / f"img{k:02d}.png", np.repeat(image[..., None], 3, axis=2))
    write_mask(src / "mask.png", mask)
    (src / "lights.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in lights.central_directions))
    session = import_images(tmp_path / "s", str(src / "img*.png"), mask=src / "mask.png",
                            lights=src / "lights.txt")
    decode_session(session)
    path = session.path("calibration/lights.yaml")
    base = read_lights_yaml(path)
    write_lights_yaml(path, LightSet(base.directions, base.intensities, positions=lights.positions,
                                     extra={"light_model": "near"}))
    errors = {}
    for model in ("near", "directional"):
        record = normals_session(session, method="lambert-low", lights_model=model, force=True,
                                 show_progress=False)
        assert record["light_model"] == model
        estimated = read_image(session.path("normals/normals.exr"))
        cos = np.clip(np.sum(estimated * normals, axis=-1), -1, 1)
        errors[model] = float(np.degrees(np.arccos(cos[mask])).mean())
    assert errors["near"] < 0.3 < 2.0 < errors["directional"]
