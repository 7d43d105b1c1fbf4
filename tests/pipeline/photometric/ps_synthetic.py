"""Test helpers on top of :mod:`pipeline.experiments.synthetic`: selected problems for the kernel
tests, row angles, and sessions imported from synthetic stacks."""

import numpy as np

from pipeline.experiments.synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals

__all__ = ["angular_error_deg", "cook_torrance_images", "hemisphere_lights", "sphere_normals", "selected_problem",
           "row_angles_deg", "import_stack"]


def selected_problem(size, count, seed, min_elevation_deg, roughness, noise):
    """A glossy sphere's observations selected as the biquadratic method does, for kernel tests.

    Returns (obs (N, K), weights (N, K), b (N, 3), lights (K, 3), h (K, 3), y (K,)) for the
    pixels with at least 12 selected observations.
    """
    from pipeline.photometric.model import half_vectors
    from pipeline.photometric.selection import resolve_selection, select_observations

    normals, mask = sphere_normals(size)
    lights = hemisphere_lights(count, seed=seed, min_elevation_deg=min_elevation_deg)
    images = cook_torrance_images(normals, mask, lights, roughness=roughness, noise=noise)
    obs = images[:, mask].T.astype(np.float64)
    _, weights, b = select_observations(obs, None, lights, **resolve_selection(lights, {}))
    keep = weights.sum(axis=1) >= 12
    h, y = half_vectors(lights)
    return obs[keep], weights[keep], b[keep], lights, h, y

def row_angles_deg(a, b):
    """Angles (deg) between the rows of a and b (N, 3), any lengths."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1, 1)))

def import_stack(folder, name, images, mask, lights):
    """A session ``folder/name`` imported from grey ``images`` (K, H, W) in 0..1 written as
    16-bit RGB PNGs, with the object ``mask`` and the light directions ``lights`` (K, 3)."""
    from pipeline.core.imageio import write_image, write_mask
    from pipeline.importers import import_images

    src = folder / f"{name}_src"
    src.mkdir(parents=True)
    for k, image in enumerate(images):
        write_image(src / f"img{k + 1:02d}.png", np.repeat(image[..., None], 3, axis=2))
    (src / "lights.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in lights))
    write_mask(src / "mask.png", mask)
    return import_images(folder / name, str(src / "img*.png"), mask=src / "mask.png",
                         lights=src / "lights.txt").root
