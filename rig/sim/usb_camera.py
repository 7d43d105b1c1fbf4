"""A simulated USB PTP camera, packaged as a pyusb backend (``usb.backend.IBackend``).

The real driver (:class:`rig.camera.PtpCamera`) finds it with ``usb.core.find(backend=...)``, so
every pyusb code path runs: descriptors, configuration, interface claiming, kernel-driver
detach, bulk and interrupt transfers. Two layers:

- :class:`SimulatedPtpCamera`, the device side of PTP: a session, a storage of objects, and the
  generic (InitiateCapture + interrupt events), Canon EOS (remote release + GetEvent polling)
  and Nikon (capture to SDRAM + DeviceReady + GetEvent) behaviours.
- :class:`SimulatedUsbBackend`, the USB side: descriptors, claim/detach, bulk IN transfers with
  short-packet / zero-length-packet semantics, the interrupt endpoint, PTP class requests, and
  fault injection (``inject(kind, count=1, op=None)``):

  ``busy``          the next ``count`` commands (of ``op`` if given) answer DeviceBusy (0x2019);
                    ``count=None`` means forever
  ``timeout``       the next ``count`` bulk reads (of ``op``'s transfer if given) time out and
                    the camera drops the transaction, as a hung camera does
  ``disconnect``    the cable is pulled half way through the next GetObject data phase
  ``truncated``     the next ``count`` GetObject data phases are shorter than ObjectInfo says
  ``session_open``  a session is left open (OpenSession answers SessionAlreadyOpened)
  ``claimed``       claim_interface fails with EBUSY, as when gvfs holds the camera
  ``no_event``      the next capture happens but reports no ObjectAdded event
  ``kernel_driver`` a kernel driver is bound to the interface (must be detached)
  ``stale_response`` a response of an earlier transaction precedes the next one (host and
                    camera out of step, e.g. after a crashed program)
  ``new_folder``    the next generic capture first reports a new folder (an association
                    object) in an ObjectAdded event, as cameras do when they start a new DCIM
                    directory
  ``length_lie``    the next data phase's header claims 1 GiB (the payload is what it is)
  ``length_max``    the next data phase's header claims 0xFFFFFFF0 bytes
  ``trickle``       the next data phase arrives slowly: a pause before each of its bulk reads,
                    each pause shorter than a transfer timeout

Exposure properties: ``generic`` and ``nikon`` cameras offer the PTP standard ExposureTime
(0x500D, UINT32, 0.1 ms), FNumber (0x5007, UINT16, x 100) and ExposureIndex (0x500F, UINT16)
through GetDevicePropDesc / GetDevicePropValue / SetDevicePropValue (host -> camera data phase);
``canon`` cameras offer Aperture, ShutterSpeed and ISOSpeed (0xD101..0xD103) in Canon's stop
codes through EOS_SetDevicePropValueEx, and report values (PropValueChanged) and allowed lists
(AvailListChanged) in GetEvent records. Each property is an enumeration (1/2000..30 s in third
stops, f/2.8..f/22, ISO 100..6400); a value outside it is answered InvalidDevicePropValue
(0x201C), a property the camera lacks (:meth:`SimulatedPtpCamera.remove_property`)
DevicePropNotSupported (0x200A). :meth:`SimulatedPtpCamera.exposure_gain` is the set shutter
time relative to the factory default (1/30 s), which the simulated rig applies to the signal.
"""

from __future__ import annotations

import array
import errno
import struct
import time
from collections import deque
from dataclasses import dataclass
from types import SimpleNamespace

import usb.backend
from usb.core import USBError, USBTimeoutError

from rig import exposure as exposure_values, ptp
from rig.ptp import EventCode, OperationCode as Op, ResponseCode as RC

__all__ = ["SimObject", "SimProp", "SimulatedPtpCamera", "SimulatedUsbBackend", "make_backend",
           "FAULT_KINDS", "BEHAVIOURS", "DATA_OUT_OPS", "REFERENCE_SHUTTER"]

FAULT_KINDS = ("busy", "timeout", "disconnect", "truncated", "session_open", "claimed",
               "no_event", "kernel_driver", "new_folder", "stale_response", "length_lie",
               "length_max", "trickle")
