"""Camera and light drivers: the registries rig files name them from, and the built-in ones.

A rig's ``lights: {driver: NAME, ...}`` and ``camera: {driver: NAME, ...}`` pick a driver from
:data:`LIGHT_DRIVERS` or :data:`CAMERA_DRIVERS` (:class:`pipeline.core.registry.Registry`). Each
driver declares and checks its OWN keys (:attr:`Driver.keys`), builds its device
(:meth:`Driver.create`) and says how it combines with others (a simulated camera needs lights
that report which light they lit). A third-party driver is a Python package that declares an
entry point in the group ``psrig.lights`` or ``psrig.cameras`` naming a :class:`LightDriver` or
:class:`CameraDriver` (an instance or a class)::

    [project.entry-points."psrig.lights"]
    dmx = "psrig_dmx:DmxLights"

A plugin that cannot be loaded is listed by ``psrig rigs`` with the reason, and named when a rig
asks for it. Nothing here imports pyserial, pyusb or gphoto2: the drivers import their device
modules only when they build a device.
"""

from pipeline.core.registry import Registry
from rig import checks
from rig.checks import ConfigError

__all__ = ["Driver", "LightDriver", "CameraDriver", "LIGHT_DRIVERS", "CAMERA_DRIVERS",
           "light_driver", "camera_driver", "make_light_controller", "make_camera",
           "driver_table", "new_registries", "SHARED_LIGHT_KEYS", "SERIAL_LIGHT_KEYS",
           "PTP_CAMERA_KEYS", "BUILTIN_LIGHT_DRIVERS", "BUILTIN_CAMERA_DRIVERS"]


class Driver:
    """One driver: its name, its keys and their checkers, and how to build its device.

    Attributes
    ----------
    name : str
        The ``driver:`` value of rig files.
    keys : dict
        ``{key: checker}`` of the driver's own keys; a checker returns the clean value or
        raises ``ValueError`` saying what it expected (see :mod:`rig.checks`).
    required : tuple of str
        Keys that must be given.
    defaults : dict
        Values of keys not given (None: absent).
    simulated : bool
        The device is simulated (needs no hardware).
    needs : str or None
        The extra that installs what the driver imports, e.g. ``gphoto2``.
    summary : str
        One line for ``psrig rigs``.
    """

    kind = "driver"
    name = None
    keys = {}
    required = ()
    defaults = {}
    simulated = False
    needs = None
    summary = ""

    def validate(self, section, fail):
        """The driver's keys of ``section`` checked: a clean dict (defaults filled in).

        Parameters
        ----------
        section : dict
            The rig file's keys for this driver (the shared keys already taken out).
        fail : callable
            ``fail(key, message)`` raises the caller's error, naming the file and the rig.
        """
        for key in section:
            if key not in self.keys:
                fail(key, f"unknown key for the {self.name!r} {self.kind} (known: "
                          f"{', '.join(self.keys) or 'none'})")
        for key in self.required:
            if section.get(key) is None:
                fail(key, f"missing (the {self.name!r} {self.kind} needs it)")
        clean = {key: value for key, value in self.defaults.items()}
        for key, value in section.items():
            if value is None:
                continue
            try:
                clean[key] = self.keys[key](value)
            except ValueError as exc:
                fail(key, f"{exc}, got {value!r}")
        return clean

    def create(self, config, **overrides):
        """The (unopened) device a validated section describes."""
        raise NotImplementedError

    def describe(self, config):
        """A few words on a configured device for ``psrig rigs`` (e.g. 'on /dev/ttyACM0')."""
        return "simulated" if self.simulated else ""

    def unavailable(self):
        """Why the driver cannot be used on this machine (a missing package), or None."""
        return None


class LightDriver(Driver):
    """A light-controller driver.

    Attributes
    ----------
    keepalive : bool
        Its controller can be kept alive through long exposures (``keep_alive()``).
    reports_lit : bool
        Its controller's ``lit`` attribute names the light it confirmed on, so a simulated
        camera can render what it lit.
    """

    kind = "light driver"
    keepalive = False
    reports_lit = False

    def watchdog(self, config):
        """Seconds after which the controller darkens itself without commands, or None."""
        return None


class CameraDriver(Driver):
    """A camera driver; its device follows :class:`rig.camera.Camera`."""

    kind = "camera driver"


# -- built-in light drivers ----------------------------------------------------------------------

_LINE_KEYS = {"timeout": checks.number(), "write_timeout": checks.number(),
              "retries": checks.integer(0, 10), "watchdog": checks.number()}
