"""How well the normals' uncertainty map predicts the actual error, on DiLiGenT objects.

    python benchmarks/uncertainty.py [DILIGENT_DIR] [--subsets 5] [--lights 10] [--seed 0] [--fit]

For every object (96 lights, and ``--subsets`` random ``--lights``-light subsets drawn with seed
``seed + 100 j`` for object number j), the default estimator's ``result.uncertainty`` against
the actual angular error (saturated observations left out, as ``psrig decode`` does):

- ROC AUC of the predicted error for telling the pixels more than 20 degrees off from the rest,
  on every case where at least 1 % of the pixels are (target >= 0.85);
- calibration: the pixels in five bins by predicted error (quintiles), each bin's median
  predicted and actual error (1-degree floor) and their ratio (target: within a factor of 2).

With ``--fit`` the model's constants are fitted again by least squares on log(actual error),
every object weighted alike, (a) on all three objects, printed for
:data:`pipeline.photometric.uncertainty.COEFFICIENTS`, and (b) leaving each object out in turn:
each held-out object is scored with the constants fitted on the other two.
"""

import argparse
from pathlib import Path

import numpy as np

from pipeline.experiments.synthetic import angular_error_deg
from pipeline.importers import read_diligent
from pipeline.photometric import estimate_normals
from pipeline.photometric.uncertainty import (COEFFICIENTS, FEATURES, agreement, design_matrix,
                                              predict_uncertainty, uncertainty_features)

BAD_DEG, MIN_BAD_SHARE, AUC_TARGET, BINS, FLOOR = 20.0, 0.01, 0.85, 5, 1.0


def case(images, valid, obj, chosen):
    """(features, has, actual error (H, W)) of the default on the lights ``chosen``."""
    result = estimate_normals(images[chosen], obj.directions[chosen], obj.mask, valid=valid[chosen])
    has, features = uncertainty_features(result.normals, result.status, result.residual, result.leverage, obj.mask,
                                          result.used)
    actual = np.full(obj.mask.shape, np.nan)
    actual[obj.mask] = angular_error_deg(result.normals, obj.normals_gt, obj.mask)
    return features, has, actual, result


def fit(cases):
    """Least-squares constants on log(actual error), each object's pixels weighted alike."""
    rows, targets, weights = [], [], []
    for name, features, has, actual in cases:
        rows.append(design_matrix(features, has))
        targets.append(np.log(np.maximum(actual[has], 0.1)))
        weights.append(np.full(int(has.sum()), 1.0 / has.sum()))
    x, y, w = np.concatenate(rows), np.concatenate(targets), np.sqrt(np.concatenate(weights))
    return np.linalg.lstsq(x * w[:, None], y * w, rcond=None)[0]


def score(label, features, has, actual, coefficients):
    """Print one case's AUC and calibration (as ``psrig eval`` measures them); returns (auc or
    NaN, calibrated: bool)."""
    predicted = predict_uncertainty(features, has, coefficients)[has]
    found = agreement(predicted, actual[has], bad_deg=BAD_DEG, bins=BINS, floor_deg=FLOOR,
                      min_bad_share=MIN_BAD_SHARE)
    auc = float("nan") if found["auc"] is None else found["auc"]
    ok = found["calibrated_bins"] == len(found["bins"])
    bins = "  ".join(f"{b['predicted_deg']:5.1f}/{b['actual_deg']:5.1f}" for b in found["bins"])
    auc_text = f"{auc:.3f}" if np.isfinite(auc) else "  -  "
    print(f"{label:24} >20deg {found['bad_share']:6.1%}  AUC {auc_text}  bins pred/actual {bins}  "
          f"{'calibrated' if ok else 'NOT calibrated'}", flush=True)
    return auc, ok


def verdict(results):
    aucs = [a for a, _ in results if np.isfinite(a)]
    auc_ok = all(a >= AUC_TARGET for a in aucs)
    cal_ok = all(ok for _, ok in results)
    return (f"AUC >= {AUC_TARGET} on {sum(a >= AUC_TARGET for a in aucs)} of {len(aucs)} cases with >= 1 % "
            f"over 20 deg ({'PASS' if auc_ok else 'MISS'}); calibrated within x2 in "
            f"{sum(ok for _, ok in results)} of {len(results)} ({'PASS' if cal_ok else 'MISS'})")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/diligent"))
    parser.add_argument("--subsets", type=int, default=5)
    parser.add_argument("--lights", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fit", action="store_true", help="fit the constants again (all; leave one object out)")
    args = parser.parse_args(argv)
    cases = []   # (object, label, features, has, actual)
    for j, path in enumerate(sorted(p for p in Path(args.data).iterdir() if (p / "filenames.txt").is_file())):
        obj = read_diligent(path)
        images, valid = obj.load_images()
        rng = np.random.default_rng(args.seed + 100 * j)
        draws = [np.arange(len(images))] + [np.sort(rng.choice(len(images), args.lights, replace=False))
                                             for _ in range(args.subsets)]
        for i, chosen in enumerate(draws):
            features, has, actual, _ = case(images, valid, obj, chosen)
            label = f"{obj.name} {len(chosen)} lights" + (f" #{i}" if i else "")
            cases.append((obj.name, label, features, has, actual))
    names = sorted({c[0] for c in cases})
    print(f"frozen constants {tuple(round(c, 4) for c in COEFFICIENTS)} over (1,) + {FEATURES}")
    for subset in ("96 lights", f"{args.lights} lights"):
        print(f"-- frozen, {subset}")
        print(verdict([score(label, f, h, a, COEFFICIENTS) for _, label, f, h, a in cases if subset in label]))
    if not args.fit:
        return
    full = fit([(n, f, h, a) for n, _, f, h, a in cases])
    print(f"-- fitted on every case: {tuple(round(float(c), 4) for c in full)}")
    for subset in ("96 lights", f"{args.lights} lights"):
        print(verdict([score(label, f, h, a, full) for _, label, f, h, a in cases if subset in label]))
    print("-- leave one object out (fitted on the other two, scored on it)")
    held = []
    for name in names:
        coefficients = fit([(n, f, h, a) for n, _, f, h, a in cases if n != name])
        print(f"   without {name}: {tuple(round(float(c), 4) for c in coefficients)}")
        held += [score(label, f, h, a, coefficients) for n, label, f, h, a in cases if n == name]
    print(verdict(held))


if __name__ == "__main__":
    main()
