"""The simulated rig: simulated light firmware + simulated PTP camera + the scenes they see.

:class:`SimulatedRig` assembles, from a rig definition (``rig.config.RigConfig``, normally the
``sim`` rig), everything a capture needs without hardware:

- a :class:`rig.sim.firmware.SimulatedLightFirmware` on a pseudo-terminal and the real serial
  driver (:class:`rig.lights.SimLightController`, a ``SerialLightController``) opened on it;
- a :class:`rig.camera.PtpCamera` on the simulated USB camera backend, whose sensor renders the
  current scene under the light the firmware has lit (``firmware.lit``; None: lights off);
- the object scene and the calibration scene (two chrome spheres, a matte sphere), built with
  the SAME true lights: the rig's nominal directions each tilted by ``light_jitter_deg`` about a
  seeded random axis (so nominal != true and calibration matters), with unequal intensities
  from :func:`rig.sim.scene.default_lights`.

The rig's ``scene:`` section may hold:

``shape``            [H, W] sensor size in pixels (even numbers; default 360 x 480)
``seed``             integer seeding light jitter, intensities and sensor noise (default 0)
``light_jitter_deg`` tilt of each true light away from its nominal direction (default 1.5)
``distance``         near point lights at ``true direction * distance`` (pixels); default none
``exposure_seconds`` real seconds each exposure takes, whatever the shutter (default: see below)
``time_scale``       simulated seconds per real second of the devices' shared clock (default 1):
                     at 40, an 8 s exposure and the firmware's 5 s watchdog take 0.2 s and
                     0.125 s, so long exposures are tested quickly
``nd_stops``         a neutral-density filter on the lens: the light is divided by 2**nd_stops
                     (default 0), so a long exposure need not clip

The rig's ``exposure:`` section is set on the simulated camera like on a real one; the sensor
then collects light in proportion to the shutter time the camera was set to, relative to its
factory default (1/30 s): 1/15 s doubles the signal (clipped at white). An exposure then lasts
the shutter time on the simulated clock, and the image integrates what the firmware actually
lit during it, at each light's level (``LEVEL``): a light the watchdog cut after 5 s of an 8 s
exposure gives 5/8 of its signal, a light off all along a dark frame. Without an ``exposure:``
key nothing is set, exposures are instantaneous (what is lit when the camera fires) and the
images are exactly those of earlier versions.

Faults for tests are ``{name: count}`` (or the text ``"busy:2,garble:1@object_005"`` parsed by
:func:`parse_faults`). Light faults: drop_reply, garble, err, interlock, ``light.disconnect``;
camera faults: busy, timeout, truncated, session_open, claimed, no_event, new_folder,
stale_response, kernel_driver, ``camera.disconnect``. Any name may carry a ``light.`` or
``camera.`` prefix; ``disconnect`` alone is ambiguous and refused. A fault armed ``@FRAME`` (a
frame id) waits until :meth:`SimulatedRig.before_frame` announces that frame; the others are
armed from the start (so they also meet the devices' opening handshakes).
"""

from __future__ import annotations

import time
import zlib

import numpy as np

from pipeline.core.atomic import atomic_write_text
from rig.camera import PtpCamera
from rig.config import ConfigError
from rig.drivers import make_light_controller
from rig.lights import LightError, SimLightController
from rig.sim import firmware as _firmware
from rig.sim import usb_camera as _usb_camera
from rig.sim.clock import SimClock
from rig.sim.firmware import SimulatedLightFirmware
from rig.sim.scene import DEFAULT_SHAPE, Scene, default_lights

__all__ = ["SimulatedRig", "SCENE_KEYS", "SCENES", "parse_faults", "split_faults", "jitter_directions"]

SCENE_KEYS = ("shape", "seed", "light_jitter_deg", "distance", "exposure_seconds", "time_scale",
              "nd_stops")
SCENES = ("object", "sphere", "dark", "outline")
SPHERES_TRUTH = "truth/spheres.yaml"
_CAMERA_OPTIONS = ("timeout", "busy_retries", "busy_backoff", "chunk_size", "delete_after_download")
_LIGHT_OPTIONS = ("timeout", "write_timeout", "retries")


# -- faults --------------------------------------------------------------------------------------

def parse_faults(text):
    """Parse ``"busy:2,garble:1@object_005"`` into ``{(name, frame or None): count}``.

    ``name`` alone means a count of 1; ``@FRAME`` delays the fault until that frame.
    """
    faults = {}
    for item in filter(None, (part.strip() for part in str(text or "").split(","))):
        spec, _, frame = item.partition("@")
        name, _, count = spec.partition(":")
        try:
            count = int(count) if count else 1
        except ValueError:
            raise ConfigError(f"faults: {item!r}: the count after ':' must be an integer") from None
        key = (name.strip(), frame.strip() or None)
        faults[key] = faults.get(key, 0) + count
    return faults