SERIAL_LIGHT_KEYS = {"port": checks.text, "baudrate": checks.integer(1),
                     "protocol": checks.choice("psrig-1"), "reset_delay": checks.number(),
                     **_LINE_KEYS}
"""Keys of the ``serial`` light driver (psrig light protocol 1 on a serial port)."""


class SerialLights(LightDriver):
    name = "serial"
    keys = SERIAL_LIGHT_KEYS
    required = ("port",)
    defaults = {"baudrate": 115200, "protocol": "psrig-1", "timeout": 1.0, "write_timeout": 1.0,
                "reset_delay": 2.0, "retries": 1, "watchdog": 5.0}
    keepalive = reports_lit = True
    summary = "psrig light protocol 1 on a serial port (rig/firmware/psrig_lights)"

    def watchdog(self, config):
        return config.get("watchdog") or None

    def create(self, config, **overrides):
        from rig.lights import SerialLightController

        options = {key: config[key] for key in ("baudrate", "timeout", "write_timeout",
                                                "reset_delay", "retries", "watchdog")
                   if config.get(key) is not None}
        if config.get("count") is not None:
            options["expected_count"] = config["count"]
        options.update(overrides)
        return SerialLightController(config["port"], **options)

    def describe(self, config):
        return f"on {config.get('port')}"


class SimLights(SerialLights):
    name = "sim"
    keys = {**_LINE_KEYS, "reset_delay": checks.number(), "boot_delay": checks.number()}
    required = ()
    defaults = {"timeout": 1.0, "write_timeout": 1.0, "retries": 1, "watchdog": 5.0,
                "boot_delay": 0.0}
    simulated = True
    summary = "the simulated light firmware on a pseudo-terminal, driven by the serial driver"

    def create(self, config, **overrides):
        from rig.lights import SimLightController

        options = {key: config[key] for key in ("timeout", "write_timeout", "retries",
                                                "watchdog", "boot_delay", "reset_delay")
                   if config.get(key) is not None}
        options.update(overrides)
        return SimLightController(int(config.get("count") or 32), **options)

    def describe(self, config):
        return "simulated"


# -- built-in camera drivers ---------------------------------------------------------------------

_PTP_OPTIONS = {"timeout": checks.number(), "busy_retries": checks.integer(0, 100),
                "busy_backoff": checks.number(), "chunk_size": checks.integer(512),
                "delete_after_download": checks.boolean}
PTP_CAMERA_KEYS = {"vendor_id": checks.usb_id, "product_id": checks.usb_id,
                   "path": checks.choice("generic", "canon", "nikon", "auto"), **_PTP_OPTIONS}
"""Keys of the ``ptp`` camera driver (PTP over USB with pyusb)."""


class PtpCameraDriver(CameraDriver):
    name = "ptp"
    keys = PTP_CAMERA_KEYS
    required = ("vendor_id", "product_id")
    summary = "PTP over USB with pyusb (generic, Canon EOS, Nikon paths)"

    def create(self, config, **overrides):
        from rig.camera import make_camera as make_ptp_camera

        return make_ptp_camera({"driver": "ptp", **config}, **overrides)

    def describe(self, config):
        return (f"{config.get('path', 'auto')} "
                f"{config.get('vendor_id', 0):04x}:{config.get('product_id', 0):04x}")


class SimCameraDriver(CameraDriver):
    name = "sim"
    keys = {"path": checks.choice("generic", "canon", "nikon", "auto"), **_PTP_OPTIONS}
    simulated = True
    summary = "the simulated PTP camera (a pyusb backend) driven by the ptp driver"

    def create(self, config, **overrides):
        raise ConfigError("camera.driver sim: the simulated camera is built by the simulated "
                          "rig (rig.sim.rig.SimulatedRig), which renders the scene it sees")


class Gphoto2CameraDriver(CameraDriver):
    name = "gphoto2"
    keys = {"model": checks.text, "port": checks.text, "timeout": checks.number(),
            "delete_after_download": checks.boolean}
    defaults = {"timeout": 10.0, "delete_after_download": True}
    needs = "gphoto2"
    summary = "libgphoto2 through python-gphoto2 (pip install 'psrig[gphoto2]')"

    def create(self, config, **overrides):
        from rig.gphoto2_camera import Gphoto2Camera

        options = {key: config[key] for key in ("model", "port", "timeout",
                                                "delete_after_download") if key in config}
        options.update(overrides)
        return Gphoto2Camera(**options)

    def describe(self, config):
        return " ".join(str(config[key]) for key in ("model", "port") if config.get(key)) or "first found"

    def unavailable(self):
        import importlib.util

        if importlib.util.find_spec("gphoto2") is None:
            return "python-gphoto2 is not installed: pip install 'psrig[gphoto2]'"
        return None


