"""Calibration benchmark: ``python benchmarks/sphere_calibration.py [../shared/data/psbox]``.

Prints, per PSBox probe, the angles to the probe's own published directions (median vs the
0.5 deg target, no clicks): from the light frames alone, then through a session that carries the
probe's room-lit ref.JPG as its outline frame (the circles found there) and the same session
calibrated with --no-outline; and the two probes' agreement; then, on the simulated rig's sphere
scene (360 x 480, 32 lights), direction median/max vs 0.2/0.5 deg, intensity error vs 1 % and,
for near lights, the triangulated distance error vs 2 %.
"""

import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from calibration.intensities import target_intensities
from calibration.positions import frame_offset
from calibration.sphere import calibrate_sphere
from calibration.stage import calibrate_session
from pipeline.decode import decode_session
from pipeline.importers import import_images
from rig.sim.scene import Scene


def angles(a, b):
    return np.degrees(np.arccos(np.clip((a * b).sum(1), -1, 1)))


def psbox(root):
    """Per probe: the light frames alone through the Python API (JPEG values), then the session
    route a user takes (import with the probe's room-lit ref.JPG as the outline frame, decode,
    calibrate; and calibrate --no-outline); then each route's agreement between the probes."""
    dirs = {}
    for name in ("LightProbe-1", "LightProbe-2"):
        folder = root / name
        frames = np.stack([cv2.imread(str(folder / f"Image_{i:02d}.JPG"))[:, :, ::-1] for i in range(1, 13)])
        own = np.loadtxt(folder / "light_directions.txt").T
        xc, yc, r = np.loadtxt(folder / "circle_data.txt")
        start = time.perf_counter()
        result = calibrate_sphere(frames.astype(np.float32) / 255)
        secs = time.perf_counter() - start
        c, a = result.circle, angles(result.directions, own)
        print(f"psbox {name}, light frames only: median {np.median(a):.3f} deg (target 0.5, ratio "
              f"{np.median(a) / 0.5:.2f}), max {a.max():.3f}; circle ({c.cx:.2f}, {c.cy:.2f}, {c.r:.2f}) vs "
              f"published ({xc - 1:.2f}, {frames.shape[1] - yc:.2f}, {r:.2f}); {secs:.2f} s; flags {result.flags}")
        dirs["api", name] = result.directions
        for route, got in _session_route(folder).items():
            b = angles(got.directions, own)
            gc = got.circle
            print(f"psbox {name}, session, {route}: median {np.median(b):.3f} deg (ratio {np.median(b) / 0.5:.2f}), "
                  f"max {b.max():.3f}; circle ({gc.cx:.2f}, {gc.cy:.2f}, {gc.r:.2f}); flags {got.flags}")
            dirs[route, name] = got.directions
    p = angles(np.loadtxt(root / "LightProbe-1/light_directions.txt").T,
               np.loadtxt(root / "LightProbe-2/light_directions.txt").T)
    for route in ("api", "outline frame", "--no-outline"):
        a = angles(dirs[route, "LightProbe-1"], dirs[route, "LightProbe-2"])
        print(f"psbox probe agreement ({route}): median {np.median(a):.3f} max {a.max():.3f} deg "
              f"(published files agree to median {np.median(p):.3f})")


def _session_route(folder):
    """{route: SphereCalibration} of a probe imported as a session with ref.JPG as its outline."""
    with tempfile.TemporaryDirectory() as tmp:
        pattern = str(folder / "Image_*.JPG")
        session = import_images(Path(tmp) / "s", pattern, sphere_glob=pattern, outline=str(folder / "ref.JPG"))
        decode_session(session, progress=False)
        quiet = lambda *_: None  # noqa: E731
        return {"outline frame": calibrate_session(session, echo=quiet),
                "--no-outline": calibrate_session(session, outline=False, echo=quiet)}


def simulated(count=32):
    for distance in (None, 600.0, 1500.0):
        scene = Scene.default_spheres((360, 480), count=count, distance=distance, seed=0)
        linear = np.stack([scene.render_linear(k) for k in range(scene.count)])
        images, sat = np.clip(linear, 0, 1), (linear >= 1).any(-1)
        start = time.perf_counter()
        result = calibrate_sphere(images, saturation=sat)
        intens = target_intensities(images, result.directions, circle=result.targets[0].params, saturation=sat,
                                    positions=result.positions, offset=frame_offset(images.shape[1:3]))
        secs = time.perf_counter() - start
        a = angles(result.directions, scene.directions)
        i_err = np.abs(intens / (scene.intensities / scene.intensities.mean()) - 1).max() * 100
        label = "directional" if distance is None else f"near {distance:g} px"
        line = (f"sim {label}: {len(result.circles)} chrome + {len(result.targets)} matte found, model "
                f"{'near' if result.near else 'directional'}; directions median {np.median(a):.3f} "
                f"(target 0.2, ratio {np.median(a) / 0.2:.2f}) max {a.max():.3f} (target 0.5, ratio "
                f"{a.max() / 0.5:.2f}) deg; intensities max error {i_err:.2f} % (target 1)")
        if distance is not None and result.triangulated is not None:
            d = np.abs(np.linalg.norm(result.triangulated, axis=1) / distance - 1).max() * 100
            line += f"; distance max error {d:.2f} % (target 2)"
        print(line + f"; {secs:.2f} s")


if __name__ == "__main__":
    root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared/data/psbox")
    if root.is_dir():
        psbox(root)
    else:
        print(f"{root}: psbox data missing, skipped")
    simulated()
