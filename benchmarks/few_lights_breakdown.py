"""Where the default's error is under few lights: its error split by pixel class, beside the
Lambertian fits of the same observations (``lambert-low``) and of every one (``lambert``).

    python benchmarks/few_lights_breakdown.py [DILIGENT_DIR] [--lights 10] [--subsets 20] [--seed 0]

The subsets are :mod:`benchmarks.few_lights`' (the same seeds, saturated observations left out
as the command line does). For every object, over all its subsets: the mean error over the mask
of each method (a pixel without a normal counting 90 degrees) and of the per-pixel best of the
default and ``lambert-low`` (an oracle: it needs the ground truth, and bounds what any per-pixel
choice between the two models could gain). Then one table per class: the observations the
default kept (``used``), its status, the 4-pixel band along the mask's outline, and the true
normal's slant (15-degree bins). Each row: the class's share of the mask, the mean error of
each method in it, and ``gap``, the default's error minus ``lambert-low``'s summed over the
class and divided by the mask (the degrees the object's mean would move if the class took the
Lambertian fit: negative where the biquadratic wins).

Last, the selection against the truth: an observation is inconsistent when its ratio to the true
normal's shading (n . l over 0.05) is more than :data:`TOLERANCE` off the median ratio of the
pixel's non-shadowed observations (a shadow, an interreflection, a highlight, a penumbra); printed
are how many inconsistent observations the default keeps per pixel, too bright and too dark, the
consistent ones it drops, and the mean error of a Lambertian fit on the selected observations
against one on exactly the consistent ones (another oracle: what a perfect per-light
decision would give the Lambertian fit), over the pixels with 3 consistent observations or more.
"""

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy import ndimage

from pipeline.experiments.synthetic import angular_error_deg
from pipeline.importers import read_diligent
from pipeline.photometric import STATUS_NAMES, estimate_normals
from pipeline.photometric.lambert import lambert_weighted
from pipeline.photometric.selection import select_observations

try:
    from few_lights import subsets
except ImportError:                      # run as a module from the repository's root
    from benchmarks.few_lights import subsets

METHODS = ("biquadratic", "lambert-low", "lambert")
#: the outline band's width (pixels): the uncertainty map's outline term uses the same
BAND_PX = 4
SLANT_BIN_DEG = 15
#: an observation more than this fraction off its pixel's median ratio to the true shading is inconsistent
TOLERANCE = 0.2


def selection_against_truth(images, valid, obj, chosen):
    """(kept too bright, kept too dark, consistent dropped) per pixel, and the errors (degrees)
    of the Lambertian fits on the selected and on the consistent observations, summed over the
    pixels with 3 consistent observations or more, and their count."""
    obs = images[chosen][:, obj.mask].T.astype(float)
    lights = obj.directions[chosen]
    base, weights, b = select_observations(obs, valid[chosen][:, obj.mask].T, lights)
    truth = obj.normals_gt[obj.mask]
    shading = truth @ lights.T
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where((base > 0) & (shading > 0.05), obs / np.maximum(shading, 1e-6), np.nan)
        off = ratio / np.nanmedian(np.where(np.isnan(ratio).all(axis=1, keepdims=True), 1.0, ratio), axis=1,
                                   keepdims=True) - 1.0
    consistent = np.abs(off) < TOLERANCE
    kept = weights > 0
    counts = np.array([(kept & ~consistent & (off > 0)).sum(), (kept & ~consistent & (off < 0)).sum(),
                       (consistent & ~kept).sum()])
    fit = lambert_weighted(obs, lights, consistent.astype(float))
    judged = consistent.sum(axis=1) >= 3

    def error(v):
        unit = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)
        return np.degrees(np.arccos(np.clip(np.sum(unit * truth, axis=1), -1.0, 1.0)))[judged].sum()

    return counts, np.array([error(b), error(fit)]), judged.sum()


