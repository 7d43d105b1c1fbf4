"""The bivariate table model rho(theta_h, theta_d), phi_d averaged (paper Fig. 5's comparison),
and its place in psrig reflectometry and psrig experiments reflectometry."""

import numpy as np

from pipeline.cli import main
from pipeline.experiments import reflectometry as exp
from pipeline.reflectance import Geometry
from pipeline.reflectance.bivariate import BivariateTable


def test_a_brdf_of_theta_h_and_theta_d_only_is_tabulated_closely():
    def material(g):
        return (0.3 + 2.0 * np.asarray(g.nh) ** 8 * (1.0 + 0.5 * np.asarray(g.lh)))[..., None]

    table = BivariateTable.from_material(material)
    assert table.n_params == 8100 and table.table.shape == (90, 90, 1)
    rng = np.random.default_rng(1)
    nh, lh = rng.uniform(0.2, 1.0, 500), rng.uniform(0.3, 1.0, 500)
    geometry = Geometry(nl=np.full(500, 0.5), nv=np.full(500, 0.5), nh=nh, lh=lh, lv=2 * lh ** 2 - 1)
    assert np.abs(table.evaluate(geometry)[:, 0] - material(geometry)[:, 0]).max() < 0.02


def test_a_brdf_that_varies_with_phi_d_is_averaged_over_it():
    # n.l - n.v is odd in phi_d: its average over phi_d is 0
    table = BivariateTable.from_material(lambda g: (1.0 + np.asarray(g.nl) - np.asarray(g.nv))[..., None])
    inner = table.table[:45, :45, 0]
    assert np.allclose(inner, 1.0, atol=1e-9)


def test_reflectometry_of_a_simulated_sphere_has_the_bivariate_row_with_its_parameters():
    material, _ = exp.parse_material("cook-torrance:0.5")
    image, normals, mask = exp.simulate_sphere(material, size=48)
    results, _ = exp.reflectometry(image, normals, mask, exp.DEFAULT_LIGHT, material=material)
    mae = {name: r[2] for name, r in results.items()}
    assert mae["bivariate"] < mae["biquadratic"] < mae["lambert"]
    table = exp.reflectometry_table(results, "test", image).to_markdown()
    rows = {line.split("|")[1].strip(): line.split("|")[4].strip() for line in table.splitlines()
            if line.startswith("| ") and "---" not in line}
    assert rows["bivariate"] == "8100" and rows["biquadratic"] == "9" and rows["lambert"] == "1"
    # a user's image: no material, no bivariate row, and the note says why
    results, _ = exp.reflectometry(image, normals, mask, exp.DEFAULT_LIGHT)
    assert "bivariate" not in results
    assert "known only for a simulated sphere" in exp.reflectometry_table(results, "test", image).to_markdown()


def test_experiments_reflectometry_compares_the_models_over_the_materials(tmp_path, capsys):
    out = tmp_path / "fig5"
    assert main(["experiments", "reflectometry", "--roughness", "0.5,0.7", "--size", "40", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "bivariate (8100 params) MAE" in printed and "biquadratic (9 params) MAE" in printed
    assert "lambert (1 params) MAE" in printed
    rows = (out / "table.csv").read_text().splitlines()
    assert len(rows) == 1 + 4 + 2 and (out / "figure.png").is_file()
    assert main(["experiments", "reflectometry", "--roughness", "2", "--out", str(out)]) == 1
