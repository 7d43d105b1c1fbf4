"""Photometric stereo on DiLiGenT objects: mean angular error next to the published numbers.

    python benchmarks/diligent.py ../shared/data/diligent [--methods biquadratic,lambert,...]

For each object folder (``*PNG`` with Normal_gt.mat) and method: mean / median angular error
over the mask (degrees; a pixel without a normal counts 90), the mean over the pixels given a
normal (``eval``: what ``psrig eval`` prints for the imported session), the published Lambertian least
squares and ST14 figures, wall time, pixels per second and the time ratio to a BLAS Lambertian
solve ``pinv(L) @ I`` run in the same process; then each method's mean over the objects.
"""

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


from pipeline.importers import read_diligent
from pipeline.photometric import estimate_normals

PUBLISHED = {"ball": (4.10, 1.74), "cat": (8.41, 6.12), "pot1": (8.89, 6.51), "bear": (8.39, 6.12),
             "pot2": (14.65, 8.78), "buddha": (14.92, 10.60), "goblet": (18.50, 10.09),
             "reading": (19.80, 13.63), "cow": (25.60, 13.93), "harvest": (30.62, 25.44)}


def pinv_seconds(images, lights, mask, repeat=7):
    """Best wall seconds of the plain baseline pinv(L) @ I over the masked pixels (float64)."""
    observations = images[:, mask].astype(np.float64)
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        np.linalg.pinv(lights) @ observations
        best = min(best, time.perf_counter() - start)
    return best


def git_archive(rev, folder, *paths, who="benchmark"):
    """Unpack ``paths`` of git revision ``rev`` of this repository into ``folder`` (made if need
    be); exits naming ``who`` when git cannot give them."""
    root = Path(__file__).resolve().parents[1]
    archive = subprocess.run(["git", "-C", str(root), "archive", rev, *paths], capture_output=True, check=False)
    if archive.returncode:
        sys.exit(f"{who}: git archive {rev}: {archive.stderr.decode().strip()}")
    Path(folder).mkdir(parents=True, exist_ok=True)
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive.stdout, check=True)
    return Path(folder)


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
    print(f"{'object':8} {'method':14} {'mean':>6} {'median':>6} {'eval':>6} {'L2 pub':>6} {'ST14 pub':>8} "
          f"{'time s':>7} {'px/s':>9} {'x pinv':>7}")
    means = {}
    for folder in folders:
        obj = read_diligent(folder)
        images, valid = obj.load_images()   # saturated observations left out, as psrig decode does
        baseline = pinv_seconds(images, obj.directions, obj.mask)
        for method in args.methods.split(","):
            times = []
            for _ in range(args.repeat):
                start = time.perf_counter()
                result = estimate_normals(images, obj.directions, obj.mask, method=method, valid=valid)
                times.append(time.perf_counter() - start)
            best = min(times)
            err = angular_error(result.normals, obj.normals_gt, obj.mask)
            given = np.linalg.norm(result.normals[obj.mask], axis=1) > 0
            means.setdefault(method, []).append(err.mean())
            l2, st14 = PUBLISHED.get(obj.name, (float("nan"), float("nan")))
            print(f"{obj.name:8} {method:14} {err.mean():6.2f} {np.median(err):6.2f} {err[given].mean():6.2f} {l2:6.2f} {st14:8.2f} "
                  f"{best:7.2f} {obj.mask.sum() / best:9.0f} {best / baseline:7.0f}", flush=True)
    names = [f.name[:-3] for f in folders]
    st14 = [PUBLISHED.get(n, (np.nan, np.nan))[1] for n in names]
    for method, values in means.items():
        print(f"mean over {len(values)} objects, {method}: {np.mean(values):.2f} (ST14 {np.nanmean(st14):.2f})")


if __name__ == "__main__":
    main()
