"""A tiny photometric-stereo session for runner and report tests: a Lambertian hemisphere under
8 lights as 16-bit PNGs, imported with a light file, an object mask and ground-truth normals,
plus a stub Lambertian normals stage (the real one may be absent or slow)."""

import time

import numpy as np

from pipeline.core.imageio import read_image, read_mask, write_image, write_mask, write_normal_png
from pipeline.importers import import_images
from pipeline.core.lightsio import read_lights

SIZE = 40


def sphere(size=SIZE):
    """Unit normals (H, W, 3) of a hemisphere filling most of the image, and its mask."""
    yy, xx = np.mgrid[:size, :size]
    x = (xx + 0.5 - size / 2) / (0.45 * size)
    y = -(yy + 0.5 - size / 2) / (0.45 * size)
    r2 = x ** 2 + y ** 2
    mask = r2 < 0.9
    z = np.sqrt(np.clip(1 - r2, 0, None))
    normals = np.where(mask[..., None], np.stack([x, y, z], -1), 0.0)
    return normals, mask


def lights(count=8):
    azimuth = np.linspace(0, 2 * np.pi, count, endpoint=False)
    polar = np.radians(np.where(np.arange(count) % 2, 30.0, 45.0))
    return np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth),
                     np.cos(polar)], -1)


def make_session(tmp_path, name="session"):
    """Import the tiny scene into ``tmp_path / name`` and return the Session."""
    normals, mask = sphere()
    dirs = lights()
    src = tmp_path / f"{name}_src"
    src.mkdir()
    for k, l in enumerate(dirs):
        shading = np.clip(normals @ l, 0, None) * 0.8 * mask
        write_image(src / f"img{k + 1}.png", np.repeat(shading[..., None], 3, axis=2))
    (src / "lights.txt").write_text(f"{len(dirs)}\n" + "".join(f"{x} {y} {z}\n" for x, y, z in dirs))
    write_mask(src / "mask.png", mask)
    session = import_images(tmp_path / name, str(src / "img*.png"), mask=src / "mask.png",
                            lights=src / "lights.txt")
    write_image(session.path("truth/normals.exr"), normals.astype(np.float32))
    write_mask(session.path("truth/mask.png"), mask)
    session.set_truth("normals", "truth/normals.exr", save=False)
    session.set_truth("mask", "truth/mask.png")
    return session


def lambert_stage(session, options, force, jobs):
    """Stub normals stage with the real one's contract; method 'tilted' bends normals to +z."""
    frames = session.frames("object")
    rels = [session.rel(session.linear_path(f)) for f in frames] + ["calibration/lights.yaml"]
    inputs = session.hash_inputs(rels)
    params = {"method": options.get("method", "lambert")}
    if not force and session.stage_is_current("normals", params, inputs):
        return
    start = time.perf_counter()
    dirs = read_lights(session.path("calibration/lights.yaml")).directions
    images = np.stack([read_image(session.linear_path(f)).mean(axis=2) for f in frames])
    k, h, w = images.shape
    g = np.linalg.lstsq(dirs, images.reshape(k, -1), rcond=None)[0].T.reshape(h, w, 3)
    albedo = np.linalg.norm(g, axis=2)
    mask = read_mask(session.path(session.manifest["lights"]["object_mask"])) & (albedo > 1e-6)
    if params["method"] == "tilted":
        g = g + albedo[..., None] * np.array([0.0, 0.0, 0.3])
    normals = g / np.maximum(np.linalg.norm(g, axis=2), 1e-12)[..., None]
    normals = np.where(mask[..., None], normals, 0.0)
    write_image(session.path("normals/normals.exr"), normals.astype(np.float32))
    write_normal_png(session.path("normals/normals.png"), normals, mask)
    write_mask(session.path("normals/mask.png"), mask)
    write_image(session.path("normals/albedo.exr"), albedo.astype(np.float32))
    write_image(session.path("normals/status.png"), mask.astype(np.uint8), bits=8)
    outputs = ["normals/normals.exr", "normals/normals.png", "normals/mask.png",
               "normals/albedo.exr", "normals/status.png"]
    session.record_stage("normals", params, inputs, outputs, seconds=time.perf_counter() - start)
