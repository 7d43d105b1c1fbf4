"""Test fixture: a calibration session of the simulated rig's sphere scene (two chrome spheres
and a matte white one), with raw DNG frames and either decoded or directly rendered linear ones."""

import numpy as np

from pipeline.core.imageio import write_image, write_mask
from pipeline.core.session import Session
from rig.sim.scene import Scene

__all__ = ["sphere_scene", "make_sphere_session", "linear_frames"]

SHAPE = (240, 320)


def sphere_scene(count=8, distance=None, shape=SHAPE, seed=0):
    """The simulated calibration scene with ``count`` lights (near at ``distance`` pixels)."""
    return Scene.default_spheres(shape, count=count, distance=distance, seed=seed)


def linear_frames(scene):
    """Noise-free linear frames (K, H, W, 3) clipped at the white level, and saturation (K, H, W)."""
    lin = np.stack([scene.render_linear(k) for k in range(scene.count)])
    return np.clip(lin, 0, 1), (lin >= 1).any(-1)


def make_sphere_session(root, scene, *, decoded=False):
    """Session at ``root`` with one DNG sphere frame per light of ``scene``.

    ``decoded`` False writes the noise-free linear frames and saturation masks straight into
    linear/ (``psrig decode`` is then not needed); True leaves decoding to the caller.
    """
    session = Session.create(root, rig={"name": "sim"})
    frames = [session.add_frame("sphere", scene.render_dng(k), light=k, save=False) for k in range(scene.count)]
    session.save()
    if not decoded:
        images, sats = linear_frames(scene)
        for frame, image, sat in zip(frames, images, sats):
            write_image(session.linear_path(frame), image.astype(np.float32))
            write_mask(session.saturation_path(frame), sat)
    return session