LENGTH_LIE = 1 << 30  # bytes a lying data header claims (fault 'length_lie')
TRICKLE_PAUSE = 0.05  # seconds before each bulk read of a trickled data phase (fault 'trickle')
BEHAVIOURS = ("generic", "canon", "nikon")

BULK_MPS = 512   # high-speed bulk wMaxPacketSize (bytes)
INTR_MPS = 64
EP_BULK_IN, EP_BULK_OUT, EP_INTR_IN = 0x81, 0x02, 0x83
STORAGE_ID = 0x00010001
_DEFAULT_IDS = {"generic": (0x1209, 0x7053), "canon": (0x04A9, 0x3218),
                "nikon": (0x04B0, 0x0428)}
_PREFIX = {"generic": "IMG_", "canon": "IMG_", "nikon": "DSC_"}

_COMMON_OPS = [Op.GetDeviceInfo, Op.OpenSession, Op.CloseSession, Op.GetStorageIDs,
               Op.GetObjectHandles, Op.GetObjectInfo, Op.GetObject, Op.DeleteObject]
_PROP_OPS = [Op.GetDevicePropDesc, Op.GetDevicePropValue, Op.SetDevicePropValue]
_OPS = {
    "generic": _COMMON_OPS + _PROP_OPS + [Op.InitiateCapture],
    "canon": _COMMON_OPS + [Op.EOS_SetRemoteMode, Op.EOS_SetEventMode, Op.EOS_GetEvent,
                            Op.EOS_RemoteReleaseOn, Op.EOS_RemoteReleaseOff,
                            Op.EOS_TransferComplete, Op.EOS_KeepDeviceOn,
                            Op.EOS_SetDevicePropValueEx],
    "nikon": _COMMON_OPS + _PROP_OPS + [Op.InitiateCapture, Op.NIKON_InitiateCaptureRecInSdram,
                                        Op.NIKON_GetEvent, Op.NIKON_DeviceReady],
}
#: operations whose data phase goes host -> camera
DATA_OUT_OPS = frozenset({Op.SetDevicePropValue, Op.EOS_SetDevicePropValueEx})
_PropCode = ptp.PropCode
# nominal ranges of a mid-range body with a zoom lens
_SHUTTERS = [v for v in exposure_values.NOMINAL_SERIES["shutter"] if 1 / 2000 - 1e-9 <= v <= 30]
_APERTURES = [v for v in exposure_values.NOMINAL_SERIES["aperture"] if 2.8 <= v <= 22]
_ISOS = [v for v in exposure_values.NOMINAL_SERIES["iso"] if 100 <= v <= 6400]
REFERENCE_SHUTTER = 1 / 30
"""Factory-default shutter time (s): the exposure at which the simulated rig renders as before."""
_VENDOR_EXT = {"generic": 0, "canon": ptp.VendorExtension.CANON,
               "nikon": ptp.VendorExtension.NIKON}
_MAKER = {"generic": ("psrig", "Simulated PTP camera"), "canon": ("Canon Inc.", "Canon EOS SIM"),
          "nikon": ("Nikon Corporation", "D-SIM")}


@dataclass
class SimObject:
    """One file on the simulated camera's storage."""

    data: bytes
    filename: str
    object_format: int


@dataclass
class SimProp:
    """One device property of the simulated camera: an enumeration of allowed values.

    ``refused`` holds listed values the camera still answers InvalidDevicePropValue to, as a
    body does when its mode narrows the list after the host read it.
    """

    datatype: int
    values: list
    current: int
    factory: int | None = None
    writable: bool = True
    refused: tuple = ()

    def __post_init__(self):
        if self.factory is None:
            self.factory = self.current

    def desc(self, code) -> ptp.DevicePropDesc:
        return ptp.DevicePropDesc(code, self.datatype, self.writable, self.factory, self.current,
                                  ptp.FormFlag.ENUMERATION, values=list(self.values))


def _standard_props() -> dict:
    shutter = [int(round(v * 1e4)) for v in _SHUTTERS]
    return {
        _PropCode.ExposureTime: SimProp(ptp.DataType.UINT32, shutter,
                                        int(round(REFERENCE_SHUTTER * 1e4))),
        _PropCode.FNumber: SimProp(ptp.DataType.UINT16, [int(round(v * 100)) for v in _APERTURES],
                                   800),
        _PropCode.ExposureIndex: SimProp(ptp.DataType.UINT16, list(_ISOS), 100),
    }


