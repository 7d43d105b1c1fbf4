"""Photometric stereo on DiLiGenT objects: mean angular error next to the published numbers.

    python benchmarks/diligent.py ../shared/data/diligent [--methods biquadratic,lambert,...]

For each object folder (``*PNG`` with Normal_gt.mat) and method: mean / median angular error
over the mask (degrees), the published Lambertian least squares and ST14 figures, wall time,
pixels per second and the time ratio to plain Lambertian least squares on the same data.
"""

import argparse
import time
from pathlib import Path

import numpy as np


from pipeline.importers import read_diligent
from pipeline.photometric import estimate_normals

PUBLISHED = {"ball": (4.10, 1.74), "cat": (8.41, 6.12), "pot1": (8.89, 6.51), "bear": (8.39, 6.12),
             "pot2": (14.65, 8.78), "buddha": (14.92, 10.60), "goblet": (18.50, 10.09),
             "reading": (19.80, 13.63), "cow": (25.60, 13.93), "harvest": (30.62, 25.44)}


def angular_error(est, gt, mask):
    cos = np.clip(np.sum(est[mask] * gt[mask], axis=1), -1, 1)
    return np.degrees(np.arccos(cos))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/diligent"))
    parser.add_argument("--methods", default="lambert,lambert-low,biquadratic")
    parser.add_argument("--repeat", type=int, default=1, help="timing runs (best is reported)")
    args = parser.parse_args(argv)
    folders = sorted(p for p in Path(args.data).iterdir() if (p / "filenames.txt").is_file())
    print(f"{'object':8} {'method':14} {'mean':>6} {'median':>6} {'L2 pub':>6} {'ST14 pub':>8} "
          f"{'time s':>7} {'px/s':>9} {'x lambert':>9}")
    for folder in folders:
        obj = read_diligent(folder)
        images = obj.load_images()
        lambert_time = None
        for method in args.methods.split(","):
            times = []
            for _ in range(args.repeat):
                start = time.perf_counter()
                result = estimate_normals(images, obj.directions, obj.mask, method=method)
                times.append(time.perf_counter() - start)
            best = min(times)
            if method == "lambert" or lambert_time is None:
                lambert_time = best if method == "lambert" else lambert_time
            err = angular_error(result.normals, obj.normals_gt, obj.mask)
            l2, st14 = PUBLISHED.get(obj.name, (float("nan"), float("nan")))
            ratio = best / lambert_time if lambert_time else float("nan")
            print(f"{obj.name:8} {method:14} {err.mean():6.2f} {np.median(err):6.2f} {l2:6.2f} {st14:8.2f} "
                  f"{best:7.2f} {obj.mask.sum() / best:9.0f} {ratio:9.1f}", flush=True)


if __name__ == "__main__":
    main()
