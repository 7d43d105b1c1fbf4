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

import os
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import yaml

from pipeline.errors import InputError, PsrigError
from pipeline.lightsio import LightSet, read_lp
from pipeline.yamlio import load_yaml, plain

__all__ = ["ConfigError", "RigConfig", "Section", "LightsConfig", "CameraConfig", "FramesConfig",
           "load_rigs", "get_rig", "find_rigs_file", "parse_rigs", "default_rig_name", "ring_directions",
           "SIM_RINGS", "RAW_FORMATS", "CAMERA_PATHS"]

RAW_FORMATS = ("dng", "cr2", "cr3", "nef", "nrw", "arw", "raf", "orf", "rw2", "pef")
CAMERA_PATHS = ("generic", "canon", "nikon", "auto")
SIM_RINGS = ({"elevation": 30, "count": 8, "azimuth": 0.0},
             {"elevation": 45, "count": 8, "azimuth": 22.5},
             {"elevation": 60, "count": 8, "azimuth": 0.0},
             {"elevation": 75, "count": 8, "azimuth": 22.5})
"""The sim rig's 32 lights: four rings of 8, alternate rings turned by half a step."""

_PACKAGE_DIR = Path(__file__).resolve().parent
_ENV_VAR = "PSRIG_RIGS"


class ConfigError(PsrigError):
    """A rig file or rig definition is invalid; the message names the file, rig and key."""


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
    """A rig's ``lights:`` section (see :func:`rig.lights.make_light_controller`).

    Always holds ``driver``, ``count``, ``directions`` (K, 3) unit vectors toward the lights
    (camera frame), ``positions`` (K, 3) or None, and the serial options with their defaults.
    """

    DEFAULTS = {"port": None, "baudrate": 115200, "protocol": "psrig-1", "timeout": 1.0,
                "write_timeout": 1.0, "reset_delay": 2.0, "retries": 1, "positions": None,
                "lp": None, "watchdog": 5.0, "boot_delay": 0.0}


class CameraConfig(Section):
    """A rig's ``camera:`` section, exactly the keys given (what :func:`rig.camera.make_camera` takes)."""


class FramesConfig(Section):
    """A rig's ``frames:`` section: ``dark``, ``ambient`` (frame counts), ``sphere`` and
    ``outline`` (bools: an evenly room-lit photo of the spheres after their frames)."""

    DEFAULTS = {"dark": 1, "ambient": 0, "sphere": True, "outline": False}


@dataclass
class RigConfig:
    """One validated rig. ``exposure`` and ``scene`` are free dicts; ``source`` the rig file."""

    name: str
    lights: LightsConfig
    camera: CameraConfig
    exposure: dict = field(default_factory=dict)
    frames: FramesConfig = field(default_factory=lambda: FramesConfig(FramesConfig.DEFAULTS))
    raw_format: str = "dng"
    description: str = ""
    scene: dict = field(default_factory=dict)
    source: str = "(built in)"

    @property
    def is_simulated(self):
        """True when neither lights nor camera need hardware."""
        return self.lights.driver == "sim" and self.camera.driver == "sim"

    def __getitem__(self, key):
        if key not in {f.name for f in fields(self)}:
            raise KeyError(key)
        return getattr(self, key)

    def to_dict(self):
        """The whole rig as a plain YAML-friendly dict."""
        return {f.name: plain(getattr(self, f.name), 9) for f in fields(self)}

    def light_set(self):
        """The nominal lights as a :class:`pipeline.lightsio.LightSet` (intensities 1)."""
        return LightSet(self.lights.directions.copy(), positions=self.lights.positions,
                        source=f"nominal, rig '{self.name}' ({self.source})")


# -- value checkers: each returns the clean value or raises ValueError(what was expected) -------

def _int(low=None, high=None):
    def check(value):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError("expected an integer")
        if (low is not None and value < low) or (high is not None and value > high):
            raise ValueError(f"expected an integer >= {low}" if high is None
                             else f"expected an integer from {low} to {high}")
        return value
    return check


def _number(low=0.0):
    def check(value):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError("expected a number")
        if not np.isfinite(value) or value < low:
            raise ValueError(f"expected a number >= {low:g}")
        return float(value)
    return check


def _usb_id(value):
    if isinstance(value, str):
        try:
            value = int(value, 16)
        except ValueError:
            raise ValueError("expected a USB id (an integer, or hex like 0x04a9)") from None
    return _int(0, 0xFFFF)(value)


def _text(value):
    if not isinstance(value, str) or not value.strip():
        raise ValueError("expected a non-empty string")
    return value


def _choice(*options):
    def check(value):
        if value not in options:
            raise ValueError(f"expected one of {', '.join(map(str, options))}")
        return value
    return check


def _boolean(value):
    if not isinstance(value, bool):
        raise ValueError("expected true or false")
    return value


def _mapping(value):
    if not isinstance(value, dict):
        raise ValueError("expected a mapping of keys to values")
    return dict(value)


def _vectors(value):
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("expected lists of 3 numbers (x, y, z)") from None
    if array.ndim != 2 or array.shape[1] != 3 or len(array) == 0 or not np.isfinite(array).all():
        raise ValueError("expected lists of 3 numbers (x, y, z)")
    return array


def _vector(value):
    return _vectors([value])[0]


