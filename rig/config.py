"""Rig definitions (``rigs.yaml``): load, validate, and name every bad key.

A rig file looks like::

    default: sim            # optional: the rig used when none is named
    rigs:
      lab1:
        description: dome in room 2.14
        lights: {driver: serial, port: /dev/ttyACM0, count: 32, lp: lab1.lp}
        camera: {driver: ptp, vendor_id: 0x04a9, product_id: 0x32d9, path: canon}
        exposure: {shutter: 1/30, iso: 100}
        frames: {dark: 2, ambient: 1, sphere: true}
        raw_format: dng

Unknown keys are errors, so a typo never passes silently; every error names the file, the rig
and the key. The rig ``sim`` (simulated lights and camera, no hardware) is always defined, with
the defaults below unless the file defines it.

Nominal light geometry, in the camera frame (x right, y up, z toward the camera), exactly one of:
``directions`` (K lists of x, y, z), ``positions`` (K lists, with ``target``, the point they
shine at, default the origin), ``lp`` (an RTI .lp file, relative to the rig file) or ``rings``
(lists of {elevation, count, azimuth} in degrees, elevation above the image plane).
"""

import functools
import os
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import yaml

from pipeline.core.errors import InputError
from pipeline.core.lightsio import LightSet, read_lp
from pipeline.core.yamlio import load_yaml, plain
from rig import checks
from rig.checks import ConfigError
from rig.drivers import SHARED_LIGHT_KEYS, camera_driver, light_driver

__all__ = ["ConfigError", "RigConfig", "Section", "LightsConfig", "CameraConfig", "FramesConfig",
           "load_rigs", "get_rig", "find_rigs_file", "parse_rigs", "default_rig_name", "ring_directions",
           "builtin_rigs", "exposure_shutters", "SIM_RIGS_FILE", "RAW_FORMATS", "CAMERA_PATHS",
           "PREVIEW_DEFAULTS"]

RAW_FORMATS = ("dng", "cr2", "cr3", "nef", "nrw", "arw", "raf", "orf", "rw2", "pef")
CAMERA_PATHS = ("generic", "canon", "nikon", "auto")
SIM_RIGS_FILE = Path(__file__).resolve().parent / "sim" / "rigs.yaml"
"""The simulated rigs (``sim``, ``sim-near``): always defined; a rig file may override them."""
PREVIEW_DEFAULTS = {"check": True, "max_clipped": 0.01, "light": "auto"}
"""A rig's ``preview:``: capture first previews its brightest light and refuses to start when
more than ``max_clipped`` of any colour channel's photosites are clipped (see rig.preview)."""

_PACKAGE_DIR = Path(__file__).resolve().parent
_ENV_VAR = "PSRIG_RIGS"


class Section(dict):
    """A validated section: a plain dict (drivers take it as is) with attribute access too."""

    def __getattr__(self, name):
        try:
            return self[name]
        except KeyError:
            raise AttributeError(f"{type(self).__name__} has no key {name!r}") from None

    def to_dict(self):
        """Plain YAML-friendly dict (arrays as lists, paths as strings)."""
        return plain(self, 9)


class LightsConfig(Section):
    """A rig's ``lights:`` section (see :func:`rig.drivers.make_light_controller`).

    Always holds ``driver``, ``count``, ``directions`` (K, 3) unit vectors toward the lights
    (camera frame), ``positions`` (K, 3) or None, ``levels`` (K ints 0-255, or None: leave the
    controller's), ``lp`` (path or None) and the driver's own keys with their defaults.
    """


class CameraConfig(Section):
    """A rig's ``camera:`` section: ``driver`` and the driver's own keys (what it builds from)."""


class FramesConfig(Section):
    """A rig's ``frames:`` section: ``dark``, ``ambient`` (frame counts), ``sphere`` and
    ``outline`` (bools: an evenly room-lit photo of the spheres after their frames)."""

    DEFAULTS = {"dark": 1, "ambient": 0, "sphere": True, "outline": False}


