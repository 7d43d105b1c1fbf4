"""Few lights over a wide dome, 8-bit frames: how many pixels get a normal, and how good.

    python benchmarks/dome_8bit.py [--counts 8,12,16] [--seeds 3] [--size 160]

The shared data has no wide-dome capture with few lights, so this renders one: a Cook-Torrance
sphere (roughness 0.3) under ``count`` random lights above 20 degrees elevation, scaled so its
99.5th percentile is at 90 % of white, with noise (0.004) and 8-bit rounding. Printed per light
count and seed: the share of the sphere's pixels without a normal (shadowed, too few, ill-posed)
and the mean angular error where the default gave one, the default's and plain Lambert's on the
same pixels (degrees).
"""

import argparse

import numpy as np

from pipeline.experiments.synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals
from pipeline.photometric import estimate_normals
from pipeline.photometric.engine import NO_NORMAL


def scene(count, seed, size):
    normals, mask = sphere_normals(size)
    lights = hemisphere_lights(count, seed=seed, min_elevation_deg=20)
    images = cook_torrance_images(normals, mask, lights, roughness=0.3)
    images = images / np.percentile(images[:, mask], 99.5) * 0.9
    noisy = images + np.random.default_rng(seed).normal(0, 0.004, images.shape)
    return normals, mask, lights, (np.round(np.clip(noisy, 0, 1) * 255) / 255).astype(np.float32)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--counts", default="8,12,16")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--size", type=int, default=160)
    args = parser.parse_args(argv)
    print(f"{'lights':>6} {'seed':>4} {'no normal':>9} {'default':>8} {'lambert':>8}")
    for count in map(int, args.counts.split(",")):
        for seed in range(args.seeds):
            normals, mask, lights, images = scene(count, seed, args.size)
            default = estimate_normals(images, lights, mask)
            lambert = estimate_normals(images, lights, mask, method="lambert")
            solved = mask & ~np.isin(default.status, NO_NORMAL)
            print(f"{count:6d} {seed:4d} {1 - solved.sum() / mask.sum():9.1%} "
                  f"{angular_error_deg(default.normals, normals, solved).mean():8.2f} "
                  f"{angular_error_deg(lambert.normals, normals, solved).mean():8.2f}", flush=True)


if __name__ == "__main__":
    main()
