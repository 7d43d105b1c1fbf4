"""The session stage: sphere frames -> calibration/lights.yaml, lights.lp, overlays."""

import time

import numpy as np

from pipeline.errors import StageError
from pipeline.imageio import read_image, read_mask
from pipeline.lightsio import LightSet, write_lights_yaml, write_lp

from .overlays import write_overlay
from .sphere import calibrate_sphere

__all__ = ["calibrate_session"]

LIGHTS, LP, OVERLAY = "calibration/lights.yaml", "calibration/lights.lp", "calibration/overlay_sphere.png"


def _load(session, frames):
    images, sats, inputs = [], [], []
    for f in frames:
        path = session.linear_path(f)
        if not path.is_file():
            raise StageError(f"{path}: linear frame {f['id']!r} is missing; run psrig decode first")
        images.append(read_image(path))
        inputs.append(session.rel(path))
        sat = session.saturation_path(f)
        sats.append(read_mask(sat) if sat.is_file() else np.zeros(images[-1].shape[:2], bool))
        if sat.is_file():
            inputs.append(session.rel(sat))
    return np.stack(images), np.stack(sats), inputs


def calibrate_session(session, *, circle=None, sphere_mask=None, K=None, force=False, echo=print):
    """Calibrate the lights of ``session`` from its sphere frames (see module docstring).

    Returns the :class:`SphereCalibration`, or None when skipped (up to date, or imported
    lights and no sphere frames).
    """
    frames = sorted(session.frames("sphere"), key=lambda f: f["light"])
    if not frames:
        if session.path(LIGHTS).is_file():
            echo(f"{session.root}: no sphere frames; keeping the imported {LIGHTS}")
            return None
        raise StageError(f"{session.root}: no sphere frames and no {LIGHTS}")
    params = {"circle": None if circle is None else [float(v) for v in np.ravel(circle)],
              "sphere_mask": None if sphere_mask is None else str(sphere_mask),
              "K": None if K is None else np.asarray(K, float).tolist()}
    rels = [session.rel(session.linear_path(f)) for f in frames]
    rels += [session.rel(session.saturation_path(f)) for f in frames if session.saturation_path(f).is_file()]
    inputs = session.hash_inputs(rels)
    if not force and session.stage_is_current("calibrate", params, inputs):
        echo(f"{session.root}: calibrate is up to date")
        return None
    start = time.perf_counter()
    images, sats, _ = _load(session, frames)
    mask = None if sphere_mask is None else read_mask(sphere_mask)
    result = calibrate_sphere(images, circle, mask, saturation=sats, K=K)
    order = [f["light"] for f in frames]
    flags = {order[k]: f"frame {frames[k]['id']}: {why}" for k, why in result.flags.items()}
    directions = np.where(np.isfinite(result.directions), result.directions, [0.0, 0.0, 1.0])
    lights = LightSet(directions, np.ones((len(frames), images.shape[-1])), positions=result.positions,
                      flags=flags, source="chrome sphere; no matte target, intensities = 1",
                      extra={"method": result.method,
                             "residual_deg": np.round(result.residual_deg, 4).tolist(),
                             "uncertainty_deg": np.round(result.uncertainty_deg, 4).tolist(),
                             "circles": [c.as_dict() for c in result.circles]})
    write_lights_yaml(session.path(LIGHTS), lights)
    objects = {f["light"]: f for f in session.frames("object")}
    names = [objects[i].get("source", objects[i]["file"].split("/")[-1]) if i in objects else frames[k]["id"]
             for k, i in enumerate(order)]
    write_lp(session.path(LP), names, directions)
    write_overlay(session.path(OVERLAY), images.max(0), result.circles, result.highlights, result.flags)
    session.record_stage("calibrate", params, inputs, [LIGHTS, LP, OVERLAY],
                         seconds=time.perf_counter() - start, flagged=flags)
    return result