@dataclass
class RigConfig:
    """One validated rig. ``exposure``, ``scene`` and ``preview`` are dicts; ``source`` the rig
    file."""

    name: str
    lights: LightsConfig
    camera: CameraConfig
    exposure: dict = field(default_factory=dict)
    frames: FramesConfig = field(default_factory=lambda: FramesConfig(FramesConfig.DEFAULTS))
    raw_format: str = "dng"
    description: str = ""
    scene: dict = field(default_factory=dict)
    preview: dict = field(default_factory=lambda: dict(PREVIEW_DEFAULTS))
    source: str = "(built in)"

    @property
    def is_simulated(self):
        """True when neither lights nor camera need hardware."""
        return self.lights.driver == "sim" and self.camera.driver == "sim"

    @property
    def simulated_camera(self):
        """True when the camera is simulated (the simulated rig renders what it sees)."""
        return self.camera.driver == "sim"

    def __getitem__(self, key):
        if key not in {f.name for f in fields(self)}:
            raise KeyError(key)
        return getattr(self, key)

    def to_dict(self):
        """The whole rig as a plain YAML-friendly dict."""
        return {f.name: plain(getattr(self, f.name), 9) for f in fields(self)}

    def light_set(self):
        """The nominal lights as a :class:`pipeline.core.lightsio.LightSet` (intensities 1)."""
        return LightSet(self.lights.directions.copy(), positions=self.lights.positions,
                        source=f"nominal, rig '{self.name}' ({self.source})")


def exposure_shutters(exposure):
    """The shutter times (s) a rig's ``exposure:`` shoots each frame at: the ``bracket`` list,
    else ``[shutter]``, else ``[]`` (the camera's own)."""
    from rig.exposure import parse_shutter

    if exposure.get("bracket"):
        return [parse_shutter(v) for v in exposure["bracket"]]
    return [parse_shutter(exposure["shutter"])] if exposure.get("shutter") is not None else []


def _rings(value):
    if not isinstance(value, list) or not value:
        raise ValueError("expected a list of {elevation, count, azimuth}")
    for ring in value:
        if not isinstance(ring, dict) or not {"elevation", "count"} <= set(ring) \
                or not set(ring) <= {"elevation", "count", "azimuth"}:
            raise ValueError("expected a list of {elevation, count, azimuth}")
        checks.number(-90.0)(ring["elevation"])
        checks.integer(1)(ring["count"])
        checks.number(-360.0)(ring.get("azimuth", 0.0))
    return value


def _levels(value):
    if not isinstance(value, list) or not value:
        raise ValueError("expected a list of levels 0-255, one per light")
    return [checks.integer(0, 255)(v) for v in value]


_LIGHT_KEYS = {"driver": checks.text, "count": checks.integer(1, 4096),
               "directions": checks.vectors, "positions": checks.vectors,
               "target": checks.vector, "lp": checks.text, "rings": _rings, "levels": _levels}
assert set(_LIGHT_KEYS) == set(SHARED_LIGHT_KEYS)
_FRAME_KEYS = {"dark": checks.integer(0, 1000), "ambient": checks.integer(0, 1000),
               "sphere": checks.boolean, "outline": checks.boolean}
_PREVIEW_KEYS = {"check": checks.boolean, "max_clipped": checks.number(0.0),
                 "light": lambda v: v if v == "auto" else checks.integer(0)(v)}
_RIG_KEYS = ("description", "lights", "camera", "exposure", "frames", "raw_format", "scene",
             "preview")
_GEOMETRY = ("directions", "positions", "lp", "rings")


def ring_directions(rings):
    """Unit directions (K, 3) of lights on rings; elevation above the image plane, degrees.

    Azimuth 0 is +x (image right), 90 is +y (image up); z points toward the camera.
    """
    dirs = []
    for ring in rings:
        elevation = np.radians(ring["elevation"])
        azimuth = np.radians(ring.get("azimuth", 0.0) + 360.0 * np.arange(ring["count"]) / ring["count"])
        dirs.append(np.stack([np.cos(elevation) * np.cos(azimuth),
                              np.cos(elevation) * np.sin(azimuth),
                              np.full(ring["count"], np.sin(elevation))], axis=1))
    return np.concatenate(dirs)


