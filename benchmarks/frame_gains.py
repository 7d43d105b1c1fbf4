"""Frames brighter or darker than their lights' intensities say: found, rescaled, and what it saves.

    python benchmarks/frame_gains.py [DILIGENT_DIR] [--seed 0] [--subsets 3]

On every DiLiGenT object found, with its own intensities divided out, the frames are made wrong
on purpose (fixed seeds): one frame x 0.5, 0.7, 0.85, 1.2, 1.4 or 2 (a light that dimmed or
misfired, an exposure that changed), 20 frames x U(0.6, 1.5), and the intensities left out
altogether (every light counted as 1). Each case is solved with the default (``frame_gains``
'auto': frames more than 16 % and more than their own spread off the others are rescaled) and
with ``frame_gains=False`` (the intensities trusted). Printed per case: mean angular error of
both (degrees), the frames rescaled, the largest error of a rescaled frame's gain (log units)
and the frames wrongly rescaled. Then the same for one frame x 0.7 in random 12-light subsets
and in a synthetic 12-light dome (the paper's darkest-fraction rule, which has no rejection).
Last, the check's own time beside ``pinv(L) @ I`` on the full objects.
"""

import argparse
import time
from pathlib import Path

import numpy as np

from pipeline.experiments.synthetic import angular_error_deg, cook_torrance_images, hemisphere_lights, sphere_normals
from pipeline.importers import read_diligent
from pipeline.photometric import estimate_normals
from pipeline.photometric.engine import gatherer
from pipeline.photometric.frame_gains import check_frames
from pipeline.photometric.selection import resolve_selection

from diligent import pinv_seconds  # the one baseline, beside this script


def cases(count, intensities, rng):
    """{name: factor (K,)} the frames are multiplied by (1 = right)."""
    out = {"right": np.ones(count)}
    for factor in (0.5, 0.7, 0.85, 1.2, 1.4, 2.0):
        wrong = np.ones(count)
        wrong[rng.integers(count)] = factor
        out[f"one x{factor}"] = wrong
    wrong = np.ones(count)
    wrong[rng.choice(count, min(20, count // 2), replace=False)] = rng.uniform(0.6, 1.5, min(20, count // 2))
    out["20 x U(0.6,1.5)"] = wrong
    if intensities is not None:
        out["intensities left out"] = intensities / np.median(intensities)
    return out


def solve_case(images, valid, lights, mask, truth, factor, right=None):
    """Errors (default, trusted, right), frames rescaled and off, the largest gain error, and the
    frames rescaled that were right; ``right`` the error with the right intensities, if known;
    ``valid`` (K, H, W) bool or None: the saturation flags."""
    if right is None:
        right = float(angular_error_deg(estimate_normals(images, lights, mask, valid=valid).normals, truth,
                                        mask).mean())
    wrong = images * factor[:, None, None].astype(np.float32)
    checked = estimate_normals(wrong, lights, mask, valid=valid)
    trusted = estimate_normals(wrong, lights, mask, valid=valid, frame_gains=False)
    record = checked.options["frame_check"]
    rescaled = record.get("rescaled", {})
    off = np.flatnonzero(np.abs(np.log(factor / np.median(factor))) > 1e-9)
    gain_error = max((abs(np.log(g / factor[k] * np.median(factor))) for k, g in rescaled.items()), default=0.0)
    false = sorted(set(rescaled) - set(off.tolist()))
    errors = [float(angular_error_deg(r.normals, truth, mask).mean()) for r in (checked, trusted)] + [right]
    return errors, len(rescaled), len(off), gain_error, false


def print_row(label, errors, rescaled, off, gain_error, false):
    print(f"{label:34s} {errors[0]:8.2f} {errors[1]:8.2f} {errors[2]:8.2f} {rescaled:4d}/{off:<4d} {gain_error:9.3f} "
          f"{len(false):6d}", flush=True)


def dome(seed, size=96):
    normals, mask = sphere_normals(size)
    lights = hemisphere_lights(12, seed=seed, min_elevation_deg=20)
    return cook_torrance_images(normals, mask, lights, roughness=0.3, noise=0.002), lights, mask, normals


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/diligent"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--subsets", type=int, default=3)
    args = parser.parse_args(argv)
    objects = [read_diligent(p) for p in sorted(Path(args.data).iterdir()) if (p / "filenames.txt").is_file()]
    print(f"{'case':34s} {'default':>8} {'trusted':>8} {'right':>8} {'rescaled/off':>9} {'gain err':>9} "
          f"{'false':>6}")
    worst_false = 0
    # saturated observations left out, as the command line does
    stacks = [obj.load_images() for obj in objects]
    for j, (obj, (images, valid)) in enumerate(zip(objects, stacks)):
        rng = np.random.default_rng(args.seed + 100 * j)
        right = None
        for name, factor in cases(len(images), obj.intensities.mean(axis=1), rng).items():
            row = solve_case(images, valid, obj.directions, obj.mask, obj.normals_gt, factor, right)
            right = row[0][2]
            worst_false = max(worst_false, len(row[4]))
            print_row(f"{obj.name} 96: {name}", *row)
        for i in range(args.subsets):
            chosen = np.sort(rng.choice(len(images), 12, replace=False))
            factor = np.ones(12)
            factor[rng.integers(12)] = 0.7
            row = solve_case(images[chosen], valid[chosen], obj.directions[chosen], obj.mask, obj.normals_gt, factor)
            worst_false = max(worst_false, len(row[4]))
            print_row(f"{obj.name} 12 lights #{i}: one x0.7", *row)
    for seed in range(args.subsets):
        images, lights, mask, normals = dome(seed)
        factor = np.ones(12)
        factor[seed] = 0.7
        row = solve_case(images, None, lights, mask, normals, factor)
        worst_false = max(worst_false, len(row[4]))
        print_row(f"dome 12 lights seed {seed}: one x0.7", *row)
    print(f"frames rescaled that were right: at most {worst_false} in a case (target 0): "
          f"{'PASS' if worst_false == 0 else 'MISS'}")
    for obj, (images, valid) in zip(objects, stacks):
        k = len(images)
        gather = gatherer(images.reshape(k, -1), valid.reshape(k, -1), obj.directions)
        pixels, options = np.flatnonzero(obj.mask), resolve_selection(obj.directions, {})
        check_frames(gather, pixels, options)   # compiled kernels warm
        check = min(_seconds(lambda: check_frames(gather, pixels, options)) for _ in range(5))
        pinv = pinv_seconds(images, obj.directions, obj.mask)
        print(f"{obj.name}: the check takes {check * 1e3:.1f} ms ({check / pinv:.0f} x pinv(L) @ I)")


def _seconds(call):
    start = time.perf_counter()
    call()
    return time.perf_counter() - start


if __name__ == "__main__":
    main()