def _eos_props() -> dict:
    def codes(key, values):
        return [exposure_values.eos_encode(key, v) for v in values]
    return {
        _PropCode.EOS_ShutterSpeed: SimProp(ptp.DataType.UINT16, codes("shutter", _SHUTTERS),
                                            exposure_values.eos_encode("shutter", REFERENCE_SHUTTER)),
        _PropCode.EOS_Aperture: SimProp(ptp.DataType.UINT16, codes("aperture", _APERTURES),
                                        exposure_values.eos_encode("aperture", 8)),
        _PropCode.EOS_ISOSpeed: SimProp(ptp.DataType.UINT16, codes("iso", _ISOS),
                                        exposure_values.eos_encode("iso", 100)),
    }


class _Faults:
    """Armed faults: kind -> [remaining count or None (forever), op code or None]."""

    def __init__(self):
        self.armed: dict[str, list] = {}

    def arm(self, kind, count=1, op=None):
        if kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault {kind!r}; known: {', '.join(FAULT_KINDS)}")
        self.armed[kind] = [count, op]

    def take(self, kind, op=None) -> bool:
        """Consume one occurrence of ``kind`` if it is armed for ``op``."""
        slot = self.armed.get(kind)
        if slot is None or (slot[1] is not None and slot[1] != op):
            return False
        if slot[0] is not None:
            slot[0] -= 1
            if slot[0] <= 0:
                del self.armed[kind]
        return True