class _Checker:
    """Validates one rig, prefixing every message with the file, the rig and the key."""

    def __init__(self, source, name):
        self.source, self.name = source, name

    def fail(self, key, message):
        raise ConfigError(f"{self.source}: rig '{self.name}': {key}: {message}")

    def section(self, data, section, schema, required=()):
        if not isinstance(data, dict):
            self.fail(section, f"expected a mapping of keys, got {data!r}")
        for key in data:
            if key not in schema:
                self.fail(f"{section}.{key}", f"unknown key (known: {', '.join(schema)})")
        for key in required:
            if data.get(key) is None:
                self.fail(f"{section}.{key}", "missing")
        return {key: self.value(f"{section}.{key}", schema[key], value)
                for key, value in data.items() if value is not None}

    def driver(self, section, lookup, name):
        """The driver ``name`` of ``section`` (its lookup error named by the key)."""
        try:
            return lookup(name)
        except ConfigError as exc:
            self.fail(f"{section}.driver", str(exc))

    def value(self, key, checker, value):
        try:
            return checker(value)
        except ValueError as exc:
            self.fail(key, f"{exc}, got {value!r}")


def _geometry(check, lights, base_dir):
    """Resolve the nominal directions (and positions) of a validated ``lights`` dict."""
    given = [key for key in _GEOMETRY if key in lights]
    if len(given) != 1:
        check.fail("lights", "give exactly one of directions, positions, lp, rings"
                   + (f" (got {', '.join(given)})" if given else ""))
    if "target" in lights and given != ["positions"]:
        check.fail("lights.target", "only meaningful with lights.positions")
    key, positions = given[0], None
    if key == "directions":
        directions = lights["directions"]
    elif key == "positions":
        positions = lights["positions"]
        directions = positions - lights.get("target", np.zeros(3))
    elif key == "rings":
        directions = ring_directions(lights["rings"])
    else:
        lights["lp"] = (Path(base_dir) / lights["lp"]) if base_dir else Path(lights["lp"])
        try:
            directions = read_lp(lights["lp"])[1]
        except (InputError, OSError) as exc:
            check.fail("lights.lp", f"cannot read the .lp file: {exc}")
    norms = np.linalg.norm(directions, axis=1)
    if (norms < 1e-9).any():
        check.fail(f"lights.{key}", f"light {int(np.argmax(norms < 1e-9))} has no direction")
    count = lights.get("count", len(directions))
    if count != len(directions):
        check.fail("lights.count", f"{count} lights, but lights.{key} gives {len(directions)}")
    lights.update(count=count, directions=directions / norms[:, None], positions=positions)
    lights.pop("rings", None)
    lights.pop("target", None)
    return lights


def _lights(check, data, base_dir):
    if not isinstance(data, dict):
        check.fail("lights", f"expected a mapping of keys, got {data!r}")
    shared = {key: value for key, value in data.items() if key in _LIGHT_KEYS}
    lights = check.section(shared, "lights", _LIGHT_KEYS, required=("driver",))
    driver = check.driver("lights", light_driver, lights["driver"])
    own = driver.validate({k: v for k, v in data.items() if k not in _LIGHT_KEYS},
                          lambda key, message: check.fail(f"lights.{key}", message))
    lights = _geometry(check, lights, base_dir)
    levels = lights.get("levels")
    if levels is not None and len(levels) != lights["count"]:
        check.fail("lights.levels", f"{len(levels)} levels for {lights['count']} lights")
    return LightsConfig({"lp": None, "levels": None, **own, **lights})


def _camera(check, data):
    if not isinstance(data, dict):
        check.fail("camera", f"expected a mapping of keys, got {data!r}")
    name = check.value("camera.driver", checks.text, data.get("driver"))
    driver = check.driver("camera", camera_driver, name)
    own = driver.validate({k: v for k, v in data.items() if k != "driver"},
                          lambda key, message: check.fail(f"camera.{key}", message))
    return CameraConfig({"driver": name, **own})


