"""The simulated scene: shapes x materials x lights -> linear radiance -> Bayer raw -> DNG.

Two scenes exist: the *object* scene (a glossy height-field object with concavities and cast
shadows, a spatially varying mix of two materials) and the *calibration* scene (two chrome spheres
and a matte white sphere). Units: one scene unit is one sensor pixel; the camera is orthographic,
camera frame x right, y up, z toward the camera, image row 0 at the top.

Rendering model, per pixel and colour channel c, for light k::

    radiance = exposure * ( I[k, c] * falloff * visible * ((albedo_c + spec) * max(n.l, 0) + chrome)
                            + ambient_c * albedo_c )

with ``spec`` the weighted Cook-Torrance and Ward lobes of :mod:`rig.sim.materials`, ``visible``
false in cast shadow, ``falloff`` = 1 for directional lights and (|p_k| / |p_k - X|)^2 for near
point lights at ``p_k``. Linear images are in sensor units: 1.0 is the white level.
"""

from dataclasses import dataclass, field

import numpy as np

from pipeline.core.dng import cfa_indices, write_dng
from pipeline.core.errors import InputError
from pipeline.core.imageio import write_image, write_mask, write_normal_png
from pipeline.core.lightsio import LightSet, write_lights_yaml

from . import materials, shapes

__all__ = ["Scene", "Sensor", "default_lights", "DEFAULT_SHAPE"]

#: the room-lit outline photo (:meth:`Scene.render_room`), radiance before exposure: the wall,
#: a chrome surface's mirrored room (base + overhead gain), a matte one's light (base + overhead)
ROOM_WALL, ROOM_MIRROR, ROOM_SKY = 0.5, (0.08, 0.1), (0.45, 0.3)

#: Sensor size (rows, columns) of the default scenes.
DEFAULT_SHAPE = (360, 480)
_KIND_CODE = {"object": 1, "spheres": 2}


@dataclass
class Sensor:
    """Raw sensor model: Poisson-Gaussian noise, black and white levels, RGGB mosaic.

    Attributes
    ----------
    black : int
        Black level, DN.
    white : int
        White (clipping) level, DN.
    dn_per_electron : float
        Conversion gain, DN per photo-electron (sets the shot noise).
    read_noise : float
        Gaussian read noise, DN (standard deviation).
    cfa : str
        Bayer order of the top-left 2x2 cell.
    """

    black: int = 512
    white: int = 16383
    dn_per_electron: float = 0.25
    read_noise: float = 2.0
    cfa: str = "RGGB"


def default_lights(count=32, seed=0, max_polar_deg=55.0, spread=0.25):
    """Light directions on a Fibonacci spiral over a cap around the view axis, with unequal
    intensities.

    Parameters
    ----------
    count : int
        Number of lights K.
    seed : int
        Seeds the intensities.
    max_polar_deg : float
        Largest angle between a light and the view axis, degrees.
    spread : float
        Relative spread of the per-light intensities (+/-).

    Returns
    -------
    directions : ndarray (K, 3)
        Unit vectors toward the lights, camera frame.
    intensities : ndarray (K, 3)
        Per light and colour channel.
    """
    i = np.arange(count) + 0.5
    cos_t = 1 - (1 - np.cos(np.radians(max_polar_deg))) * i / count
    sin_t = np.sqrt(1 - cos_t ** 2)
    phi = i * np.pi * (3 - np.sqrt(5))
    directions = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)
    rng = np.random.default_rng([seed, 7])
    level = rng.uniform(1 - spread, 1 + spread, (count, 1))
    tint = rng.uniform(0.92, 1.08, (count, 3))
    return directions, level * tint