def split_faults(faults):
    """Sort faults by device.

    Parameters
    ----------
    faults : dict
        ``{name: count}`` or ``{(name, frame or None): count}`` (see :func:`parse_faults`).

    Returns
    -------
    dict
        ``{frame or None: {"light": {kind: count}, "camera": {kind: count}}}``.
    """
    out = {}
    for key, count in (faults or {}).items():
        name, frame = key if isinstance(key, tuple) else (key, None)
        device, kind = _fault_device(name)
        slot = out.setdefault(frame, {"light": {}, "camera": {}})[device]
        slot[kind] = slot.get(kind, 0) + int(count)
    return out


def _fault_device(name):
    prefix, _, kind = str(name).rpartition(".")
    light, camera = kind in _firmware.FAULT_KINDS, kind in _usb_camera.FAULT_KINDS
    if prefix in ("light", "lights") and light:
        return "light", kind
    if prefix == "camera" and camera:
        return "camera", kind
    if not prefix and light != camera:
        return ("light" if light else "camera"), kind
    if not prefix and light and camera:
        raise ConfigError(f"faults: {name!r} exists for the lights and the camera; "
                          f"write light.{kind} or camera.{kind}")
    known = sorted(set(_firmware.FAULT_KINDS) ^ set(_usb_camera.FAULT_KINDS))
    raise ConfigError(f"faults: unknown fault {name!r} (known: {', '.join(known)}, "
                      f"light.disconnect, camera.disconnect)")


# -- scene settings ------------------------------------------------------------------------------

def _scene_settings(rig_config):
    """Validated ``scene:`` keys of the rig (ConfigError naming the key)."""
    scene = dict(rig_config.scene or {})
    where = f"{rig_config.source}: rig '{rig_config.name}': scene"
    for key in scene:
        if key not in SCENE_KEYS:
            raise ConfigError(f"{where}.{key}: unknown key (known: {', '.join(SCENE_KEYS)})")
    shape = scene.get("shape", list(DEFAULT_SHAPE))
    if (not isinstance(shape, (list, tuple)) or len(shape) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 32 and v % 2 == 0
                       for v in shape)):
        raise ConfigError(f"{where}.shape: expected [H, W], even integers >= 32, got {shape!r}")
    seed = scene.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{where}.seed: expected an integer >= 0, got {seed!r}")
    numbers = {}
    for key, default, low in (("light_jitter_deg", 1.5, 0.0), ("distance", None, 1e-9),
                              ("exposure_seconds", 0.0, 0.0), ("time_scale", 1.0, 1e-3),
                              ("nd_stops", 0.0, 0.0)):
        value = scene.get(key, default)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not np.isfinite(value) or value < low):
            raise ConfigError(f"{where}.{key}: expected a number >= {low:g}, got {value!r}")
        numbers[key] = None if value is None else float(value)
    return {"shape": tuple(shape), "seed": seed, **numbers}