def _combination(check, rig):
    """Refuse driver combinations that cannot work, and exposures a light cannot cover."""
    lights = light_driver(rig.lights.driver)
    if rig.simulated_camera and not lights.reports_lit:
        check.fail("camera.driver", f"a simulated camera renders the light its controller "
                   f"reports lit; the {lights.name!r} light driver does not report it "
                   "(use lights.driver: sim, or a real camera)")
    if rig.scene and not rig.simulated_camera:
        check.fail("scene", "only a simulated camera (camera.driver: sim) has a scene")
    if rig.name in ("sim", "sim-near") and not rig.is_simulated:
        check.fail("lights.driver" if rig.lights.driver != "sim" else "camera.driver",
                   f"the rig '{rig.name}' must need no hardware (driver: sim)")
    watchdog = lights.watchdog(rig.lights)
    longest = max(exposure_shutters(rig.exposure), default=0.0)
    if watchdog and longest >= watchdog and not lights.keepalive:
        check.fail("exposure.bracket" if rig.exposure.get("bracket") else "exposure.shutter",
                   f"{longest:g} s exposures outlast the {watchdog:g} s watchdog of the "
                   f"{lights.name!r} light controller, which cannot be kept alive: its light "
                   "would go out during the exposure")


def _exposure(check, data):
    """The ``exposure:`` section: shutter (s) or bracket (a list of shutters), iso, aperture
    (f-number), each parseable.

    Values stay as written (e.g. '1/30'): the camera driver matches them to what it allows.
    """
    from rig.exposure import EXPOSURE_KEYS, PARSERS, parse_shutter

    exposure = check.value("exposure", checks.mapping, data)
    for key, value in exposure.items():
        if key == "bracket":
            _bracket(check, exposure)
            continue
        if key not in PARSERS:
            check.fail(f"exposure.{key}", f"unknown key (known: {', '.join(EXPOSURE_KEYS)}, bracket)")
        try:
            PARSERS[key](value)
        except ValueError as exc:
            check.fail(f"exposure.{key}", str(exc).split(": ", 1)[-1])
    return exposure


def _bracket(check, exposure):
    from rig.exposure import parse_shutter

    bracket = exposure["bracket"]
    if "shutter" in exposure:
        check.fail("exposure.bracket", "give shutter or bracket, not both")
    if not isinstance(bracket, list) or len(bracket) < 2:
        check.fail("exposure.bracket", f"expected a list of 2 or more shutter times (e.g. "
                                       f"[1/60, 1/15]), got {bracket!r}")
    try:
        seconds = [parse_shutter(value) for value in bracket]
    except ValueError as exc:
        check.fail("exposure.bracket", str(exc).split(": ", 1)[-1])
    if len(set(seconds)) != len(seconds):
        check.fail("exposure.bracket", f"the same shutter time twice in {bracket!r}")


def _rig(source, name, data, base_dir):
    check = _Checker(source, name)
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: rig '{name}': expected a mapping of keys, got {data!r}")
    for key in data:
        if key not in _RIG_KEYS:
            check.fail(key, f"unknown key (known: {', '.join(_RIG_KEYS)})")
    for key in ("lights", "camera"):
        if data.get(key) is None:
            check.fail(key, "missing")
    rig = RigConfig(
        name=name, source=str(source),
        lights=_lights(check, data["lights"], base_dir),
        camera=_camera(check, data["camera"]),
        exposure=_exposure(check, data.get("exposure") or {}),
        frames=FramesConfig({**FramesConfig.DEFAULTS,
                             **check.section(data.get("frames") or {}, "frames", _FRAME_KEYS)}),
        raw_format=check.value("raw_format", checks.choice(*RAW_FORMATS), data.get("raw_format", "dng")),
        description=check.value("description", str, data.get("description") or ""),
        scene=check.value("scene", checks.mapping, data.get("scene") or {}),
        preview={**PREVIEW_DEFAULTS,
                 **check.section(data.get("preview") or {}, "preview", _PREVIEW_KEYS)})
    _combination(check, rig)
    return rig


# -- the file ------------------------------------------------------------------------------------

class _StrictLoader(yaml.SafeLoader):
    """Safe YAML that refuses duplicate keys (a second ``lab1:`` would silently replace the first)."""


