"""Near point lights: per-pixel light directions and intensity falloff from light positions.

Chrome-sphere calibration with two spheres triangulates each light's position (see
:mod:`calibration.positions`). A light a few object sizes away is not a direction: across the
object its direction changes by degrees and its irradiance by the inverse square of the
distance. :class:`PointLights` gives photometric stereo both, per pixel, computed chunk by chunk
so a (K, H, W, 3) array is never built.

Frame: the orthographic session frame of the calibration, in pixels: x = col - (W - 1) / 2,
y = (H - 1) / 2 - row, z toward the camera with z = 0 on the plane of the sphere centres.
"""

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError

__all__ = ["PointLights", "observations_at"]


@dataclass
class PointLights:
    """Point lights at known positions seen by an orthographic camera.

    Attributes
    ----------
    positions : ndarray (K, 3)
        Light positions, pixels, session frame (see the module docstring).
    shape : (H, W)
        Image size in pixels.
    plane_z : float or ndarray (H, W)
        Height of the surface points assumed for the directions (pixels, 0 = the plane of the
        calibration spheres' centres): one plane before the depth is known, or a height per
        pixel (see :mod:`pipeline.photometric.near_depth`).

    Notes
    -----
    Intensities of near lights are defined at the frame origin (image centre, z = 0): the
    irradiance at X is ``I_k |p_k|^2 / |p_k - X|^2``, so :meth:`falloff` is 1 there.
    """

    positions: np.ndarray
    shape: tuple
    plane_z: float = 0.0

    def __post_init__(self):
        self.positions = np.asarray(self.positions, float).reshape(-1, 3)
        if not np.isfinite(self.positions).all():
            raise InputError("near lights: a light position is not finite")
        self.shape = tuple(int(v) for v in self.shape)
        if len(self.shape) != 2:
            raise InputError(f"near lights: image shape must be (H, W), got {self.shape}")
        if (np.linalg.norm(self.positions, axis=1) < 1e-9).any():
            raise InputError("near lights: a light sits at the frame origin")
        if np.ndim(self.plane_z):
            self.plane_z = np.asarray(self.plane_z, float)
            if self.plane_z.shape != self.shape or not np.isfinite(self.plane_z).all():
                raise InputError(f"near lights: a depth map must be finite and {self.shape}, got "
                                 f"shape {self.plane_z.shape}")

    def __len__(self):
        return len(self.positions)

    @property
    def central_directions(self):
        """Unit directions (K, 3) from the frame origin to the lights (for summaries and the
        light-geometry rules that need one direction per light)."""
        return self.positions / np.linalg.norm(self.positions, axis=1, keepdims=True)

    def points(self, flat_index):
        """Surface points (N, 3) assumed at the flat pixel indices ``flat_index`` (N,)."""
        h, w = self.shape
        flat_index = np.asarray(flat_index)
        rows, cols = np.divmod(flat_index, w)
        z = self.plane_z.ravel()[flat_index] if np.ndim(self.plane_z) else np.full(rows.shape, self.plane_z, float)
        return np.stack([cols - (w - 1) / 2.0, (h - 1) / 2.0 - rows, z], axis=1)

    def at(self, flat_index):
        """Directions (N, K, 3) toward the lights and falloff (N, K) at the given pixels.

        The falloff ``|p_k|^2 / |p_k - X|^2`` multiplies the light's intensity at X; divide
        the observations by it.
        """
        to_light = self.positions[None, :, :] - self.points(flat_index)[:, None, :]
        dist2 = np.einsum("nkc,nkc->nk", to_light, to_light)
        if (dist2 < 1e-12).any():
            raise InputError("near lights: a light position lies on the object plane")
        directions = to_light / np.sqrt(dist2)[..., None]
        falloff = np.einsum("kc,kc->k", self.positions, self.positions)[None, :] / dist2
        return directions, falloff


def observations_at(lights, obs, flat_index):
    """The solver's view of pixels ``flat_index`` (N,): observations (N, K) and lights.

    Directional ``lights`` (K, 3) pass through. For :class:`PointLights` the falloff is divided
    out of ``obs`` and the per-pixel directions (N, K, 3) are returned.
    """
    if not isinstance(lights, PointLights):
        return obs, lights
    directions, falloff = lights.at(flat_index)
    return obs / falloff, directions