BUILTIN_LIGHT_DRIVERS = (SerialLights, SimLights)
BUILTIN_CAMERA_DRIVERS = (PtpCameraDriver, SimCameraDriver, Gphoto2CameraDriver)


def new_registries():
    """Fresh (light, camera) registries holding the built-in drivers; their plugins are read
    from the entry points when first used (tests make new ones after faking entry points)."""
    lights = Registry("light driver", error=ConfigError, entry_points="psrig.lights")
    cameras = Registry("camera driver", error=ConfigError, entry_points="psrig.cameras")
    for registry, builtins in ((lights, BUILTIN_LIGHT_DRIVERS), (cameras, BUILTIN_CAMERA_DRIVERS)):
        for cls in builtins:
            registry.register(cls.name, cls())
    return lights, cameras


LIGHT_DRIVERS, CAMERA_DRIVERS = new_registries()
"""Drivers by the ``driver`` name of rig files' ``lights:`` and ``camera:`` (plugins: entry
point groups ``psrig.lights`` and ``psrig.cameras``)."""


def _lookup(registry, base, name):
    driver = registry[name]
    if isinstance(driver, type) and issubclass(driver, base):
        driver = driver()
    if not isinstance(driver, base):
        raise ConfigError(f"{registry.kind} {name!r} is installed but is not a "
                          f"rig.drivers.{base.__name__} (got {type(driver).__name__})")
    if driver.name != name:  # the name it is registered under is the one rig files use
        driver.name = name
    return driver


def light_driver(name):
    """The :class:`LightDriver` named ``name`` (ConfigError listing the known ones)."""
    return _lookup(LIGHT_DRIVERS, LightDriver, name)


def camera_driver(name):
    """The :class:`CameraDriver` named ``name`` (ConfigError listing the known ones)."""
    return _lookup(CAMERA_DRIVERS, CameraDriver, name)


#: keys of ``lights:`` that every light driver shares: psrig reads them, not the driver
SHARED_LIGHT_KEYS = ("driver", "count", "directions", "positions", "target", "lp", "rings",
                     "levels")


def _own_keys(config, shared):
    return {key: value for key, value in config.items() if key not in shared}


def _raise(error, section):
    def fail(key, message):
        raise error(f"{section}.{key}: {message}")
    return fail


def make_light_controller(config, **overrides):
    """Build the (unopened) light controller a rig's ``lights:`` section describes.

    Parameters
    ----------
    config : mapping
        A rig's ``lights`` section (validated, or a plain dict with at least ``driver``).
    **overrides
        Constructor options that win over the section (e.g. ``timeout``).

    Returns
    -------
    rig.lights.LightController
    """
    from rig.lights import LightError

    try:
        driver = light_driver(config.get("driver"))
        options = driver.validate(_own_keys(config, SHARED_LIGHT_KEYS), _raise(LightError, "lights"))
    except ConfigError as exc:
        raise LightError(f"lights.driver: {exc}") from None
    return driver.create({**config, **options}, **overrides)


def make_camera(config, **overrides):
    """Build the (unopened) camera a rig's ``camera:`` section describes (not ``sim``: the
    simulated rig builds its own)."""
    from rig.camera import CameraConfigError

    try:
        driver = camera_driver(config.get("driver", "ptp"))
        options = driver.validate(_own_keys(config, ("driver",)),
                                  _raise(CameraConfigError, "camera"))
        return driver.create(options, **overrides)
    except ConfigError as exc:
        raise CameraConfigError(f"camera: {exc}") from None


def driver_table():
    """Rows (kind, name, origin, summary or why not usable) of every driver found, plugins
    that failed to load included."""
    rows = []
    for kind, registry, lookup, builtins in (
            ("lights", LIGHT_DRIVERS, light_driver, BUILTIN_LIGHT_DRIVERS),
            ("camera", CAMERA_DRIVERS, camera_driver, BUILTIN_CAMERA_DRIVERS)):
        builtin = {cls.name for cls in builtins}
        for name in registry.names():
            origin = "built in" if name in builtin else "plugin"
            try:
                driver = lookup(name)
                note = driver.unavailable()
                rows.append((kind, name, origin, f"not usable: {note}" if note else driver.summary))
            except ConfigError as exc:
                rows.append((kind, name, "plugin", f"BROKEN: {exc}"))
        for name, why in sorted(registry.broken().items()):
            rows.append((kind, name, "plugin", f"BROKEN: cannot be loaded ({why})"))
    return rows