def errors_of(images, valid, obj, chosen):
    """Each method's error (P,) over the mask's pixels, and the default's result."""
    out, result = {}, None
    for method in METHODS:
        found = estimate_normals(images[chosen], obj.directions[chosen], obj.mask, method=method,
                                 valid=valid[chosen])
        out[method] = angular_error_deg(found.normals, obj.normals_gt, obj.mask)
        result = found if method == "biquadratic" else result
    return out, result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/diligent"))
    parser.add_argument("--lights", type=int, default=10)
    parser.add_argument("--subsets", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    paths = [p for p in sorted(Path(args.data).iterdir()) if (p / "filenames.txt").is_file()]
    for j, path in enumerate(paths):
        obj = read_diligent(path)
        images, valid = obj.load_images()
        mask = obj.mask
        band = (mask & ~ndimage.binary_erosion(mask, iterations=BAND_PX))[mask]
        slant = np.degrees(np.arccos(np.clip(obj.normals_gt[mask][:, 2], -1.0, 1.0)))
        slant_bin = (slant // SLANT_BIN_DEG).astype(int) * SLANT_BIN_DEG
        sums = defaultdict(lambda: np.zeros(1 + len(METHODS)))
        totals, oracle, pixels = np.zeros(len(METHODS)), 0.0, 0
        truth_counts, truth_errors, judged = np.zeros(3), np.zeros(2), 0
        # the light count and subset seeds of benchmarks/few_lights.py
        for chosen in subsets(args.lights, len(images), args.subsets, args.seed + 1000 * args.lights + 100 * j):
            errs, result = errors_of(images, valid, obj, chosen)
            counts, fits, n_judged = selection_against_truth(images, valid, obj, chosen)
            truth_counts, truth_errors, judged = truth_counts + counts, truth_errors + fits, judged + n_judged
            stack = np.stack([errs[m] for m in METHODS])
            totals += stack.sum(axis=1)
            oracle += np.minimum(stack[0], stack[1]).sum()
            pixels += mask.sum()
            classes = {"used": result.used[mask].astype(int), "status": result.status[mask].astype(int),
                       "outline band": band.astype(int), "slant": slant_bin}
            for kind, labels in classes.items():
                for label in np.unique(labels):
                    inside = labels == label
                    sums[(kind, int(label))] += np.concatenate([[inside.sum()], stack[:, inside].sum(axis=1)])
        means = totals / pixels
        print(f"\n{obj.name}, {args.lights} lights, {args.subsets} subsets: " +
              ", ".join(f"{m} {v:.3f}" for m, v in zip(METHODS, means)) +
              f"; per-pixel best of biquadratic and lambert-low (oracle) {oracle / pixels:.3f}")
        print(f"  {'class':14} {'value':>14} {'share':>6} " + " ".join(f"{m:>12}" for m in METHODS) + f" {'gap':>7}")
        for (kind, label), (count, *errs) in sorted(sums.items()):
            if count / pixels < 0.005:
                continue
            name = STATUS_NAMES.get(label, str(label)) if kind == "status" else \
                f"{label}-{label + SLANT_BIN_DEG}" if kind == "slant" else str(label)
            print(f"  {kind:14} {name:>14} {count / pixels:6.1%} " + " ".join(f"{e / count:12.2f}" for e in errs) +
                  f" {(errs[0] - errs[1]) / pixels:+7.3f}", flush=True)
        bright, dark, dropped = truth_counts / pixels
        print(f"  selection against the truth ({TOLERANCE:.0%}): kept inconsistent per pixel {bright:.2f} too bright, "
              f"{dark:.2f} too dark; consistent dropped {dropped:.2f}; Lambert on the selected "
              f"{truth_errors[0] / judged:.2f}, on the consistent ones (oracle) {truth_errors[1] / judged:.2f} "
              f"({judged / pixels:.1%} of the pixels)", flush=True)


if __name__ == "__main__":
    main()
