"""Photometric stereo speed and memory on synthetic stacks.

    python benchmarks/photometric_speed.py [--pixels 57000] [--lights 96] [--big-mp 4] [--big-lights 50]

1. A DiLiGenT-sized object (57,000 pixels, 96 lights, narrow light cone as DiLiGenT's): seconds
   for biquadratic vs Lambertian least squares, pixels per second, and peak traced memory.
2. A large stack (``--big-mp`` megapixels x ``--big-lights`` lights, wide lights): peak memory
   beyond the input stack, as a ratio to the input stack's size (target: peak < 2 x input,
   i.e. extra < 1 x). Use --big-mp 24 for the full 24-megapixel check (slow).
"""

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "pipeline"))

from pipeline.photometric import estimate_normals  # noqa: E402
from ps_synthetic import cook_torrance_images, hemisphere_lights  # noqa: E402


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


def timed(images, lights, mask, method):
    tracemalloc.start()
    start = time.perf_counter()
    result = estimate_normals(images, lights, mask, method=method)
    seconds = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return result, seconds, peak


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pixels", type=int, default=57000)
    parser.add_argument("--lights", type=int, default=96)
    parser.add_argument("--big-mp", type=float, default=4.0)
    parser.add_argument("--big-lights", type=int, default=50)
    args = parser.parse_args(argv)

    normals, mask = blob(args.pixels)
    lights = hemisphere_lights(args.lights, seed=0, min_elevation_deg=48)  # DiLiGenT-like cone
    images = cook_torrance_images(normals, mask, lights, roughness=0.4, noise=0.002)
    _, t_lambert, _ = timed(images, lights, mask, "lambert")
    _, t_biq, peak = timed(images, lights, mask, "biquadratic")
    n = int(mask.sum())
    print(f"object: {n} pixels x {args.lights} lights")
    print(f"  lambert      {t_lambert:7.2f} s  {n / t_lambert:10.0f} px/s")
    print(f"  biquadratic  {t_biq:7.2f} s  {n / t_biq:10.0f} px/s  ratio to lambert {t_biq / t_lambert:5.1f}x  "
          f"target 0.5 s: {'PASS' if t_biq <= 0.5 else 'MISS'} ({t_biq / 0.5:.1f}x the target)")
    print(f"  peak traced memory {peak / 2**20:7.1f} MiB (target < 1024 MiB)")

    side = int(np.sqrt(args.big_mp * 1e6))
    big_normals, big_mask = blob(int(side * side * np.pi / 4 * 0.9))
    big_lights = hemisphere_lights(args.big_lights, seed=3, min_elevation_deg=15)
    stack = cook_torrance_images(big_normals, big_mask, big_lights, roughness=0.4)
    input_bytes = stack.nbytes
    _, seconds, peak = timed(stack, big_lights, big_mask, "biquadratic")
    print(f"large stack: {stack.shape[1]}x{stack.shape[2]} px ({big_mask.sum()} masked) x {args.big_lights} lights, "
          f"input {input_bytes / 2**20:.0f} MiB")
    print(f"  biquadratic {seconds:7.1f} s, {big_mask.sum() / seconds:.0f} px/s; peak extra memory "
          f"{peak / 2**20:.0f} MiB = {peak / input_bytes:.2f} x input (peak total {1 + peak / input_bytes:.2f} x input, "
          f"target < 2 x)")


if __name__ == "__main__":
    main()
