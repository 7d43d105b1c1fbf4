"""Simulated devices that the real drivers talk to: light firmware, PTP camera, scene.

The names other packages use are re-exported here and imported on first use, so importing
``rig.sim`` stays light.
"""

import importlib

__all__ = ["SimulatedRig", "SimulatedLightFirmware", "SimClock", "Scene", "make_backend",
           "pixel_grid", "parse_faults"]

_WHERE = {"SimulatedRig": "rig.sim.rig", "parse_faults": "rig.sim.rig",
          "SimulatedLightFirmware": "rig.sim.firmware", "SimClock": "rig.sim.clock",
          "Scene": "rig.sim.scene", "make_backend": "rig.sim.usb_camera",
          "pixel_grid": "rig.sim.shapes"}


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'rig.sim' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
