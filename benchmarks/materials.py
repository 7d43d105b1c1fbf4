"""One material or two under a narrow light cone: the single-material check and its fallback.

``python benchmarks/materials.py`` prints, for the simulated rig's two-material object (sharp
and broad lobes, noisy and noise-free) and for one-material Cook-Torrance spheres, all under a
DiLiGenT-like cone (64 lights, 48 degrees minimum elevation), the mean angular error (degrees)
of the default estimator (when the check fails, each pixel gets the Lambertian prior instead of
the shared shape), of the shared shape forced (``shape_check=False``), of the Lambertian prior
asked for (``shared_shape=False``) and of the paper's rule given explicitly (``t_low=0.35``,
Lambertian prior), with the check's verdict. The specular anchor is off so that only the
selection and the prior differ.
"""

from pathlib import Path

import numpy as np

from pipeline.photometric import estimate_normals
from pipeline.experiments.synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals

NARROW = hemisphere_lights(64, seed=3, min_elevation_deg=48)
RUNS = (("default", {}), ("shared shape", {"shape_check": False}), ("lambertian prior", {"shared_shape": False}),
        ("paper t_low 0.35", {"t_low": 0.35, "shared_shape": False}))


def two_materials(sharp, noise):
    """The simulated rig's object: a mix of Cook-Torrance and Ward lobes over the surface."""
    from rig.sim.scene import Scene

    scene = Scene.default_object((120, 160), directions=NARROW, intensities=np.ones((len(NARROW), 3)),
                                 ambient=0.0)
    if sharp:
        scene.lobes["cook_torrance"]["roughness"] = 0.15
        scene.lobes["ward"]["alpha"] = 0.1
    images = np.stack([scene.render_linear(k, ambient=False).mean(axis=2) for k in range(len(NARROW))])
    if noise:
        images += np.random.default_rng(0).normal(0, noise, images.shape)
    truth = scene.truth()
    return images, truth["normals"], truth["mask"]


def report(name, images, normals, mask):
    cells = []
    for label, options in RUNS:
        result = estimate_normals(images, NARROW, mask, specular_anchor=False, **options)
        cells.append(f"{label} {angular_error_deg(result.normals, normals, mask).mean():6.3f}")
        if label == "default":
            check = result.options.get("shape_check") or {}
            verdict = ("one material" if check.get("one_material") else
                       f"not one material ({check.get('fallback', 'no fallback')})")
    print(f"{name:40s} " + " | ".join(cells) + f" | check: {verdict}", flush=True)


def main():
    for sharp in (True, False):
        for noise in (0.002, 0.0):
            lobes = "sharp lobes" if sharp else "broad lobes"
            report(f"two materials, {lobes}, noise {noise:g}", *two_materials(sharp, noise))
    normals, mask = sphere_normals(64)
    for roughness in (0.1, 0.2, 0.4):
        for noise in (0.002, 0.0):
            images = cook_torrance_images(normals, mask, NARROW, roughness=roughness, noise=noise)
            report(f"one material, CT {roughness:g}, noise {noise:g}", images, normals, mask)


if __name__ == "__main__":
    main()