def _rings(value):
    if not isinstance(value, list) or not value:
        raise ValueError("expected a list of {elevation, count, azimuth}")
    for ring in value:
        if not isinstance(ring, dict) or not {"elevation", "count"} <= set(ring) \
                or not set(ring) <= {"elevation", "count", "azimuth"}:
            raise ValueError("expected a list of {elevation, count, azimuth}")
        _number(-90.0)(ring["elevation"])
        _int(1)(ring["count"])
        _number(-360.0)(ring.get("azimuth", 0.0))
    return value


_LIGHT_KEYS = {
    "driver": _text, "port": _text, "baudrate": _int(1), "protocol": _choice("psrig-1"),
    "count": _int(1, 4096), "timeout": _number(), "write_timeout": _number(),
    "reset_delay": _number(), "retries": _int(0, 10), "directions": _vectors,
    "positions": _vectors, "target": _vector, "lp": _text, "rings": _rings,
    "watchdog": _number(), "boot_delay": _number(),
}
_CAMERA_KEYS = {"driver": _choice("ptp", "sim"), "vendor_id": _usb_id, "product_id": _usb_id,
                "path": _choice(*CAMERA_PATHS), "timeout": _number(), "busy_retries": _int(0, 100),
                "chunk_size": _int(512), "delete_after_download": _boolean,
                "busy_backoff": _number()}
_FRAME_KEYS = {"dark": _int(0, 1000), "ambient": _int(0, 1000), "sphere": _boolean, "outline": _boolean}
_RIG_KEYS = ("description", "lights", "camera", "exposure", "frames", "raw_format", "scene")
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
    lights = check.section(data, "lights", _LIGHT_KEYS, required=("driver",))
    from rig.lights import LIGHT_DRIVERS  # lazily: rig.lights imports pyserial

    if lights["driver"] not in LIGHT_DRIVERS:
        check.fail("lights.driver", f"unknown light driver {lights['driver']!r} "
                                    f"(known: {', '.join(sorted(LIGHT_DRIVERS))})")
    if lights["driver"] != "sim" and "port" not in lights:
        check.fail("lights.port", f"missing (the {lights['driver']!r} driver needs a serial port)")
    if "rings" not in lights and check.name == "sim" and not set(_GEOMETRY) & set(lights):
        lights["rings"] = list(SIM_RINGS)
    return LightsConfig({**LightsConfig.DEFAULTS, **_geometry(check, lights, base_dir)})


def _camera(check, data):
    camera = check.section(data, "camera", _CAMERA_KEYS, required=("driver",))
    if camera["driver"] == "ptp":
        for key in ("vendor_id", "product_id"):
            if key not in camera:
                check.fail(f"camera.{key}", "missing (a PTP camera is found by its USB ids)")
    return CameraConfig(camera)


def _exposure(check, data):
    """The ``exposure:`` section: shutter (s), iso, aperture (f-number), each parseable.

    Values stay as written (e.g. '1/30'): the camera driver matches them to what it allows.
    """
    from rig.exposure import EXPOSURE_KEYS, PARSERS

    exposure = check.value("exposure", _mapping, data)
    for key, value in exposure.items():
        if key not in PARSERS:
            check.fail(f"exposure.{key}", f"unknown key (known: {', '.join(EXPOSURE_KEYS)})")
        try:
            PARSERS[key](value)
        except ValueError as exc:
            check.fail(f"exposure.{key}", str(exc).split(": ", 1)[-1])
    return exposure


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
        raw_format=check.value("raw_format", _choice(*RAW_FORMATS), data.get("raw_format", "dng")),
        description=check.value("description", str, data.get("description") or ""),
        scene=check.value("scene", _mapping, data.get("scene") or {}))
    if name == "sim" and not rig.is_simulated:
        check.fail("lights.driver" if rig.lights.driver != "sim" else "camera.driver",
                   "the rig 'sim' must need no hardware (driver: sim)")
    return rig


SIM_DEFINITION = {
    "description": "simulated dome: 32 lights on 4 rings, simulated PTP camera; no hardware",
    "lights": {"driver": "sim", "count": 32, "rings": [dict(r) for r in SIM_RINGS]},
    "camera": {"driver": "sim", "path": "generic"},
    "frames": {"dark": 1, "ambient": 0, "sphere": True},
    "raw_format": "dng",
}
"""The ``sim`` rig used when the rig file does not define one."""


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

    The shipped one is the repository's ``rigs.yaml`` beside the ``rig`` package when present
    (an editable install), else ``rig/rigs_default.yaml``. Returns None when there is none.
    """
    if path is not None:
        return Path(path)
    if os.environ.get(_ENV_VAR):
        return Path(os.environ[_ENV_VAR])
    for candidate in (Path.cwd() / "rigs.yaml", _PACKAGE_DIR.parent / "rigs.yaml",
                      _PACKAGE_DIR / "rigs_default.yaml"):
        if candidate.is_file():
            return candidate
    return None


def parse_rigs(text, source="rigs.yaml", base_dir=None):
    """Validate rig-file text; returns {name: RigConfig}, always including ``sim``.

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
    if "sim" not in rigs:
        rigs["sim"] = _rig("(built in)", "sim", SIM_DEFINITION, None)
    default = data.get("default")
    if default is not None and default not in rigs:
        raise ConfigError(f"{source}: default: no rig named {default!r} (rigs: {', '.join(rigs)})")
    return rigs


def load_rigs(path=None):
    """Load and validate a rig file (see :func:`find_rigs_file`); returns {name: RigConfig}.

    The rig ``sim`` is always present, even without any file.
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
