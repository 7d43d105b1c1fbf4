"""Acquisition: light controllers, cameras, rig configuration and capture into sessions.

The names other packages use are re-exported here and imported on first use (module
``__getattr__``), so ``import rig`` loads neither pyserial nor pyusb.
"""

import importlib

__all__ = ["capture_session", "CaptureError", "get_rig", "load_rigs", "ConfigError", "RigConfig",
           "make_camera", "make_light_controller", "LIGHT_DRIVERS", "CAMERA_DRIVERS",
           "LightDriver", "CameraDriver", "raw_extension"]

_WHERE = {"capture_session": "rig.capture", "CaptureError": "rig.capture",
          "get_rig": "rig.config", "load_rigs": "rig.config", "RigConfig": "rig.config",
          "ConfigError": "rig.checks", "make_camera": "rig.drivers",
          "make_light_controller": "rig.drivers", "LIGHT_DRIVERS": "rig.drivers",
          "CAMERA_DRIVERS": "rig.drivers", "LightDriver": "rig.drivers",
          "CameraDriver": "rig.drivers", "raw_extension": "rig.rawtype"}


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'rig' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
