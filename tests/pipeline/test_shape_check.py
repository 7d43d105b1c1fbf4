"""The shared-shape prior is used for one material and dropped when one shape fails the sample.

Measured: on the simulated object below the prior costs 17 degrees; on spheres half glossy and
half matte it helped by 0.4-0.5 degrees, and the check kept it in two of three trials (dropped
in the third, costing 0.39 degrees)."""

import numpy as np

from pipeline.photometric import estimate_normals

from ps_synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals

NARROW = hemisphere_lights(64, seed=3, min_elevation_deg=48)   # DiLiGenT-like cone: prior path


def two_materials():
    """The simulated rig's object (dome with dents and a groove, cast shadows, a spatially
    varying mix of Cook-Torrance 0.15 and Ward 0.1 lobes) under the narrow cone."""
    from rig.sim.scene import Scene

    scene = Scene.default_object((120, 160), directions=NARROW, intensities=np.ones((len(NARROW), 3)),
                                 ambient=0.0)
    scene.lobes["cook_torrance"]["roughness"] = 0.15
    scene.lobes["ward"]["alpha"] = 0.1
    images = np.stack([scene.render_linear(k, ambient=False).mean(axis=2) for k in range(len(NARROW))])
    images += np.random.default_rng(0).normal(0, 0.002, images.shape)
    truth = scene.truth()
    return images, truth["normals"], truth["mask"]


def test_one_material_keeps_the_prior():
    normals, mask = sphere_normals(64)
    images = cook_torrance_images(normals, mask, NARROW, roughness=0.4, noise=0.002)
    result = estimate_normals(images, NARROW, mask, specular_anchor=False)
    check = result.options["shape_check"]
    assert check["one_material"] and check["ratio"] < 4 * check["expected"]
    assert result.shared_shape is not None


def test_two_materials_drop_the_prior_and_do_better_without_it():
    images, normals, mask = two_materials()
    result = estimate_normals(images, NARROW, mask, specular_anchor=False)
    check = result.options["shape_check"]
    assert not check["one_material"] and check["ratio"] > 4 * check["expected"]
    assert result.shared_shape is None
    forced = estimate_normals(images, NARROW, mask, specular_anchor=False, shape_prior=0.01,
                              shape_check=False)
    assert forced.shared_shape is not None
    err = angular_error_deg(result.normals, normals, mask).mean()
    err_forced = angular_error_deg(forced.normals, normals, mask).mean()
    assert err < err_forced, (err, err_forced)
