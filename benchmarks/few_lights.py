"""Photometric stereo with few lights: random 12- and 16-light subsets of the DiLiGenT objects.

    python benchmarks/few_lights.py [DILIGENT_DIR] [--counts 12,16] [--subsets 5] [--seed 0]

For every object found and every light count, ``--subsets`` random subsets of its lights (fixed
seeds: the subsets of count c of object number j are drawn with seed ``seed + 1000 c + 100 j``)
are solved with ``lambert`` (every observation), ``lambert-low`` (the observations the default
selects) and the default estimator. Printed: each subset's mean angular errors (degrees), then
per light count the means over all subsets, the default's gain over lambert-low (target: at
least 5 % lower), and whether the default was ever worse than lambert on a subset's lights
(target: never).
"""

import argparse
from pathlib import Path

import numpy as np

from pipeline.experiments.synthetic import angular_error_deg
from pipeline.importers import read_diligent
from pipeline.photometric import estimate_normals

METHODS = ("lambert", "lambert-low", "biquadratic")


def mean_error(normals, truth, mask):
    return float(angular_error_deg(normals, truth, mask).mean())


def subsets(count, lights, n, seed):
    rng = np.random.default_rng(seed)
    return [np.sort(rng.choice(lights, count, replace=False)) for _ in range(n)]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/diligent"))
    parser.add_argument("--counts", default="12,16")
    parser.add_argument("--subsets", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    objects = [read_diligent(p) for p in sorted(Path(args.data).iterdir()) if (p / "filenames.txt").is_file()]
    stacks = [obj.load_images() for obj in objects]
    print(f"{'lights':>6} {'object':8} {'subset':>6} " + " ".join(f"{m:>12}" for m in METHODS))
    for count in (int(c) for c in args.counts.split(",")):
        errors = {m: [] for m in METHODS}
        for j, (obj, images) in enumerate(zip(objects, stacks)):
            for i, chosen in enumerate(subsets(count, len(images), args.subsets, args.seed + 1000 * count + 100 * j)):
                row = {m: mean_error(estimate_normals(images[chosen], obj.directions[chosen], obj.mask, method=m).normals,
                                     obj.normals_gt, obj.mask) for m in METHODS}
                for m in METHODS:
                    errors[m].append(row[m])
                print(f"{count:6d} {obj.name:8} {i:6d} " + " ".join(f"{row[m]:12.2f}" for m in METHODS), flush=True)
        means = {m: float(np.mean(v)) for m, v in errors.items()}
        gain = 1 - means["biquadratic"] / means["lambert-low"]
        worse = sum(b > a for a, b in zip(errors["lambert"], errors["biquadratic"]))
        print(f"{count} lights, {len(errors['lambert'])} subsets: mean " +
              ", ".join(f"{m} {means[m]:.3f}" for m in METHODS) +
              f"; default {gain:.1%} below lambert-low (target >= 5 %): {'PASS' if gain >= 0.05 else 'MISS'}; "
              f"worse than lambert on {worse} subset(s) (target 0): {'PASS' if worse == 0 else 'MISS'}", flush=True)


if __name__ == "__main__":
    main()
