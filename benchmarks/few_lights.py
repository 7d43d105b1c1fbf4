"""Photometric stereo with few lights: random 4- to 16-light subsets of the DiLiGenT objects.

    python benchmarks/few_lights.py [DILIGENT_DIR] [--counts 4,6,8,12,16] [--subsets 5] [--seed 0]
                                    [--neighbour-consensus on|off]

For every object found and every light count, ``--subsets`` random subsets of its lights (fixed
seeds: the subsets of count c of object number j are drawn with seed ``seed + 1000 c + 100 j``)
are solved with ``lambert`` (every observation), ``lambert-low`` (the observations the default
selects) and the default estimator. Printed: each subset's mean angular errors (degrees) over
the object's mask, a pixel without a normal counting 90 degrees, then the default's over the
pixels that every method gives a normal (``common``) and the share of the mask the default gives
one (``cover``: the others are marked too few or ill-posed in its status map, not left wrong).
Per light count: the means over all subsets; whether the default was worse than lambert on the
common pixels of any subset (target: never); and from 12 lights, where
the biquadratic model is determined at most pixels, the default's gain over lambert-low over the
mask (target: at least 5 % lower).
"""

import argparse
from pathlib import Path

import numpy as np

from pipeline.experiments.synthetic import angular_error_deg
from pipeline.importers import read_diligent
from pipeline.photometric import estimate_normals

METHODS = ("lambert", "lambert-low", "biquadratic")
#: light counts from which the default must beat lambert-low by GAIN_TARGET
GAIN_FROM, GAIN_TARGET = 12, 0.05


def subsets(count, lights, n, seed):
    rng = np.random.default_rng(seed)
    return [np.sort(rng.choice(lights, count, replace=False)) for _ in range(n)]


def solve(images, valid, obj, chosen, options=None):
    """Each method's errors (H, W) over the mask and where it gives a normal (H, W) bool;
    ``options`` are the default method's."""
    found = {}
    for method in METHODS:
        given = (options or {}) if method == "biquadratic" else {}
        normals = estimate_normals(images[chosen], obj.directions[chosen], obj.mask, method=method,
                                   valid=valid[chosen], **given).normals
        errors = np.zeros(obj.mask.shape)
        errors[obj.mask] = angular_error_deg(normals, obj.normals_gt, obj.mask)
        found[method] = (errors, obj.mask & (np.linalg.norm(normals, axis=2) > 0))
    return found


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/diligent"))
    parser.add_argument("--counts", default="4,6,8,12,16")
    parser.add_argument("--subsets", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--neighbour-consensus", choices=("on", "off"), default="on",
                        help="the default's neighbour consensus (on, its default)")
    args = parser.parse_args(argv)
    objects = [read_diligent(p) for p in sorted(Path(args.data).iterdir()) if (p / "filenames.txt").is_file()]
    stacks = [obj.load_images() for obj in objects]
    print(f"{'lights':>6} {'object':8} {'subset':>6} " + " ".join(f"{m:>12}" for m in METHODS) +
          f" {'common: lambert':>16} {'default':>8} {'cover':>6}")
    for count in (int(c) for c in args.counts.split(",")):
        errors, common, cover = {m: [] for m in METHODS}, [], []
        for j, (obj, (images, valid)) in enumerate(zip(objects, stacks)):
            for i, chosen in enumerate(subsets(count, len(images), args.subsets, args.seed + 1000 * count + 100 * j)):
                found = solve(images, valid, obj, chosen, {"neighbour_consensus": args.neighbour_consensus == "on"})
                shared = np.logical_and.reduce([has for _, has in found.values()])
                row = {m: float(found[m][0][obj.mask].mean()) for m in METHODS}
                # no pixel in common: lights too close to coplanar for every method (NaN, left out)
                pair = tuple(float(found[m][0][shared].mean()) if shared.any() else np.nan
                             for m in ("lambert", "biquadratic"))
                for m in METHODS:
                    errors[m].append(row[m])
                common.append(pair)
                cover.append(float(found["biquadratic"][1][obj.mask].mean()))
                print(f"{count:6d} {obj.name:8} {i:6d} " + " ".join(f"{row[m]:12.2f}" for m in METHODS) +
                      f" {pair[0]:16.2f} {pair[1]:8.2f} {cover[-1]:6.1%}", flush=True)
        means = {m: float(np.mean(v)) for m, v in errors.items()}
        judged = [(a, b) for a, b in common if np.isfinite(a)]
        worse = sum(b > a for a, b in judged)
        line = (f"{count} lights, {len(common)} subsets: mean {', '.join(f'{m} {means[m]:.3f}' for m in METHODS)}; "
                f"common pixels ({len(judged)} subsets) lambert {np.mean([a for a, _ in judged]):.3f}, default "
                f"{np.mean([b for _, b in judged]):.3f}, cover {np.mean(cover):.1%}; default worse than lambert on "
                f"{worse} subset(s) (target 0): {'PASS' if worse == 0 else 'MISS'}")
        if count >= GAIN_FROM:
            gain = 1 - means["biquadratic"] / means["lambert-low"]
            verdict = "PASS" if gain >= GAIN_TARGET else "MISS"
            line += f"; default {gain:.1%} below lambert-low (target >= 5 %): {verdict}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
