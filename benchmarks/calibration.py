"""Calibration benchmark: ``python benchmarks/calibration.py ../shared/data/psbox``.

Prints, per PSBox probe, per-light angles to the probe's own published directions and to the
averaged ones (median, max, seconds), the two probes' mutual agreement, and a simulated section.
"""

import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from calibration.sphere import calibrate_sphere  # noqa: E402
from tests.calibration.render import render_chrome  # noqa: E402


def angles(a, b):
    return np.degrees(np.arccos(np.clip((a * b).sum(1), -1, 1)))


def probe(folder):
    frames = np.stack([cv2.imread(str(folder / f"Image_{i:02d}.JPG"))[:, :, ::-1] for i in range(1, 13)])
    start = time.perf_counter()
    result = calibrate_sphere(frames.astype(np.float32) / 255)
    return result, time.perf_counter() - start


def main(root):
    root = Path(root)
    mean = np.loadtxt(root / "light_directions.txt").T
    dirs = {}
    for name in ("LightProbe-1", "LightProbe-2"):
        result, secs = probe(root / name)
        own = np.loadtxt(root / name / "light_directions.txt").T
        h = cv2.imread(str(root / name / "Image_01.JPG")).shape[0]
        xc, yc, r = np.loadtxt(root / name / "circle_data.txt")
        c = result.circle
        print(f"{name}: circle ({c.cx:.2f}, {c.cy:.2f}, {c.r:.2f}) vs published ({xc - 1:.2f}, {h - yc:.2f}, {r:.2f}); "
              f"{secs:.2f} s; flags {result.flags}")
        for label, ref in (("own", own), ("averaged", mean)):
            a = angles(result.directions, ref)
            print(f"  vs {label:8s} per light {np.round(a, 2).tolist()}  median {np.median(a):.3f}  max {a.max():.3f} deg")
        dirs[name] = result.directions
    a = angles(dirs["LightProbe-1"], dirs["LightProbe-2"])
    p = angles(np.loadtxt(root / "LightProbe-1/light_directions.txt").T, np.loadtxt(root / "LightProbe-2/light_directions.txt").T)
    print(f"probe-1 vs probe-2: median {np.median(a):.3f} max {a.max():.3f} deg (published files: median {np.median(p):.3f})")
    rng = np.random.default_rng(3)
    theta, phi = np.radians(rng.uniform(5, 50, 16)), rng.uniform(0, 2 * np.pi, 16)
    truth = np.c_[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]
    start = time.perf_counter()
    result = calibrate_sphere(render_chrome(truth))
    a = angles(result.directions, truth)
    print(f"simulated (own render, 16 lights): median {np.median(a):.3f} max {a.max():.3f} deg, "
          f"{time.perf_counter() - start:.2f} s")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/psbox")
