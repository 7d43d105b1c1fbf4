"""Tiny versions of every experiment: they run in seconds and write CSV, Markdown and PNG."""

import csv

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.experiments import cook_torrance as ct_exp
from pipeline.experiments import ps as ps_exp
from pipeline.experiments import reflectometry as refl
from pipeline.reflectance.merl import MERL_SHAPE, write_merl

from tests import SHARED_DATA

DILIGENT = SHARED_DATA / "diligent"
TINY = ["--longitudes", "6", "--altitudes", "5", "--lights", "30"]


def _outputs(folder):
    names = sorted(p.name for p in folder.iterdir())
    assert names == ["figure.png", "table.csv", "table.md"]
    assert (folder / "figure.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(folder / "table.csv", newline="") as fh:
        return list(csv.reader(fh))


def test_low_frequency_weights_keep_the_darkest_lit_fraction():
    radiance = np.array([[5.0, 1.0, 3.0, 2.0, 4.0, 0.5]])
    lit = np.array([[True, True, True, True, True, False]])
    weights = ct_exp.low_frequency_weights(radiance, lit, 0.4)
    np.testing.assert_array_equal(weights, [[0, 1, 0, 1, 0, 0]])


def test_protocol_geometry_matches_the_paper():
    normals, lights, geometry = ct_exp.protocol_geometry()
    assert normals.shape == (1620, 3) and lights.shape == (100, 3)
    assert np.all(normals[:, 2] > 0) and np.all(lights[:, 2] > 0)
    np.testing.assert_allclose(np.linalg.norm(lights, axis=1), 1.0)
    assert geometry.nl.shape == (1620, 100)


def test_cook_torrance_command(tmp_path, capsys):
    out = tmp_path / "ct"
    assert main(["experiments", "cook-torrance", "--roughness", "0.1,0.6", "--t-low", "0.25,1",
                 "--out", str(out)] + TINY) == 0
    rows = _outputs(out)
    assert rows[0] == ["model", "m", "T_low 25%", "T_low 100%"]
    mae = {(r[0], r[1]): [float(v) for v in r[2:]] for r in rows[1:]}
    # Sharp lobes leave pure Lambertian low-frequency samples: fitted almost exactly.
    assert mae[("biquadratic", "0.1")][0] < 1e-4
    # Keeping every sample (T_low 100 %) makes the fit worse than keeping the darkest quarter.
    assert mae[("biquadratic", "0.6")][1] > mae[("biquadratic", "0.6")][0]
    assert "Fig. 2" in capsys.readouterr().out


def test_cook_torrance_is_deterministic():
    args = dict(n_longitudes=4, n_altitudes=3, n_lights=20)
    first = ct_exp.cook_torrance_grid((0.3,), (0.5,), **args)
    np.testing.assert_array_equal(first, ct_exp.cook_torrance_grid((0.3,), (0.5,), **args))


def _merl_folder(tmp_path):
    """Two MERL files: a Lambertian one and one with a theta_h lobe (synthetic, not MERL data)."""
    folder = tmp_path / "merl"
    folder.mkdir()
    theta_h = (np.arange(90) + 0.5) ** 2 / 90 ** 2 * np.pi / 2
    lobe = np.exp(-np.tan(theta_h) ** 2 / 0.3 ** 2)[:, None, None]
    for name, table in (("flat", np.full(MERL_SHAPE, 0.1)), ("shiny", 0.1 + 2 * lobe + 0 * np.ones(MERL_SHAPE))):
        write_merl(folder / f"{name}.binary", np.stack([table, table * 0.5, table * 0.25]))
    return folder


def test_merl_and_models_commands(tmp_path):
    folder = _merl_folder(tmp_path)
    assert main(["experiments", "merl", str(folder), "--t-low", "0.25,1", "--out",
                 str(tmp_path / "m")] + TINY) == 0
    rows = _outputs(tmp_path / "m")
    flat = [r for r in rows[1:] if r[1] == "flat"]
    assert len(flat) == 2 and all(float(v) < 1e-6 for r in flat for v in r[2:])
    assert main(["experiments", "models", str(folder), "--roughness", "0.3", "--out",
                 str(tmp_path / "models")] + TINY) == 0
    rows = _outputs(tmp_path / "models")
    labels = [r[0] for r in rows[1:]]
    assert labels == ["cook-torrance m=0.3", "ward m=0.3", "flat", "shiny", "mean", "median"]
    header = rows[0]
    ct_row = rows[1]
    # A model fits its own renders (near) exactly.
    assert float(ct_row[header.index("Cook-Torrance")]) < 1e-6


def test_merl_command_names_a_bad_folder(tmp_path, capsys):
    assert main(["experiments", "merl", str(tmp_path)]) == 1
    assert "no MERL .binary files" in capsys.readouterr().err


def test_reflectometry_simulated_ranks_the_models(tmp_path):
    assert main(["reflectometry", "--simulate", "cook-torrance:0.6", "--size", "48", "--out",
                 str(tmp_path / "r")]) == 0
    rows = _outputs(tmp_path / "r")
    mae = {r[0]: float(r[1]) for r in rows[1:]}
    assert mae["biquadratic"] < mae["lafortune"] < mae["lambert"]


def test_reflectometry_on_a_user_image(tmp_path):
    from pipeline.core.imageio import write_image

    material, _ = refl.parse_material("ward:0.5")
    image, _, _ = refl.simulate_sphere(material, (0.2, 0.1, 0.97), size=40)
    write_image(tmp_path / "sphere.exr", image.astype(np.float32))
    assert main(["reflectometry", "--image", str(tmp_path / "sphere.exr"), "--light", "0.2,0.1,0.97",
                 "--circle", "19.5,19.5,19", "--out", str(tmp_path / "r")]) == 0
    rows = _outputs(tmp_path / "r")
    assert float(rows[1][1]) < float(rows[3][1])  # biquadratic below Lambert


def test_reflectometry_errors_name_the_option(capsys):
    assert main(["reflectometry", "--image", "x.exr", "--light", "0,0,1"]) == 1
    assert "--circle" in capsys.readouterr().err
    assert main(["reflectometry", "--simulate", "plastic"]) == 1
    assert "plastic" in capsys.readouterr().err


def test_alternating_normals_recover_a_biquadratic_surface():
    images, lights, truth, mask, _ = ps_exp.render_two_materials(size=24, n_lights=40)
    results = ps_exp.run_methods(images, lights, mask, truth, methods=ps_exp.PS_METHODS[:3],
                                 shadow=0.01, psrig_default=False)
    assert results["Lambert (low)"][0] < results["Lambert (all)"][0]
    assert results["biquadratic"][0] < 3.0


def test_ps_command_tiny(tmp_path):
    assert main(["experiments", "ps", "--size", "20", "--lights", "30", "--no-diligent", "--out",
                 str(tmp_path / "ps")]) == 0
    rows = _outputs(tmp_path / "ps")
    assert [r[0] for r in rows[1:]] == [label for label, _, _ in ps_exp.PS_METHODS] + [ps_exp.PSRIG_DEFAULT]
    assert all(np.isfinite(float(r[1])) for r in rows[1:])


@pytest.mark.slow
@pytest.mark.skipif(not (DILIGENT / "ballPNG").is_dir(), reason="DiLiGenT data not present")
def test_diligent_ball_lambert_baseline():
    results = ps_exp.run_diligent(DILIGENT / "ballPNG", methods=ps_exp.PS_METHODS[:1],
                                  psrig_default=False)
    assert abs(results["Lambert (all)"][0] - 4.10) < 0.3  # the published LS baseline


@pytest.mark.parametrize("method", ["cook-torrance", "ward", "lafortune", "biquadratic-factorised"])
def test_models_work_inside_estimate_normals(method):
    """psrig normals --method NAME runs the lead's alternation with these models' fit/evaluate."""
    from pipeline.photometric import estimate_normals

    images, lights, truth, mask, _ = ps_exp.render_two_materials(size=20, n_lights=40)
    result = estimate_normals(images.astype(np.float32), lights, mask, method, t_low=0.5)
    error = ps_exp.angular_error(result.normals[mask].astype(float), truth[mask])
    assert np.all(np.isfinite(result.normals))
    assert error.mean() < 10.0
