"""Frames taken after the object or camera moved: named, and what they cost.

    python benchmarks/registration.py [DILIGENT_DIR] [--seed 5] [--subsets 3]

On every DiLiGenT object found, frames are moved on purpose (bilinear shifts, fixed seeds):
none; 10 random frames by 1-6 px in random directions (bumps); the last 40 frames by one
2.5 px shift (the object moved mid-capture). Each case is solved with the default, then
:func:`pipeline.photometric.registration.check_registration` (with a re-solve without the
frames it names, as the normals stage does). Printed per case: the mean angular error (degrees)
with every frame, and with the named frames left out; the frames named right / the frames moved;
the frames named wrongly; the threshold and the right frames' median departure (px); the
check's seconds beside ``pinv(L) @ I``. Then the same for 2 frames moved by 1-4 px, and for no
frame moved, in random 12-, 16- and 32-light subsets.
"""

import argparse
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from pipeline.experiments.synthetic import angular_error_deg
from pipeline.importers import read_diligent
from pipeline.photometric import check_registration, estimate_normals

from diligent import pinv_seconds  # the one baseline, beside this script


def shifted(images, valid, frames, rng, low, high, one=None):
    """images and their saturation flags ``valid`` with ``frames`` moved (by ``one`` (cols, rows)
    px, else each by a random ``low``-``high`` px; pixels shifted in from outside not valid)."""
    out, out_valid, truth = images.copy(), valid.copy(), {}
    for k in frames:
        if one is None:
            direction = rng.normal(size=2)
            shift = direction / np.linalg.norm(direction) * rng.uniform(low, high)
        else:
            shift = np.asarray(one, float)
        out[k] = ndimage.shift(images[k], (shift[1], shift[0]), order=1)
        out_valid[k] = ndimage.shift(valid[k].astype(np.uint8), (shift[1], shift[0]), order=0, cval=0) > 0
        truth[int(k)] = shift
    return out, out_valid, truth


def run_case(name, stack, lights, mask, truth_normals, moved):
    images, valid = stack[:2]
    result = estimate_normals(images, lights, mask, valid=valid)
    baseline = pinv_seconds(images, lights, mask)

    def without(keep):
        return estimate_normals(images[keep], lights[keep], mask, valid=valid[keep])

    start = time.perf_counter()
    found = check_registration(images, result, lights, valid, resolve=without)
    seconds = time.perf_counter() - start
    named = set(found.get("moved") or {})
    keep = np.ones(len(images), bool)
    keep[list(named)] = False
    left_out = angular_error_deg(without(keep).normals, truth_normals, mask).mean() if named else float("nan")
    print(f"  {name:28} err {angular_error_deg(result.normals, truth_normals, mask).mean():6.2f} / {left_out:6.2f}  "
          f"named {len(named & set(moved)):3d}/{len(moved):3d} wrong {len(named - set(moved)):2d}  "
          f"thr {found.get('threshold_px', float('nan')):4.2f} med {found.get('median_departure_px', float('nan')):5.3f} px"
          f"  run_from {found.get('run_from', '-')!s:>4}  {seconds:5.2f} s ({seconds / baseline:5.0f}x pinv)", flush=True)
    return len(named - set(moved))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("diligent", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/diligent"))
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--subsets", type=int, default=3)
    args = parser.parse_args()
    wrong = 0
    for path in sorted(p for p in Path(args.diligent).iterdir() if (p / "filenames.txt").is_file()):
        obj = read_diligent(path)
        # saturated observations left out, as the command line does
        (images, valid), lights, mask, truth = obj.load_images(), obj.directions, obj.mask, obj.normals_gt
        count = len(images)
        rng = np.random.default_rng(args.seed)
        print(f"{obj.name} ({count} lights, {int(mask.sum())} px): error all / named left out (deg)")
        wrong += run_case("none moved", (images, valid), lights, mask, truth, [])
        frames = np.sort(rng.choice(count, 10, replace=False))
        wrong += run_case("10 frames by 1-6 px", shifted(images, valid, frames, rng, 1, 6), lights, mask, truth, frames)
        last = np.arange(count - 40, count)
        wrong += run_case("last 40 by (2.0, -1.5) px", shifted(images, valid, last, rng, 0, 0, one=(2.0, -1.5)), lights,
                          mask, truth, last)
        for size in (12, 16, 32):
            for _ in range(args.subsets):
                keep = np.sort(rng.choice(count, size, replace=False))
                sub, sub_valid, sub_lights = images[keep], valid[keep], lights[keep]
                wrong += run_case(f"{size} lights, none moved", (sub, sub_valid), sub_lights, mask, truth, [])
            frames = np.sort(rng.choice(size, 2, replace=False))
            wrong += run_case(f"{size} lights, 2 by 1-4 px", shifted(sub, sub_valid, frames, rng, 1, 4), sub_lights, mask,
                              truth, frames)
    print(f"frames named wrongly over every case: {wrong}")


if __name__ == "__main__":
    main()