class SimulatedPtpCamera:
    """The device side of PTP: session, storage, capture behaviours.

    Parameters
    ----------
    render : callable
        Zero-argument callable returning the bytes of the image the sensor sees at the moment
        of the capture.
    behaviour : {'generic', 'canon', 'nikon'}
    faults : _Faults
        Shared with the USB layer.
    filename_ext : str
        Extension of captured files, e.g. '.DNG'.
    """

    def __init__(self, render, behaviour, faults, filename_ext=".DNG", serial="SIM0001"):
        if behaviour not in BEHAVIOURS:
            raise ValueError(f"unknown camera behaviour {behaviour!r}; known: {BEHAVIOURS}")
        self.render, self.behaviour, self.faults = render, behaviour, faults
        self.filename_ext, self.serial = filename_ext, serial
        self.objects: dict[int, SimObject] = {}
        self.next_names: list[str] = []  # names for the next captures (tests: odd names)
        self.captures = 0
        self.log: list[int] = []          # operation codes executed, in order
        self.events: deque = deque()      # packed event containers for the interrupt endpoint
        self.session_id = None
        self.remote_mode = self.event_mode = 0
        self.props: dict[int, SimProp] = _eos_props() if behaviour == "canon" else _standard_props()
        self._eos_pending: list = self._eos_state()
        self._eos_hold = 0
        self._nikon_pending: list = []
        self._nikon_busy = 0
        self._next_handle = 0xFFFF0001 if behaviour == "nikon" else 0x00000001

    def reset(self):
        """PTP Device Reset class request / power cycle: session closed, pending I/O dropped."""
        self.session_id = None
        self.events.clear()
        if self.behaviour == "canon":  # the next GetEvent dumps the whole state again
            self._eos_pending += self._eos_state()

    # -- exposure properties -------------------------------------------------------------------
    def _eos_state(self) -> list:
        """GetEvent records of every property: its allowed list, then its value."""
        if self.behaviour != "canon":
            return []
        return [rec for code, prop in self.props.items()
                for rec in (ptp.pack_eos_avail_list(code, prop.values),
                            ptp.pack_eos_prop_value(code, prop.current))]

    def remove_property(self, code: int):
        """Make the camera lack a property (e.g. FNumber on a manual lens)."""
        self.props.pop(code, None)

    def shutter_seconds(self) -> float:
        """The shutter time now set (s)."""
        if self.behaviour == "canon":
            prop = self.props.get(_PropCode.EOS_ShutterSpeed)
            return REFERENCE_SHUTTER if prop is None else exposure_values.eos_decode("shutter", prop.current)
        prop = self.props.get(_PropCode.ExposureTime)
        return REFERENCE_SHUTTER if prop is None else prop.current / 1e4

    def exposure_gain(self) -> float:
        """Set shutter time over the factory default's: the factor on the collected light."""
        code = _PropCode.EOS_ShutterSpeed if self.behaviour == "canon" else _PropCode.ExposureTime
        prop = self.props.get(code)
        if prop is None or prop.current == prop.factory:
            return 1.0
        if self.behaviour == "canon":
            return (exposure_values.eos_decode("shutter", prop.current)
                    / exposure_values.eos_decode("shutter", prop.factory))
        return prop.current / prop.factory

    def device_info(self) -> ptp.DeviceInfo:
        maker, model = _MAKER[self.behaviour]
        return ptp.DeviceInfo(
            vendor_extension_id=_VENDOR_EXT[self.behaviour], vendor_extension_version=100,
            vendor_extension_desc="microsoft.com: 1.0" if self.behaviour == "generic" else "",
            operations=[int(o) for o in _OPS[self.behaviour]],
            events=[EventCode.ObjectAdded, EventCode.CaptureComplete],
            capture_formats=[ptp.format_for_filename(self.filename_ext)],
            image_formats=[ptp.format_for_filename(self.filename_ext)],
            device_properties=[int(c) for c in self.props],
            manufacturer=maker, model=model, device_version="1.0", serial_number=self.serial)

    def execute(self, code: int, tid: int, params: tuple, data: bytes | None = None):
        """Run one operation: returns (data bytes or None, response code, response params).

        ``data`` is the host's data phase of the operations in :data:`DATA_OUT_OPS`.
        """
        if self.faults.take("busy", code):
            return None, RC.DeviceBusy, ()
        if code not in _OPS[self.behaviour]:
            return None, RC.OperationNotSupported, ()
        if self.session_id is None and code not in (Op.GetDeviceInfo, Op.OpenSession):
            return None, RC.SessionNotOpen, ()
        self.log.append(code)
        handler = getattr(self, "_op_" + Op(code).name, None)
        if handler is None:
            return None, RC.OK, ()
        if code in DATA_OUT_OPS:
            return handler(tid, *params, data=data)
        return handler(tid, *params)

    # -- standard operations -------------------------------------------------------------
    def _op_GetDeviceInfo(self, tid, *_):
        return self.device_info().pack(), RC.OK, ()

    def _op_OpenSession(self, tid, session_id=0, *_):
        if self.session_id is not None:
            return None, RC.SessionAlreadyOpened, (self.session_id,)
        if session_id == 0:
            return None, RC.InvalidParameter, ()
        self.session_id = session_id
        return None, RC.OK, ()

    def _op_CloseSession(self, tid, *_):
        self.session_id = None
        return None, RC.OK, ()

    def _op_GetStorageIDs(self, tid, *_):
        return ptp.pack_array([STORAGE_ID], "I"), RC.OK, ()

    def _op_GetObjectHandles(self, tid, *_):
        return ptp.pack_array(sorted(self.objects), "I"), RC.OK, ()

    def _object_info(self, handle) -> ptp.ObjectInfo:
        obj = self.objects[handle]
        return ptp.ObjectInfo(storage_id=STORAGE_ID, object_format=obj.object_format,
                              compressed_size=len(obj.data), filename=obj.filename,
                              capture_date="20240101T120000")

    def _op_GetObjectInfo(self, tid, handle=0, *_):
        if handle not in self.objects:
            return None, RC.InvalidObjectHandle, ()
        return self._object_info(handle).pack(), RC.OK, ()

    def _op_GetObject(self, tid, handle=0, *_):
        if handle not in self.objects:
            return None, RC.InvalidObjectHandle, ()
        data = memoryview(self.objects[handle].data)
        if self.faults.take("truncated"):
            data = data[:len(data) * 2 // 3]
        return data, RC.OK, ()

    def _op_GetDevicePropDesc(self, tid, code=0, *_):
        prop = self.props.get(code)
        if prop is None:
            return None, RC.DevicePropNotSupported, ()
        return prop.desc(code).pack(), RC.OK, ()

    def _op_GetDevicePropValue(self, tid, code=0, *_):
        prop = self.props.get(code)
        if prop is None:
            return None, RC.DevicePropNotSupported, ()
        return ptp.pack_value(prop.datatype, prop.current), RC.OK, ()

    def _op_SetDevicePropValue(self, tid, code=0, *_, data=None):
        prop = self.props.get(code)
        if prop is None:
            return None, RC.DevicePropNotSupported, ()
        try:
            value = ptp.unpack_value(ptp.Reader(data or b""), prop.datatype)
        except ptp.PtpDecodeError:
            return None, RC.InvalidDevicePropFormat, ()
        if not prop.writable:
            return None, RC.AccessDenied, ()
        if value not in prop.values or value in prop.refused:
            return None, RC.InvalidDevicePropValue, ()
        prop.current = value
        return None, RC.OK, ()

    def _op_DeleteObject(self, tid, handle=0, *_):
        if self.objects.pop(handle, None) is None:
            return None, RC.InvalidObjectHandle, ()
        return None, RC.OK, ()

    def _shoot(self) -> tuple[int, SimObject] | None:
        """Expose one frame into storage; None when the 'no_event' fault hides it."""
        data = self.render()
        data = data if isinstance(data, bytes) else bytes(data)
        self.captures += 1
        handle, self._next_handle = self._next_handle, self._next_handle + 1
        name = (self.next_names.pop(0) if self.next_names
                else f"{_PREFIX[self.behaviour]}{self.captures:04d}{self.filename_ext}")
        obj = SimObject(data, name, ptp.format_for_filename(name))
        self.objects[handle] = obj
        return None if self.faults.take("no_event") else (handle, obj)

    def _op_InitiateCapture(self, tid, *_):
        if self.faults.take("new_folder"):
            folder = self._next_handle
            self._next_handle += 1
            self.objects[folder] = SimObject(b"", f"{100 + self.captures}PSRIG",
                                             ptp.ObjectFormat.Association)
            self.events.append(ptp.pack_event(EventCode.ObjectAdded, tid, (folder,)))
        shot = self._shoot()
        if shot is not None:
            self.events.append(ptp.pack_event(EventCode.ObjectAdded, tid, (shot[0],)))
            self.events.append(ptp.pack_event(EventCode.CaptureComplete, tid))
        return None, RC.OK, ()

    # -- Canon EOS ---------------------------------------------------------------------------
    def _op_EOS_SetRemoteMode(self, tid, mode=0, *_):
        self.remote_mode = mode
        return None, RC.OK, ()

    def _op_EOS_SetEventMode(self, tid, mode=0, *_):
        self.event_mode = mode
        return None, RC.OK, ()

    def _op_EOS_RemoteReleaseOn(self, tid, button=0, *_):
        if not (self.remote_mode and self.event_mode):
            return None, RC.GeneralError, ()
        if button & 2:  # full press
            shot = self._shoot()
            if shot is not None:
                handle, obj = shot
                self._eos_pending.append(ptp.EosObjectAdded(
                    handle, STORAGE_ID, obj.object_format, len(obj.data), 0x00100000,
                    obj.filename))
                self._eos_hold = 1  # the first poll after release finds nothing: exposure
        return None, RC.OK, ()

    def _op_EOS_SetDevicePropValueEx(self, tid, *_, data=None):
        try:
            code, value = ptp.unpack_eos_set_prop(data or b"")
        except ptp.PtpDecodeError:
            return None, RC.InvalidDevicePropFormat, ()
        prop = self.props.get(code)
        if prop is None:
            return None, RC.DevicePropNotSupported, ()
        if value not in prop.values or value in prop.refused:
            return None, RC.InvalidDevicePropValue, ()
        prop.current = value
        self._eos_pending.append(ptp.pack_eos_prop_value(code, value))
        return None, RC.OK, ()

    def _op_EOS_GetEvent(self, tid, *_):
        if self._eos_hold:
            self._eos_hold -= 1
            return ptp.pack_eos_events([]), RC.OK, ()
        records, self._eos_pending = self._eos_pending, []
        return ptp.pack_eos_events(records), RC.OK, ()

    # -- Nikon --------------------------------------------------------------------------------
    def _op_NIKON_InitiateCaptureRecInSdram(self, tid, *_):
        shot = self._shoot()
        self._nikon_busy = 2  # DeviceReady answers busy twice while the frame is written
        if shot is not None:
            self._nikon_pending += [(EventCode.NIKON_ObjectAddedInSDRAM, shot[0]),
                                    (EventCode.NIKON_CaptureCompleteRecInSdram, 0)]
        return None, RC.OK, ()

    def _op_NIKON_DeviceReady(self, tid, *_):
        if self._nikon_busy:
            self._nikon_busy -= 1
            return None, RC.DeviceBusy, ()
        return None, RC.OK, ()

    def _op_NIKON_GetEvent(self, tid, *_):
        events, self._nikon_pending = self._nikon_pending, []
        return ptp.pack_nikon_events(events), RC.OK, ()


class _InTransfer:
    """One bulk IN transfer (a container), read piecewise into host buffers."""

    def __init__(self, segments, op):
        self.segments = [memoryview(s).cast("B") for s in segments]
        self.length = sum(len(s) for s in self.segments)
        self.pos = 0
        self.op = op
        self.cut_at = None  # byte offset where the cable is pulled
        self.trickle = False  # pause before each read (a camera sending slowly)

    @property
    def remaining(self) -> int:
        return self.length - self.pos

    def read_into(self, out: memoryview, n: int):
        done, start = 0, self.pos
        for seg in self.segments:
            if start >= len(seg):
                start -= len(seg)
                continue
            k = min(len(seg) - start, n - done)
            out[done:done + k] = seg[start:start + k]
            done += k
            start = 0
            if done == n:
                break
        self.pos += n


def _desc(**fields):
    return SimpleNamespace(extra_descriptors=[], **fields)


def _usb_error(name, code, err):
    return USBError(name, code, err)


class SimulatedUsbBackend(usb.backend.IBackend):
    """The USB side of the simulated camera: one device, one PTP interface, three endpoints.

    Attributes
    ----------
    camera : SimulatedPtpCamera
    objects : dict
        The camera's storage, handle -> :class:`SimObject`.
    captures : int
        Frames exposed so far.
    kernel_driver_detached, kernel_driver_attached : int
        How often the driver detached / re-attached the kernel driver.
    send_zlp : bool
        False imitates firmware that sends no zero-length packet after a data phase ending on
        a packet boundary, so the response arrives in the same read as the data's tail.
    resets : int
        PTP Device Reset class requests received.
    """

    def __init__(self, camera, vendor_id, product_id):
        super().__init__()
        self.camera, self.faults = camera, camera.faults
        self.vendor_id, self.product_id = vendor_id, product_id
        self.connected = True
        self.kernel_driver_active = False
        self.kernel_driver_detached = self.kernel_driver_attached = 0
        self.claimed = False
        self.configuration = 1
        self.resets = 0
        self.send_zlp = True  # False: firmware that omits ZLPs after full-packet transfers
        self._in: deque = deque()
        self._out = None   # (command, bytes so far) while a host -> camera data phase arrives
        self._dev_id = SimpleNamespace(name="sim-ptp")

    # -- test controls ------------------------------------------------------------------------
    @property
    def objects(self) -> dict:
        return self.camera.objects

    @property
    def captures(self) -> int:
        return self.camera.captures

    def inject(self, kind: str, count: int | None = 1, op: int | None = None):
        """Arm a fault (see the module docstring); ``count=None`` keeps it armed forever."""
        if kind == "session_open":
            self.camera.session_id = 0x5E55
        elif kind == "kernel_driver":
            self.kernel_driver_active = True
        else:
            self.faults.arm(kind, count, op)

    def clear_faults(self):
        self.faults.armed.clear()

    def reconnect(self):
        """Plug the camera back in: a fresh USB state and a closed PTP session."""
        self.connected = True
        self.claimed = False
        self._in.clear()
        self._out = None
        self.camera.reset()

    def _alive(self):
        if not self.connected:
            raise _usb_error("No such device (it may have been disconnected)", -4, errno.ENODEV)

    def _disconnect(self):
        self.connected = False
        self._in.clear()
        self._out = None
        self.camera.reset()
        raise _usb_error("No such device (it may have been disconnected)", -4, errno.ENODEV)

    # -- enumeration and descriptors ---------------------------------------------------------
    def enumerate_devices(self):
        if self.connected:
            yield self._dev_id

    def get_parent(self, dev):
        return None

    def get_device_descriptor(self, dev):
        return _desc(bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0,
                     bDeviceSubClass=0, bDeviceProtocol=0, bMaxPacketSize0=64,
                     idVendor=self.vendor_id, idProduct=self.product_id, bcdDevice=0x0100,
                     iManufacturer=1, iProduct=2, iSerialNumber=3, bNumConfigurations=1,
                     address=7, bus=1, port_number=2, port_numbers=(2,), speed=3)

    def get_configuration_descriptor(self, dev, config):
        return _desc(bLength=9, bDescriptorType=2, wTotalLength=39, bNumInterfaces=1,
                     bConfigurationValue=1, iConfiguration=0, bmAttributes=0xC0, bMaxPower=50)

    def get_interface_descriptor(self, dev, intf, alt, config):
        return _desc(bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
                     bNumEndpoints=3, bInterfaceClass=6, bInterfaceSubClass=1,
                     bInterfaceProtocol=1, iInterface=0)

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        address, attributes, mps, interval = ((EP_BULK_IN, 2, BULK_MPS, 0),
                                              (EP_BULK_OUT, 2, BULK_MPS, 0),
                                              (EP_INTR_IN, 3, INTR_MPS, 8))[ep]
        return _desc(bLength=7, bDescriptorType=5, bEndpointAddress=address,
                     bmAttributes=attributes, wMaxPacketSize=mps, bInterval=interval,
                     bRefresh=0, bSynchAddress=0)

    # -- device handle ------------------------------------------------------------------------
    def open_device(self, dev):
        self._alive()
        return SimpleNamespace(dev=dev)

    def close_device(self, dev_handle):
        self.claimed = False

    def set_configuration(self, dev_handle, config_value):
        self._alive()
        self.configuration = config_value

    def get_configuration(self, dev_handle):
        self._alive()
        return self.configuration

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        self._alive()

    def claim_interface(self, dev_handle, intf):
        self._alive()
        if self.kernel_driver_active or self.faults.take("claimed"):
            raise _usb_error("Resource busy", -6, errno.EBUSY)
        self.claimed = True

    def release_interface(self, dev_handle, intf):
        self.claimed = False

    def is_kernel_driver_active(self, dev_handle, intf):
        self._alive()
        return self.kernel_driver_active

    def detach_kernel_driver(self, dev_handle, intf):
        self._alive()
        self.kernel_driver_active = False
        self.kernel_driver_detached += 1

    def attach_kernel_driver(self, dev_handle, intf):
        self._alive()
        self.kernel_driver_active = True
        self.kernel_driver_attached += 1

    def clear_halt(self, dev_handle, ep):
        self._alive()

    def reset_device(self, dev_handle):
        self._alive()
        self._in.clear()
        self.camera.reset()

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        self._alive()
        if bmRequestType == 0x21 and bRequest == 0x66:   # PTP Device Reset Request
            self.resets += 1
            self._in.clear()
            self._out = None
            self.camera.reset()
            return 0
        if bmRequestType == 0xA1 and bRequest == 0x67:   # PTP Get Device Status
            status = struct.pack("<HH", 4, RC.OK)
            n = min(len(data), len(status))
            data[:n] = array.array("B", status[:n])
            return n
        return 0

    # -- transfers ----------------------------------------------------------------------------
    def _check_claimed(self):
        if not self.claimed:
            raise _usb_error("Access denied (interface not claimed)", -3, errno.EACCES)

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        self._alive()
        self._check_claimed()
        written = len(data) * data.itemsize
        raw = bytes(memoryview(data).cast("B"))
        if self._out is not None:  # the data phase of the pending host -> camera operation
            cmd, got = self._out
            got += raw
            if len(got) < ptp.HEADER.size or len(got) < ptp.unpack_header(got)[0]:
                self._out = (cmd, got)
                return written
            self._out = None
            phase = ptp.unpack_container(got)
            if phase.type != ptp.ContainerType.DATA or phase.transaction_id != cmd.transaction_id:
                raise _usb_error("Pipe error", -9, errno.EPIPE)
            self._run(cmd, phase.payload)
            return written
        cmd = ptp.unpack_container(raw)
        if cmd.type != ptp.ContainerType.COMMAND:
            raise _usb_error("Pipe error", -9, errno.EPIPE)
        if cmd.code in DATA_OUT_OPS:
            self._out = (cmd, b"")
            return written
        self._run(cmd, None)
        return written

    def _run(self, cmd, out):
        """Execute a command (with the host's data phase ``out``) and queue its IN transfers."""
        if self.faults.take("stale_response", cmd.code):
            # the transaction before the first (OpenSession, id 0) wraps round to 0xFFFFFFFF
            self._in.append(_InTransfer([ptp.pack_response(RC.OK, (cmd.transaction_id - 1) & 0xFFFFFFFF)],
                                        cmd.code))
        payload, code, params = self.camera.execute(cmd.code, cmd.transaction_id, cmd.params,
                                                    out)
        if payload is not None:
            claimed = len(payload)
            if self.faults.take("length_lie", cmd.code):
                claimed = LENGTH_LIE
            elif self.faults.take("length_max", cmd.code):
                claimed = 0xFFFFFFF0 - ptp.HEADER.size
            t = _InTransfer([ptp.pack_data_header(cmd.code, cmd.transaction_id, claimed),
                             payload], cmd.code)
            t.trickle = self.faults.take("trickle", cmd.code)
            if cmd.code == Op.GetObject and self.faults.take("disconnect"):
                t.cut_at = t.length // 2
            self._in.append(t)
        self._in.append(_InTransfer([ptp.pack_response(code, cmd.transaction_id, params)],
                                    cmd.code))

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        self._alive()
        self._check_claimed()
        op = self._in[0].op if self._in else None
        if not self._in or self.faults.take("timeout", op):
            self._in.clear()  # a hung camera drops the transaction
            raise USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
        size, out, got = len(buff) * buff.itemsize, memoryview(buff).cast("B"), 0
        if self._in[0].trickle:
            time.sleep(TRICKLE_PAUSE)
        if self._in[0].remaining == 0:  # the zero-length packet ending a full-packet transfer
            self._in.popleft()
            return 0
        while self._in and got < size:
            t = self._in[0]
            n = min(size - got, t.remaining)
            if (size - got) % BULK_MPS and t.remaining > size - got:
                raise _usb_error("Overflow", -8, errno.EOVERFLOW)
            if t.cut_at is not None and t.pos + n > t.cut_at:
                self._disconnect()
            t.read_into(out[got:], n)
            got += n
            if t.remaining:
                break
            if t.length % BULK_MPS:          # a short packet ends the host's read
                self._in.popleft()
                break
            if got == size and self.send_zlp:
                break                         # buffer full on a packet boundary: ZLP pending
            self._in.popleft()
            if self.send_zlp:
                break                         # the ZLP ended the read
            # without a ZLP the host's read runs on into the next container
        return got

    def intr_read(self, dev_handle, ep, intf, buff, timeout):
        self._alive()
        self._check_claimed()
        if not self.camera.events:
            # a real device blocks until the timeout; a short sleep keeps pollers from spinning
            time.sleep(min(timeout / 1000.0, 0.002))
            raise USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
        event = self.camera.events.popleft()
        n = min(len(event), len(buff) * buff.itemsize)
        memoryview(buff).cast("B")[:n] = event[:n]
        return n


def make_backend(render, *, behaviour="generic", faults=None, vendor_id=None, product_id=None,
                 filename_ext=".DNG", serial="SIM0001") -> SimulatedUsbBackend:
    """Build a pyusb backend that is one simulated PTP camera.

    Parameters
    ----------
    render : callable
        ``render() -> bytes``: the image the sensor sees at the moment of the capture.
    behaviour : {'generic', 'canon', 'nikon'}
        Capture protocol the camera speaks; also picks default USB ids (Canon 0x04A9,
        Nikon 0x04B0).
    faults : dict or iterable, optional
        Faults armed from the start: ``{kind: count}`` or ``[(kind, count), ...]``.
    vendor_id, product_id : int, optional
    filename_ext : str
        Extension of the files the camera names, e.g. '.DNG' -> 'IMG_0001.DNG'.

    Returns
    -------
    SimulatedUsbBackend
    """
    if behaviour not in BEHAVIOURS:
        raise ValueError(f"unknown camera behaviour {behaviour!r}; known: {BEHAVIOURS}")
    vid, pid = _DEFAULT_IDS[behaviour]
    camera = SimulatedPtpCamera(render, behaviour, _Faults(), filename_ext, serial)
    backend = SimulatedUsbBackend(camera, vendor_id if vendor_id is not None else vid,
                                  product_id if product_id is not None else pid)
    items = faults.items() if isinstance(faults, dict) else (faults or ())
    for kind, count in items:
        backend.inject(kind, count)
    return backend