def jitter_directions(directions, degrees, seed):
    """Tilt each unit vector by ``degrees`` about a seeded random axis perpendicular to it.

    Parameters
    ----------
    directions : array (K, 3)
        Unit vectors toward the lights, camera frame.
    degrees : float
        Tilt of every light, degrees (exactly this angle between input and output).
    seed : int

    Returns
    -------
    ndarray (K, 3)
        Unit vectors.
    """
    d = np.asarray(directions, float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    rng = np.random.default_rng([seed, 11])
    # Any vector not parallel to d gives a perpendicular; a random one gives a random azimuth.
    axis = np.cross(d, rng.normal(size=d.shape))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.radians(degrees)
    return np.cos(angle) * d + np.sin(angle) * np.cross(axis, d)


# -- the rig -------------------------------------------------------------------------------------

class SimulatedRig:
    """A whole simulated rig; use as a context manager (or :meth:`open` / :meth:`close`).

    Parameters
    ----------
    rig_config : rig.config.RigConfig
        The rig (normally ``sim``); its ``lights`` give the count and nominal directions, its
        ``camera`` the PTP path (generic, canon, nikon) and driver options, its ``scene`` the
        scene settings (see the module docstring).
    behaviour : str, optional
        Camera protocol; default the rig's ``camera.path`` (``auto`` -> generic).
    faults : dict or str, optional
        Faults to inject (see the module docstring).
    seed : int, optional
        Overrides the rig's ``scene.seed``.

    Attributes
    ----------
    lights : rig.lights.SimLightController
        The real serial driver, open on the firmware's pty while the rig is open.
    camera : rig.camera.PtpCamera
    firmware : SimulatedLightFirmware
    backend : rig.sim.usb_camera.SimulatedUsbBackend
    true_lights : dict
        ``directions`` (K, 3), ``intensities`` (K, 3), ``positions`` (K, 3) or None.
    scenes : dict
        ``{'object': Scene, 'sphere': Scene}``.
    scene : str
        The current scene, one of :data:`SCENES`.
    """

    def __init__(self, rig_config, *, behaviour=None, faults=None, seed=None):
        self.config = rig_config
        self.settings = _scene_settings(rig_config)
        if seed is not None:
            self.settings["seed"] = int(seed)
        path = rig_config.camera.get("path", "generic")
        self.behaviour = behaviour or ("generic" if path == "auto" else path)
        faults = parse_faults(faults) if isinstance(faults, str) else faults
        self._faults = split_faults(faults)
        start = self._faults.pop(None, {"light": {}, "camera": {}})
        self.true_lights = self._make_true_lights()
        self.scenes = self._make_scenes()
        self.scene, self.shot, self._shots = "object", None, 0
        self.last_weights = {}  # what the last exposure saw lit: {light: weight}
        self.clock = SimClock(self.settings["time_scale"])
        self.backend = _usb_camera.make_backend(self._render, behaviour=self.behaviour,
                                                faults=start["camera"])
        self.firmware, self.lights = self._make_lights(start["light"])
        cam_options = {k: rig_config.camera[k] for k in _CAMERA_OPTIONS if k in rig_config.camera}
        self.camera = PtpCamera(backend=self.backend, path=self.behaviour, **cam_options)
        self.is_open = False

    def __repr__(self):
        return f"SimulatedRig({self.config.name!r}, {len(self.true_lights['directions'])} lights)"

    # -- building ------------------------------------------------------------------------------
    def _make_lights(self, faults):
        """(firmware or None, controller): the simulated firmware and the serial driver on it,
        or, for a rig whose lights are real, that rig's own controller (no firmware)."""
        config = self.config.lights
        if config.driver != "sim":
            if faults:
                raise ConfigError(f"faults: light faults ({', '.join(faults)}) need simulated "
                                  f"lights; rig '{self.config.name}' has {config.driver!r} lights")
            return None, make_light_controller(config)
        firmware = SimulatedLightFirmware(config.count, faults=faults,
                                          watchdog=config.get("watchdog", 5.0), clock=self.clock)
        options = {k: config[k] for k in _LIGHT_OPTIONS if config.get(k) is not None}
        return firmware, SimLightController(config.count, firmware=firmware, reset_delay=0.0,
                                            **options)

    def _make_true_lights(self):
        s, count = self.settings, self.config.lights.count
        directions = jitter_directions(self.config.lights.directions, s["light_jitter_deg"], s["seed"])
        intensities = default_lights(count, s["seed"])[1]
        positions = None if s["distance"] is None else directions * s["distance"]
        return {"directions": directions, "intensities": intensities, "positions": positions}

    def _make_scenes(self):
        s, t = self.settings, self.true_lights
        common = dict(directions=t["directions"], intensities=t["intensities"],
                      positions=t["positions"], seed=s["seed"])
        return {"object": Scene.default_object(s["shape"], **common),
                "sphere": Scene.default_spheres(s["shape"], **common)}

    # -- life cycle ----------------------------------------------------------------------------
    def open(self):
        """Start the firmware, open the light driver on it and the camera; returns self."""
        if self.is_open:
            return self
        if self.firmware is not None:
            self.firmware.start()
        try:
            self.lights.open()
            self.camera.open()
        except BaseException:
            self.close()
            raise
        self.is_open = True
        return self

    def close(self):
        """Lights OFF (when still reachable), close the camera and the port, stop the firmware."""
        try:
            if self.lights.is_open:
                self.lights.off()
        except LightError:
            pass  # stopping the firmware below darkens every light anyway
        finally:
            self.lights.close()
            self.camera.close()
            if self.firmware is not None:
                self.firmware.stop()
            self.is_open = False

    def __enter__(self):
        return self.open()

    def __exit__(self, exc_type, exc, tb):
        self.close()
        return False

    # -- scenes and frames ---------------------------------------------------------------------
    def scene_for(self, kind):
        """The scene a frame kind is shot in: 'dark', 'sphere', 'outline' or 'object'."""
        return {"dark": "dark", "sphere": "sphere", "target": "sphere", "outline": "outline"}.get(kind, "object")

    def set_scene(self, name):
        """Switch what the camera sees: 'object', 'sphere', 'dark' (no light reaches it) or
        'outline' (the sphere scene lit evenly by the room, the rig's lights off)."""
        if name not in SCENES:
            raise ValueError(f"unknown scene {name!r}; expected one of {', '.join(SCENES)}")
        self.scene = name

    def before_frame(self, frame_id, kind=None):
        """Announce the next frame: seeds its noise from its id and arms faults set ``@frame_id``."""
        if kind is not None:
            self.set_scene(self.scene_for(kind))
        self.shot = zlib.crc32(str(frame_id).encode())
        armed = self._faults.pop(frame_id, None)
        if armed:
            for kind_, count in armed["light"].items():
                if self.firmware is None:
                    raise ConfigError(f"faults: light fault {kind_!r} needs simulated lights")
                self.firmware.inject(kind_, count)
            for kind_, count in armed["camera"].items():
                self.backend.inject(kind_, count)

    def _exposure_seconds(self):
        """Simulated seconds the next exposure lasts: the camera's shutter time when the rig
        sets an exposure, else 0 (instantaneous, as before exposure control)."""
        exposure = self.config.exposure or {}
        if "shutter" in exposure or "bracket" in exposure:
            return self.backend.camera.shutter_seconds()
        return 0.0

    def _expose(self):
        """Hold the shutter open; returns ``{light: weight}`` of what was lit meanwhile."""
        if self.firmware is None:  # real lights: the light their controller confirmed on
            lit = getattr(self.lights, "lit", None)
            if self.settings["exposure_seconds"]:
                time.sleep(self.settings["exposure_seconds"])
            else:
                self.clock.sleep(self._exposure_seconds())
            return {} if lit is None else {lit: 1.0}
        if self.settings["exposure_seconds"]:
            start = self.clock.now()
            time.sleep(self.settings["exposure_seconds"])
            return self.firmware.light_weights(start, start)  # lit when the shutter opened
        start = self.clock.now()
        self.clock.sleep(self._exposure_seconds())
        return self.firmware.light_weights(start, self.clock.now())

    def _render(self):
        """What the sensor records now: the current scene under what the firmware lit during
        the exposure (see the module docstring)."""
        if self.shot is None:  # no frame announced: still give each exposure its own noise
            self._shots += 1
        shot = self.shot if self.shot is not None else self._shots
        weights = self._expose()
        self.last_weights = weights
        gain = self.backend.camera.exposure_gain() * 2.0 ** -self.settings["nd_stops"]
        if self.scene == "outline":
            scene = self.scenes["sphere"]
            linear = scene.render_room() * np.float32(gain)
            # noise key (light, ambient flag, shot) as below; ambient 2 keeps it apart from theirs
            return scene.dng_from_mosaic(scene.mosaic_from_linear(linear, key=(0, 2, int(shot))))
        scene, ambient = self.scenes["object" if self.scene == "dark" else self.scene], True
        if self.scene == "dark":
            weights, ambient = {}, False
        light = max(weights, key=weights.get) if weights else None
        if gain == 1.0 and weights in ({}, {light: 1.0}):
            # one light at full level all along, factory shutter: bit-identical to the images
            # before exposure control
            return scene.render_dng(light, ambient=ambient, shot=shot)
        # light collected scales with the shutter time and with each light's lit share and
        # level; noise and clipping act on the result
        linear = scene.render_linear(None, ambient=ambient)
        for index, weight in weights.items():
            linear += np.float32(weight) * scene.render_linear(index, ambient=False)
        linear *= np.float32(gain)
        key = (0 if light is None else int(light) + 1, int(ambient), int(shot))
        return scene.dng_from_mosaic(scene.mosaic_from_linear(linear, key=key))

    # -- ground truth --------------------------------------------------------------------------
    def write_truth(self, session):
        """Write ground truth into ``session``: the object scene's (normals, mask, depth,
        albedo, TRUE lights; see ``Scene.write_truth``) and the calibration scene's spheres in
        ``truth/spheres.yaml`` (truth key ``spheres``). Returns {key: relative path}."""
        import yaml

        rels = self.scenes["object"].write_truth(session)
        sphere = self.scenes["sphere"]
        data = {"circles": [[round(float(v), 6) for v in c] for c in sphere.circles],
                "sphere_kinds": list(sphere.sphere_kinds),
                "shape": list(sphere.shape), "units": "pixels: cx, cy (column, row of the centre), r",
                "light_jitter_deg": self.settings["light_jitter_deg"], "seed": self.settings["seed"]}
        atomic_write_text(session.path(SPHERES_TRUTH), yaml.safe_dump(data, sort_keys=False))
        session.set_truth("spheres", SPHERES_TRUTH)
        return {**rels, "spheres": SPHERES_TRUTH}
