"""``psrig preview --rig NAME [--light i ...]``: one frame per light, measured before a capture.

Prints per colour channel the percentiles and the clipped share, a suggested shutter (99.9th
percentile at 80 % of white) and a focus measure, and writes a PNG of each frame (atomically).
"""

import sys
from pathlib import Path

__all__ = ["register", "run"]


def register(subparsers):
    parser = subparsers.add_parser(
        "preview", help="one frame per light: histogram, clipping, suggested shutter, focus",
        description="Shoot one frame per chosen light on a rig (default: its brightest light) and "
                    "print the histogram summary, the clipped share per colour channel, a shutter "
                    "putting the 99.9th percentile at 80 % of white, and a focus measure; a PNG "
                    "of each frame is written to --out.")
    parser.add_argument("--rig", required=True, metavar="NAME", help="rig of the rig file (e.g. sim)")
    parser.add_argument("--config", metavar="FILE", help="rig file to read instead of rigs.yaml")
    parser.add_argument("--light", type=int, action="append", metavar="I",
                        help="light to preview (repeat for several; default the brightest)")
    parser.add_argument("--out", metavar="DIR", default=".",
                        help="folder for the PNGs (default: the current folder)")
    parser.set_defaults(func=run)


def run(args):
    from rig.capture import open_devices, set_camera_exposure
    from rig.config import ConfigError, get_rig
    from rig.preview import default_lights, format_stats, take_preview

    rig = get_rig(args.rig, args.config)
    lights = args.light or default_lights(rig)
    for light in lights:
        if not 0 <= light < rig.lights.count:
            raise ConfigError(f"--light {light}: rig '{rig.name}' has lights 0-{rig.lights.count - 1}")
    out = Path(args.out)
    with open_devices(rig, None) as devices:
        devices.exposure = set_camera_exposure(rig, devices, lambda line: print(line, file=sys.stderr))
        shutter = (devices.exposure.get("shutter") or {}).get("value")
        if shutter is None and devices.sim is not None:
            shutter = devices.sim.backend.camera.shutter_seconds()
        results = take_preview(devices, lights, shutter=shutter, png_folder=out)
    for stats in results:
        print("\n".join(format_stats(stats)))
    return 0