def _no_duplicates(loader, node, deep=False):
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise ConfigError(f"line {key_node.start_mark.line + 1}: key {key!r} appears twice")
        seen.add(key)
    return loader.construct_mapping(node, deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _no_duplicates)


def find_rigs_file(path=None):
    """The rig file to read: ``path``; else $PSRIG_RIGS; else ./rigs.yaml; else the shipped one.

    The shipped one is the repository's ``rigs.yaml`` (examples of real rigs) beside the
    ``rig`` package when present (an editable install). Returns None when there is none: the
    simulated rigs are defined all the same.
    """
    if path is not None:
        return Path(path)
    if os.environ.get(_ENV_VAR):
        return Path(os.environ[_ENV_VAR])
    for candidate in (Path.cwd() / "rigs.yaml", _PACKAGE_DIR.parent / "rigs.yaml"):
        if candidate.is_file():
            return candidate
    return None


def parse_rigs(text, source="rigs.yaml", base_dir=None):
    """Validate rig-file text; returns {name: RigConfig}, always including the simulated
    rigs of :data:`SIM_RIGS_FILE` (``sim``, ``sim-near``) unless the text redefines them.

    ``source`` names the file in messages; ``base_dir`` resolves relative ``lp`` paths.
    """
    try:
        data = load_yaml(text, loader=_StrictLoader)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML: {exc}") from None
    data = {} if data is None else data
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping with the key 'rigs'")
    unknown = set(data) - {"rigs", "default"}
    if unknown:
        raise ConfigError(f"{source}: {sorted(unknown)[0]}: unknown top-level key (known: rigs, default)")
    rigs_data = data.get("rigs") or {}
    if not isinstance(rigs_data, dict):
        raise ConfigError(f"{source}: rigs: expected a mapping of rig names to rigs")
    rigs = {}
    for name, rig_data in rigs_data.items():
        if not isinstance(name, str) or not name.strip() or any(c.isspace() for c in name):
            raise ConfigError(f"{source}: rigs: {name!r} is not a valid rig name (no spaces)")
        rigs[name] = _rig(source, name, rig_data, base_dir)
    if source != str(SIM_RIGS_FILE):  # the simulated rigs, unless this file redefines them
        rigs.update({name: rig for name, rig in builtin_rigs().items() if name not in rigs})
    default = data.get("default")
    if default is not None and default not in rigs:
        raise ConfigError(f"{source}: default: no rig named {default!r} (rigs: {', '.join(rigs)})")
    return rigs


@functools.lru_cache(maxsize=1)
def _builtin_rig_text():
    return SIM_RIGS_FILE.read_text(encoding="utf-8")


def builtin_rigs():
    """The simulated rigs shipped with psrig (``rig/sim/rigs.yaml``): {name: RigConfig}."""
    return parse_rigs(_builtin_rig_text(), source=str(SIM_RIGS_FILE), base_dir=SIM_RIGS_FILE.parent)


def load_rigs(path=None):
    """Load and validate a rig file (see :func:`find_rigs_file`); returns {name: RigConfig}.

    The simulated rigs are always present, even without any file.
    """
    found = find_rigs_file(path)
    if found is None:
        return parse_rigs("")
    try:
        text = found.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{found}: cannot read the rig file: {exc}") from None
    return parse_rigs(text, source=str(found), base_dir=found.parent)


def default_rig_name(path=None):
    """The rig file's ``default:`` rig, or ``sim`` when it names none."""
    found = find_rigs_file(path)
    data = load_yaml(found.read_text(encoding="utf-8")) if found and found.is_file() else None
    load_rigs(path)  # the whole file must be valid before any of it is used
    return (data or {}).get("default") or "sim"


def get_rig(name, path=None):
    """The validated rig ``name`` from the rig file; ConfigError naming the file if missing."""
    rigs = load_rigs(path)
    if name not in rigs:
        source = find_rigs_file(path) or "(built in)"
        raise ConfigError(f"{source}: no rig named {name!r} (rigs: {', '.join(rigs)})")
    return rigs[name]
