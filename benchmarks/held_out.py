"""The normals stage's held-out-light check on sessions that have been run, timed on its own.

    python benchmarks/held_out.py SESSION [SESSION ...] [--folds 5] [--pixels 20000]

For each session (its decode and lights in place, e.g. ``python -m pipeline import diligent
../shared/data/diligent/catPNG /tmp/cat && python -m pipeline run /tmp/cat``), reads the object
frames as the normals stage does and runs :func:`pipeline.photometric.prediction.held_out_prediction`
with the stage's recorded options (the lights as given: the specular anchor's correction, which
the stage applies, is not redone here). Prints the overall errors, how many lights the
biquadratic predicts better than Lambert, the worst light and the check's time.
"""

import argparse
import time

import numpy as np

from pipeline.photometric.prediction import FOLDS, SAMPLE_PIXELS, held_out_prediction
from pipeline.photometric.stage import begin_normals, load_object_stack, object_mask
from pipeline.core.session import Session


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+")
    parser.add_argument("--folds", type=int, default=FOLDS)
    parser.add_argument("--pixels", type=int, default=SAMPLE_PIXELS)
    args = parser.parse_args()
    for root in args.sessions:
        session = Session.open(root)
        run = begin_normals(session, force=True)
        images, valid = load_object_stack(session, run.frames, run.lights)
        mask = object_mask(session, run, images)
        lights = run.solver_lights(images.shape[1:])
        start = time.perf_counter()
        found = held_out_prediction(images, valid, lights, mask, options=run.options, folds=args.folds,
                                    sample_pixels=args.pixels)
        seconds = time.perf_counter() - start
        if found["verdict"] != "checked":
            print(f"{root}: not checked: {found['reason']}")
            continue
        lights_table = found["lights"]
        better = sum(1 for e in lights_table if e["biquadratic_pct"] is not None
                     and e["biquadratic_pct"] < e["lambert_pct"])
        ranked = sum(1 for e in lights_table if e["biquadratic_pct"] is not None)
        overall = found["overall"]
        print(f"{root}: {found['pixels']} grid pixels (stride {found['stride']}), {found['folds']} folds: "
              f"biquadratic {overall['biquadratic_pct']:.2f} %, Lambert {overall['lambert_pct']:.2f} %; "
              f"biquadratic lower on {better} / {ranked} lights; worst light {found['worst_light']} "
              f"({lights_table[found['worst_light']]['biquadratic_pct']:.2f} %); {seconds:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
