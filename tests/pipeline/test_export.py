"""psrig export SESSION --relight DIR: the files and relight.json are enough to evaluate the
model again (EXR and 16-bit PNG)."""

import json

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.core.imageio import read_image, read_mask
from pipeline.relight import read_model, shade
from pipeline.core.session import Session
from tests.pipeline.tiny_session import make_session


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    session = make_session(tmp_path_factory.mktemp("export"))
    assert main(["decode", str(session.root)]) == 0
    assert main(["normals", str(session.root), "--holdout-folds", "0"]) == 0
    return Session.open(session.root)


def evaluate(spec, normals, albedo, coefficients, light):
    """The JSON's formula, written out from its text: rho in the listed monomials."""
    light = np.asarray(light, float) / np.linalg.norm(light)
    h = light + [0.0, 0.0, 1.0]
    h /= np.linalg.norm(h)
    x, y = normals @ h, light @ h
    monomials = {"x^2 y^2": x * x * y * y, "x^2 y": x * x * y, "x^2": x * x, "x y^2": x * y * y, "x y": x * y,
                 "x": x, "y^2": y * y, "y": y, "1": np.ones_like(x)}
    rho = sum(coefficients[..., i] * monomials[c["monomial"]] for i, c in enumerate(spec["coefficients"]))
    return albedo * (rho * np.maximum(normals @ light, 0))[..., None]


def decode_png(entry, folder):
    codes = read_image(folder / entry["file"]).astype(np.float64)   # 0..1 = code / 65535
    return np.stack([c["offset"] + c["scale"] * codes[..., i] for i, c in enumerate(entry["codes"])], axis=-1)


@pytest.mark.parametrize("fmt", ["exr", "png"])
def test_the_export_evaluates_to_the_model(fitted, tmp_path, fmt, capsys):
    out = tmp_path / "relight"
    assert main(["export", str(fitted.root), "--relight", str(out), "--format", fmt]) == 0
    assert "relight.json" in capsys.readouterr().out
    spec = json.loads((out / "relight.json").read_text())
    model = read_model(fitted)
    assert (spec["height"], spec["width"]) == model.shape and spec["method"] == "biquadratic"
    mask = read_mask(out / spec["files"]["mask"]["file"])
    assert np.array_equal(mask, model.mask)
    files = spec["files"]
    if fmt == "exr":
        normals = read_image(out / files["normals"]["file"])
        albedo = read_image(out / files["albedo"]["file"])
        coefficients = read_image(out / files["coefficients"]["file"])
    else:
        normals = 2 * read_image(out / files["normals"]["file"]).astype(np.float64) - 1
        normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-12)
        albedo = decode_png(files["albedo"], out)
        coefficients = np.concatenate([decode_png(files[k], out) for k in
                                       ("coefficients_ABC", "coefficients_DEF", "coefficients_GHI")], axis=2)
    light = (0.2, -0.4, 0.89)
    got = evaluate(spec, normals[mask], albedo[mask], coefficients[mask], light)
    want = shade(model.normals[mask], model.coefficients[mask], model.albedo[mask], light)
    tolerance = 1e-6 if fmt == "exr" else 2e-3
    assert np.abs(got - want).max() <= tolerance * max(want.max(), 1e-9)
    example = spec["example"]
    r, c = example["pixel_row_col"]
    again = evaluate(spec, np.array(example["normal"]), np.array(example["albedo_rgb"]),
                     np.array(example["coefficients_A_to_I"]), example["light"])
    assert np.allclose(again, example["image_rgb"], atol=1e-6) and mask[r, c]


def test_export_is_refused_inside_the_session_and_without_relight(fitted, capsys):
    assert main(["export", str(fitted.root), "--relight", str(fitted.path("normals"))]) == 1
    assert "inside the session" in capsys.readouterr().err
    assert main(["export", str(fitted.root)]) == 1
    assert "--relight" in capsys.readouterr().err


def test_export_of_a_session_without_normals_names_the_file(tmp_path, capsys):
    session = make_session(tmp_path)
    assert main(["export", str(session.root), "--relight", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "normals.exr: missing" in err and "Traceback" not in err


@pytest.mark.parametrize("method", ["biquadratic-factorised", "bilinear"])
def test_fits_of_the_biquadratic_family_are_converted_to_the_nine_coefficients(tmp_path, method):
    from pipeline.reflectance import Geometry, get_model

    session = make_session(tmp_path)
    assert main(["decode", str(session.root)]) == 0
    assert main(["normals", str(session.root), "--method", method, "--holdout-folds", "0"]) == 0
    session = Session.open(session.root)
    model = read_model(session)
    assert model.family == "biquadratic" and model.method == method
    mask = model.mask
    light = np.array([0.3, -0.2, 0.93])
    light /= np.linalg.norm(light)
    params = read_image(session.path("normals/brdf.exr"))[mask].astype(np.float64)
    n = model.normals[mask].astype(np.float64)
    geometry = Geometry.from_vectors(n, light[None])
    # the method's own model: rho carries the albedo (the paper's alternation)
    want = get_model(method).evaluate(params, geometry)[:, 0] * np.maximum(n @ light, 0)
    got = shade(n, model.coefficients[mask], model.albedo[mask], light).mean(axis=1)
    assert np.abs(got - want).max() < 1e-4 * max(np.abs(want).max(), 1e-9)