@dataclass
class Scene:
    """A scene the simulated camera looks at.

    Build it with :meth:`default_object` or :meth:`default_spheres`. Per-pixel arrays are
    (H, W[, 3]); lobe weights are (H, W) maps so materials can vary across the surface.

    Attributes
    ----------
    kind : {'object', 'spheres'}
    geometry : shapes.Geometry
    albedo : ndarray (H, W, 3)
        Diffuse albedo (defined everywhere; only used on surfaces).
    lobes : dict
        Specular lobes: name -> dict(weight=(H, W) map, params); names 'cook_torrance',
        'ward', 'mirror'.
    directions : ndarray (K, 3)
        Unit vectors toward the lights (for near lights: from the origin to the light).
    intensities : ndarray (K, 3)
    positions : ndarray (K, 3) or None
        Near point light positions (pixels, camera frame), or None for directional lights.
    exposure : float
        Scales radiance to sensor units (1.0 = white level).
    ambient : ndarray (3,)
        Ambient irradiance (times albedo gives the ambient radiance), before ``exposure``.
    cast_shadows : bool
        March the height field for cast shadows (the object scene).
    circles : list of (cx, cy, r)
        The spheres, for the calibration scene.
    sphere_kinds : list of str
        'chrome' or 'matte' per circle.
    sensor : Sensor
    seed : int
        Seeds the per-frame noise.
    """

    kind: str
    geometry: shapes.Geometry
    albedo: np.ndarray
    lobes: dict
    directions: np.ndarray
    intensities: np.ndarray
    positions: np.ndarray = None
    exposure: float = 0.45
    ambient: np.ndarray = field(default_factory=lambda: np.full(3, 0.04))
    cast_shadows: bool = False
    circles: list = field(default_factory=list)
    sphere_kinds: list = field(default_factory=list)
    sensor: Sensor = field(default_factory=Sensor)
    seed: int = 0

    def __post_init__(self):
        self.directions = np.asarray(self.directions, float)
        self.directions = self.directions / np.linalg.norm(self.directions, axis=1, keepdims=True)
        self.intensities = np.broadcast_to(np.asarray(self.intensities, float),
                                           (len(self.directions), 3)).copy()
        if self.positions is not None:
            self.positions = np.asarray(self.positions, float).reshape(-1, 3)
            if len(self.positions) != len(self.directions):
                raise InputError(f"positions: {len(self.positions)} rows for {len(self.directions)} lights")
        h, w = self.shape
        if h % 2 or w % 2:
            raise InputError(f"scene shape {self.shape}: a Bayer sensor needs even height and width")
        self._points = None
        self._shadow_cache = {}

    # ------------------------------------------------------------------ constructors
    @classmethod
    def default_object(cls, shape=DEFAULT_SHAPE, *, count=32, directions=None, intensities=None,
                       positions=None, distance=None, seed=0, exposure=0.45, ambient=0.04):
        """The default glossy object: dome with bumps, dents and a groove; a mix of a
        Lambertian + Cook-Torrance (roughness 0.35) material and a Lambertian + Ward one.

        Parameters
        ----------
        shape : (H, W)
            Sensor size in pixels (even numbers).
        count : int
            Number of lights when ``directions`` is not given.
        directions : array (K, 3), optional
            Directional lights (camera frame, toward the light).
        intensities : array (K, 3) or (K, 1), optional
            Per-light intensities; default unequal (see :func:`default_lights`).
        positions : array (K, 3), optional
            Near point lights, pixels, camera frame.
        distance : float, optional
            Shortcut for near lights: ``positions = directions * distance``.
        seed : int
            Seeds intensities and noise.
        exposure : float
            Radiance scale; the default keeps the diffuse part near half of white.
        ambient : float or (3,)
            Ambient irradiance.
        """
        geometry = shapes.blob_object(shape)
        x, y = shapes.pixel_grid(shape)
        s = min(shape) / 360.0
        mix = 0.5 + 0.5 * np.sin(x / (37 * s) + 0.3) * np.cos(y / (29 * s))
        mix = np.clip((mix - 0.5) * 2.5 + 0.5, 0.0, 1.0)
        albedo = (mix[..., None] * np.array([0.78, 0.52, 0.36])
                  + (1 - mix[..., None]) * np.array([0.45, 0.58, 0.75]))
        lobes = {"cook_torrance": {"weight": 0.5 * mix, "roughness": 0.35, "f0": 0.04},
                 "ward": {"weight": 0.2 * (1 - mix), "alpha": 0.25}}
        directions, intensities, positions = _lights(count, directions, intensities, positions,
                                                     distance, seed)
        return cls("object", geometry, albedo, lobes, directions, intensities, positions,
                   exposure=exposure, ambient=np.broadcast_to(ambient, 3).astype(float),
                   cast_shadows=True, seed=seed)

    @classmethod
    def default_spheres(cls, shape=DEFAULT_SHAPE, *, count=32, directions=None, intensities=None,
                        positions=None, distance=None, seed=0, exposure=0.45, ambient=0.04,
                        chrome_gain=8.0):
        """The calibration scene: two chrome spheres (top left and right) and a matte white
        sphere (bottom centre) under the same lights as :meth:`default_object`.

        ``chrome_gain`` is the peak of a chrome highlight relative to a white diffuser facing
        the light; the default clips the highlight core like a real chrome ball.
        """
        h, w = shape
        r = 0.24 * min(h, w)
        circles = [(0.25 * w - 0.5, 0.33 * h - 0.5, r), (0.75 * w - 0.5, 0.33 * h - 0.5, r),
                   (0.5 * w - 0.5, 0.72 * h - 0.5, 0.85 * r)]
        kinds = ["chrome", "chrome", "matte"]
        geometry = shapes.spheres(shape, circles)
        matte = geometry.label == 2
        chrome = (geometry.label >= 0) & ~matte
        albedo = np.where(matte[..., None], 0.8, np.where(chrome[..., None], 0.005, 0.0))
        albedo = np.broadcast_to(albedo, (h, w, 3)).copy()
        lobes = {"mirror": {"weight": chrome * 0.9 * chrome_gain, "spread_deg": 2.5}}
        directions, intensities, positions = _lights(count, directions, intensities, positions,
                                                     distance, seed)
        return cls("spheres", geometry, albedo, lobes, directions, intensities, positions,
                   exposure=exposure, ambient=np.broadcast_to(ambient, 3).astype(float),
                   circles=[tuple(map(float, c)) for c in circles], sphere_kinds=kinds, seed=seed)

    # ------------------------------------------------------------------ properties
    @property
    def shape(self):
        """(H, W) of the sensor."""
        return self.geometry.mask.shape

    @property
    def count(self):
        """Number of lights K."""
        return len(self.directions)

    # ------------------------------------------------------------------ rendering
    def render_linear(self, light=None, *, ambient=True):
        """Linear image the sensor integrates, before noise.

        Parameters
        ----------
        light : int or None
            0-based light index; None renders with every light off.
        ambient : bool
            Include the ambient light (False gives the black image of a dark frame).

        Returns
        -------
        ndarray (H, W, 3) float32
            Sensor units (1.0 = white level), unclipped.
        """
        geometry = self.geometry
        out = np.zeros(self.shape + (3,), np.float32)
        if ambient:
            out += (self.ambient * self.albedo * geometry.coverage[..., None]).astype(np.float32)
        if light is not None:
            out[geometry.mask] += self._lit(self._check_light(light))
        out *= np.float32(self.exposure)
        return out

    def render_room(self):
        """Linear image (H, W, 3) of the scene under even room light, the rig's lights off:
        what an outline photo records, before exposure scaling's noise.

        A lit wall at :data:`ROOM_WALL` behind; a chrome surface mirrors a dim room, a little
        brighter overhead; a matte one shows its albedo under a sky-like light. Edges are
        anti-aliased by the geometry's coverage.
        """
        g = self.geometry
        n = g.normals
        mirror = self.lobes.get("mirror", {}).get("weight", np.zeros(self.shape))
        chrome = np.clip(mirror, 0, 1)[..., None]
        # reflected view ray of an orthographic camera (view (0, 0, 1)): its y component
        up = 2 * n[..., 2] * n[..., 1]
        env = ROOM_MIRROR[0] + ROOM_MIRROR[1] * np.clip(up, 0, None)
        matte = self.albedo * (ROOM_SKY[0] + ROOM_SKY[1] * n[..., 1])[..., None]
        surface = chrome * env[..., None] + (1 - chrome) * matte
        cover = g.coverage[..., None]
        out = ROOM_WALL * (1 - cover) + surface * cover
        return (out * self.exposure).astype(np.float32)

    def _check_light(self, light):
        light = int(light)
        if not 0 <= light < self.count:
            raise InputError(f"light {light}: the scene has lights 0..{self.count - 1}")
        return light

    def _surface_points(self):
        """Camera-frame positions (N, 3) of the masked pixels, in mask order."""
        if self._points is None:
            x, y = shapes.pixel_grid(self.shape)
            m = self.geometry.mask
            self._points = np.stack([x[m], y[m], self.geometry.depth[m]], axis=1)
        return self._points

    def _light_vectors(self, k):
        """Unit directions toward light k (N, 3) and the intensity falloff (N,)."""
        n = int(self.geometry.mask.sum())
        if self.positions is None:
            return np.broadcast_to(self.directions[k], (n, 3)), np.ones(n)
        to_light = self.positions[k] - self._surface_points()
        dist2 = np.einsum("ij,ij->i", to_light, to_light)
        falloff = np.dot(self.positions[k], self.positions[k]) / dist2
        return to_light / np.sqrt(dist2)[:, None], falloff

    def _shadow(self, k, l):
        if not self.cast_shadows:
            return None
        if k not in self._shadow_cache:
            g = self.geometry
            if self.positions is None:
                self._shadow_cache[k] = shapes.cast_shadow_directional(g.depth, g.mask, self.directions[k])
            else:
                self._shadow_cache[k] = shapes.cast_shadow(g.depth, g.mask, l)
        return self._shadow_cache[k]

    def _lit(self, k):
        """Radiance (N, 3) of the masked pixels under light k alone, before exposure."""
        g = self.geometry
        m = g.mask
        n = g.normals[m]
        l, falloff = self._light_vectors(k)
        nl = np.clip(np.einsum("ij,ij->i", n, l), 0.0, None)
        spec = np.zeros(len(n))
        for name, lobe in self.lobes.items():
            weight = lobe["weight"][m]
            params = {key: v for key, v in lobe.items() if key != "weight"}
            value = getattr(materials, name)(n, l, **params)
            spec += weight * (value if name == "mirror" else value * nl)
        radiance = self.albedo[m] * nl[:, None] + spec[:, None]
        shadow = self._shadow(k, l)
        scale = falloff * g.coverage[m]
        if shadow is not None:
            scale = np.where(shadow, 0.0, scale)
        return (radiance * (scale[:, None] * self.intensities[k])).astype(np.float32)

    def render_mosaic(self, light=None, *, ambient=True, shot=0):
        """Raw Bayer mosaic with Poisson-Gaussian noise, black level and clipping.

        Parameters
        ----------
        light : int or None
            0-based light, or None for lights off.
        ambient : bool
            False for a dark frame (no light reaches the sensor).
        shot : int
            Distinguishes repeated frames of the same light; with the scene seed, the light
            and ``ambient`` it seeds the noise, so a frame is reproducible.

        Returns
        -------
        ndarray (H, W) uint16
            RGGB mosaic, black level ``sensor.black``, clipped to ``sensor.white``.
        """
        linear = self.render_linear(light, ambient=ambient)
        return self.mosaic_from_linear(linear, key=(0 if light is None else int(light) + 1,
                                                    int(ambient), int(shot)))

    def mosaic_from_linear(self, linear, key=(0,)):
        """Sample ``linear`` (H, W, 3) through the CFA and add noise (seeded by scene seed,
        scene kind and ``key``). Returns the uint16 (H, W) mosaic."""
        sensor = self.sensor
        cfa = cfa_indices(sensor.cfa)
        h, w = self.shape
        site = np.empty((h, w), np.float64)
        for i in range(2):
            for j in range(2):
                site[i::2, j::2] = linear[i::2, j::2, cfa[i, j]]
        rng = np.random.default_rng([self.seed, _KIND_CODE[self.kind], *key])
        span = sensor.white - sensor.black
        electrons = rng.poisson(np.clip(site, 0, 2.0) * span / sensor.dn_per_electron)
        dn = electrons * sensor.dn_per_electron + rng.normal(sensor.black, sensor.read_noise, (h, w))
        return np.clip(np.rint(dn), 0, sensor.white).astype(np.uint16)

    def render_dng(self, light=None, *, ambient=True, shot=0):
        """The DNG file (bytes) the camera delivers; see :meth:`render_mosaic`."""
        return self.dng_from_mosaic(self.render_mosaic(light, ambient=ambient, shot=shot))

    def dng_from_mosaic(self, mosaic):
        """Encode a mosaic from :meth:`render_mosaic` as DNG bytes (pipeline.core.dng)."""
        s = self.sensor
        return write_dng(mosaic, cfa=s.cfa, black_level=s.black, white_level=s.white)

    # ------------------------------------------------------------------ ground truth
    def truth(self):
        """Ground truth of the scene.

        Returns
        -------
        dict
            normals (H, W, 3) camera frame, mask (H, W) bool, depth (H, W) NaN outside,
            albedo (H, W, 3), directions (K, 3), intensities (K, 3), positions (K, 3) or None;
            for the calibration scene also circles [(cx, cy, r)] in pixels and sphere_kinds.
        """
        g = self.geometry
        out = {"normals": g.normals.copy(), "mask": g.mask.copy(), "depth": g.depth.copy(),
               "albedo": np.where(g.mask[..., None], self.albedo, 0.0),
               "directions": self.directions.copy(), "intensities": self.intensities.copy(),
               "positions": None if self.positions is None else self.positions.copy()}
        if self.kind == "spheres":
            out["circles"] = list(self.circles)
            out["sphere_kinds"] = list(self.sphere_kinds)
        return out

    def write_truth(self, session, folder="truth"):
        """Write the ground truth into ``session`` and record it with ``session.set_truth``.

        Writes ``folder``/normals.exr, normals.png, mask.png, depth.exr, albedo.exr and
        lights.yaml (keys normals, mask, depth, albedo, lights). Returns {key: relative path}.
        """
        truth = self.truth()
        rels = {"normals": f"{folder}/normals.exr", "normals_png": f"{folder}/normals.png",
                "mask": f"{folder}/mask.png", "depth": f"{folder}/depth.exr",
                "albedo": f"{folder}/albedo.exr", "lights": f"{folder}/lights.yaml"}
        write_image(session.path(rels["normals"]), truth["normals"].astype(np.float32))
        write_normal_png(session.path(rels["normals_png"]), truth["normals"], truth["mask"])
        write_mask(session.path(rels["mask"]), truth["mask"])
        write_image(session.path(rels["depth"]), truth["depth"].astype(np.float32))
        write_image(session.path(rels["albedo"]), truth["albedo"].astype(np.float32))
        extra = {"units": "pixels (orthographic camera)", "exposure": float(self.exposure)}
        if self.kind == "spheres":
            extra["circles"] = [list(map(float, c)) for c in self.circles]
        lights = LightSet(truth["directions"], truth["intensities"], positions=truth["positions"],
                          source=f"simulated {self.kind} scene (ground truth)", extra=extra)
        write_lights_yaml(session.path(rels["lights"]), lights)
        for key, rel in rels.items():
            session.set_truth(key, rel, save=False)
        session.save()
        return rels


def _lights(count, directions, intensities, positions, distance, seed):
    """Resolve the light arguments of the constructors into (directions, intensities, positions)."""
    base_dirs, base_int = default_lights(count if directions is None else len(directions), seed)
    if directions is None and positions is not None:
        positions = np.asarray(positions, float)
        directions = positions / np.linalg.norm(positions, axis=1, keepdims=True)
    directions = base_dirs if directions is None else np.asarray(directions, float)
    if intensities is None:
        intensities = base_int
    intensities = np.asarray(intensities, float)
    if intensities.ndim == 1:
        intensities = intensities[:, None]
    if len(intensities) != len(directions):
        raise InputError(f"intensities: {len(intensities)} rows for {len(directions)} lights")
    if positions is None and distance is not None:
        unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        positions = unit * float(distance)
    return directions, intensities, positions
