"""Photometric stereo speed and memory on synthetic stacks.

    python benchmarks/photometric_speed.py [--pixels 57000] [--lights 96] [--big-mp 4] [--big-lights 50]
                                           [--repeat 3] [--workers N] [--skip-big]

1. A DiLiGenT-sized object (57,000 pixels, 96 lights, narrow light cone as DiLiGenT's): seconds
   for biquadratic vs Lambertian least squares (best of ``--repeat`` runs, wall clock and
   process CPU time), pixels per second, and peak traced memory (a separate traced run, since
   tracing slows numpy down). The load average is printed: the machine may be shared.
2. A large stack (``--big-mp`` megapixels x ``--big-lights`` lights, wide lights): peak memory
   beyond the input stack, as a ratio to the input stack's size (target: peak < 2 x input,
   i.e. extra < 1 x). Use --big-mp 24 for the full 24-megapixel check (slow).
"""

import argparse
import os
import time
import tracemalloc
from pathlib import Path

import numpy as np


from pipeline.photometric import estimate_normals
from pipeline.experiments.synthetic import cook_torrance_images, hemisphere_lights


def blob(pixels):
    """Normals (H, W, 3) and mask of a sphere-like blob with about ``pixels`` masked pixels."""
    size = int(np.sqrt(pixels / (np.pi / 4 * 0.95**2))) + 1
    c = (size - 1) / 2
    yy, xx = np.mgrid[0:size, 0:size]
    x, y = (xx - c) / (size / 2), -(yy - c) / (size / 2)
    mask = x**2 + y**2 < 0.95**2
    z = np.sqrt(np.clip(1 - x**2 - y**2, 0, None))
    normals = np.where(mask[..., None], np.stack([x, y, z], -1), 0.0)
    return normals, mask


def timed(images, lights, mask, method, repeat=1, workers=None):
    """Best wall-clock and CPU seconds over ``repeat`` untraced runs; the last result."""
    walls, cpus = [], []
    for _ in range(repeat):
        start, cpu = time.perf_counter(), time.process_time()
        result = estimate_normals(images, lights, mask, method=method, workers=workers)
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - cpu)
    return result, min(walls), min(cpus)


def traced_peak(images, lights, mask, method, workers=None):
    """Peak traced memory (bytes) of one run."""
    tracemalloc.start()
    estimate_normals(images, lights, mask, method=method, workers=workers)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def load_average():
    return " ".join(f"{v:.2f}" for v in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pixels", type=int, default=57000)
    parser.add_argument("--lights", type=int, default=96)
    parser.add_argument("--big-mp", type=float, default=4.0)
    parser.add_argument("--big-lights", type=int, default=50)
    parser.add_argument("--repeat", type=int, default=3, help="timed runs; the best is reported")
    parser.add_argument("--workers", type=int, default=None, help="threads (default: all cores)")
    parser.add_argument("--skip-big", action="store_true", help="only the DiLiGenT-sized object")
    args = parser.parse_args(argv)

    normals, mask = blob(args.pixels)
    lights = hemisphere_lights(args.lights, seed=0, min_elevation_deg=48)  # DiLiGenT-like cone
    images = cook_torrance_images(normals, mask, lights, roughness=0.4, noise=0.002)
    print(f"load average before: {load_average()}")
    _, t_lambert, c_lambert = timed(images, lights, mask, "lambert", args.repeat, args.workers)
    _, t_biq, c_biq = timed(images, lights, mask, "biquadratic", args.repeat, args.workers)
    peak = traced_peak(images, lights, mask, "biquadratic", args.workers)
    n = int(mask.sum())
    print(f"object: {n} pixels x {args.lights} lights, best of {args.repeat}")
    print(f"  lambert      {t_lambert:7.2f} s  {n / t_lambert:10.0f} px/s  (cpu {c_lambert:.2f} s)")
    verdict = "PASS" if t_biq <= 0.5 else "MISS"
    print(f"  biquadratic  {t_biq:7.2f} s  {n / t_biq:10.0f} px/s  (cpu {c_biq:.2f} s)  ratio to lambert "
          f"{t_biq / t_lambert:5.1f}x  target 0.5 s: {verdict} ({t_biq / 0.5:.1f}x the target)")
    print(f"  peak traced memory {peak / 2**20:7.1f} MiB (target < 1024 MiB)")
    print(f"load average after: {load_average()}")
    if args.skip_big:
        return

    side = int(np.sqrt(args.big_mp * 1e6))
    big_normals, big_mask = blob(int(side * side * np.pi / 4 * 0.9))
    big_lights = hemisphere_lights(args.big_lights, seed=3, min_elevation_deg=15)
    stack = cook_torrance_images(big_normals, big_mask, big_lights, roughness=0.4)
    input_bytes = stack.nbytes
    _, seconds, _ = timed(stack, big_lights, big_mask, "biquadratic", 1, args.workers)
    peak = traced_peak(stack, big_lights, big_mask, "biquadratic", args.workers)
    print(f"large stack: {stack.shape[1]}x{stack.shape[2]} px ({big_mask.sum()} masked) x {args.big_lights} lights, "
          f"input {input_bytes / 2**20:.0f} MiB")
    print(f"  biquadratic {seconds:7.1f} s, {big_mask.sum() / seconds:.0f} px/s; peak extra memory "
          f"{peak / 2**20:.0f} MiB = {peak / input_bytes:.2f} x input "
          f"(peak total {1 + peak / input_bytes:.2f} x input, target < 2 x)")

if __name__ == "__main__":
    main()
