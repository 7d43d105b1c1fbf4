"""Cameras: the Camera protocol and PtpCamera, a PTP-over-USB driver on pyusb.

PtpCamera speaks PTP (ISO 15740) on the still-image interface (class 6) of a USB camera:
OpenSession (SessionAlreadyOpened accepted), GetDeviceInfo, a capture sequence, GetObjectInfo,
GetObject (in chunks, zero-length packets handled, size verified), DeleteObject. Capture paths:

- ``generic``: InitiateCapture, then ObjectAdded / CaptureComplete on the interrupt endpoint;
- ``canon`` (EOS): SetRemoteMode + SetEventMode at open; RemoteReleaseOn/Off, GetEvent polling
  for ObjectAddedEx, TransferComplete after the download;
- ``nikon``: InitiateCaptureRecInSdram, DeviceReady until not busy, GetEvent polling for
  ObjectAddedInSDRAM;
- ``auto``: chosen from DeviceInfo's VendorExtensionID, the USB idVendor and the operations.

Exposure (:meth:`PtpCamera.set_exposure`): the rig's ``exposure:`` keys shutter, iso and aperture
are set once after opening, checked against what the camera allows and read back. ``generic`` and
``nikon`` use the PTP standard properties (GetDevicePropDesc / SetDevicePropValue /
GetDevicePropValue: ExposureTime 0x500D in 0.1 ms, FNumber 0x5007 x 100, ExposureIndex 0x500F);
``canon`` uses EOS_SetDevicePropValueEx with Canon's stop codes (0xD101..0xD103), its allowed
values and read-back from the GetEvent property records.

DeviceBusy (0x2019) is retried with exponential back-off. USB failures become
:class:`CameraError` subclasses whose message names the camera and the operation. After a timeout
or protocol error the next :meth:`PtpCamera.capture` resets the PTP channel and reopens the
session; after a disconnect it finds the camera again, so a capture can resume. A failed capture
never returns a frame and never deletes the image from the camera.
"""

from __future__ import annotations

import abc
import array
import errno
import logging
import time
from contextlib import contextmanager
from dataclasses import dataclass

import usb.core
import usb.util

from pipeline.core.errors import PsrigError
from rig import exposure as exposure_values, ptp
from rig.exposure import choose_value, format_exposure
from rig.ptp import EventCode, OperationCode as Op, PropCode, ResponseCode as RC

__all__ = [
    "CameraError",
    "CameraNotFound",
    "CameraBusy",
    "CameraTimeout",
    "CameraDisconnected",
    "CameraInterfaceClaimed",
    "CameraProtocolError",
    "CameraConfigError",
    "CameraExposureError",
    "CapturedImage",
    "Camera",
    "PtpCamera",
    "make_camera",
    "CONFIG_KEYS",
    "PATHS",
    "MAX_DATASET",
    "MAX_OBJECT",
    "MIN_TRANSFER_RATE",
    "choose_value",
    "format_exposure",
]

log = logging.getLogger(__name__)

PATHS = ("generic", "canon", "nikon", "auto")
CANON_VENDOR_ID, NIKON_VENDOR_ID = 0x04A9, 0x04B0
_STILL_IMAGE_CLASS = 6
_PTP_RESET_REQUEST, _PTP_CLASS_OUT = 0x66, 0x21
_EOS_FULL_PRESS = 3          # RemoteReleaseOn/Off button: half + full press
_NIKON_NO_AF = 0xFFFFFFFF    # InitiateCaptureRecInSdram parameter used by libgphoto2
#: Largest data phase (bytes) of an operation that returns a dataset (DeviceInfo, ObjectInfo,
#: property descriptions, event lists): a camera's length field is never trusted beyond it.
MAX_DATASET = 16 << 20
#: Largest object a capture may download (bytes): no raw file comes near it.
MAX_OBJECT = 1 << 30
#: Slowest transfer an exchange may take (bytes/s): an exchange's total deadline is the
#: timeout plus its size at this rate, however the camera spaces its packets.
MIN_TRANSFER_RATE = 1e6


class CameraError(PsrigError):
    """A camera cannot be used or a capture failed."""


class CameraNotFound(CameraError):
    """No matching USB PTP camera is connected."""


class CameraBusy(CameraError):
    """The camera kept answering DeviceBusy (0x2019) after every retry."""


class CameraTimeout(CameraError):
    """The camera did not answer (a transfer or an awaited event) in time."""


class CameraDisconnected(CameraError):
    """The camera vanished from the bus (cable, power, sleep)."""


class CameraInterfaceClaimed(CameraError):
    """Another program holds the camera's USB interface."""


class CameraProtocolError(CameraError):
    """The camera answered with an error code or with bytes that are not valid PTP."""


class CameraConfigError(CameraError):
    """A rig's ``camera:`` section is invalid."""


class CameraExposureError(CameraError):
    """The camera refused, or does not support, an exposure setting; names the key and value."""


@dataclass
class CapturedImage:
    """One downloaded frame, exactly as the camera stored it.

    Attributes
    ----------
    data : bytes
        File contents.
    filename : str
        The name the camera gave it, e.g. 'IMG_0001.DNG'.
    object_handle : int
        PTP object handle on the camera.
    size : int
        ``len(data)`` in bytes, equal to the camera's ObjectCompressedSize.
    format_code : int
        PTP object format code (0x3811 DNG, 0x3801 JPEG, ...).
    """

    data: bytes
    filename: str
    object_handle: int
    size: int
    format_code: int


class Camera(abc.ABC):
    """Protocol of every camera driver: open, capture, close (also as a context manager)."""

    @abc.abstractmethod
    def open(self) -> "Camera":
        """Connect to the camera; returns self."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the camera; safe to call twice."""

    @abc.abstractmethod
    def capture(self) -> CapturedImage:
        """Expose one frame and return its file."""

    @property
    @abc.abstractmethod
    def device_info(self) -> dict:
        """manufacturer, model, serial, operations supported, ..."""

    def set_exposure(self, exposure: dict) -> dict:
        """Set a rig's ``exposure:`` keys on the camera; returns what it reported back.

        Drivers that cannot set exposure refuse any non-empty section.
        """
        if exposure:
            raise CameraExposureError(f"{type(self).__name__} cannot set exposure "
                                      f"({', '.join(exposure)}); set it on the camera")
        return {}

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()


@dataclass
class _Response:
    code: int
    params: tuple
    data: bytes | None
    tid: int


def _is_disconnect(exc: usb.core.USBError) -> bool:
    return exc.errno == errno.ENODEV or exc.backend_error_code == -4


def _op_name(code: int) -> str:
    try:
        return Op(code).name
    except ValueError:
        return f"operation 0x{code:04X}"


def _rc_name(code: int) -> str:
    try:
        return f"{RC(code).name} (0x{code:04X})"
    except ValueError:
        return f"response 0x{code:04X}"


class PtpCamera(Camera):
    """A PTP camera on USB, driven through pyusb.

    Parameters
    ----------
    vendor_id, product_id : int, optional
        USB ids to match; by default the first device with a still-image interface.
    path : {'auto', 'generic', 'canon', 'nikon'}
        Capture sequence (see the module docstring).
    backend : usb.backend.IBackend, optional
        pyusb backend; default libusb. Tests pass a simulated camera's backend.
    timeout : float
        Seconds allowed for each USB transfer and for a capture's events to arrive.
    busy_retries : int
        Retries of an operation answered with DeviceBusy before :class:`CameraBusy`.
    chunk_size : int
        Bytes per bulk read (rounded up to whole 512-byte packets).
    delete_after_download : bool
        DeleteObject once a frame is downloaded and verified.
    busy_backoff : float
        First back-off delay in seconds, doubled per retry up to 1 s.
    get_object_retries : int
        Extra GetObject attempts when the object arrives shorter than announced.
    """

    def __init__(self, *, vendor_id=None, product_id=None, path="auto", backend=None,
                 timeout=5.0, busy_retries=8, chunk_size=1 << 20, delete_after_download=True,
                 busy_backoff=0.05, get_object_retries=1):
        if path not in PATHS:
            raise CameraConfigError(f"camera path {path!r} is not one of {', '.join(PATHS)}")
        self.vendor_id, self.product_id = vendor_id, product_id
        self.requested_path, self.path = path, None
        self.backend, self.timeout = backend, float(timeout)
        self.busy_retries, self.busy_backoff = int(busy_retries), float(busy_backoff)
        self.chunk_size = max(512, -(-int(chunk_size) // 512) * 512)
        self.delete_after_download = bool(delete_after_download)
        self.get_object_retries = int(get_object_retries)
        self._dev = None
        self._info: ptp.DeviceInfo | None = None
        self._stale = False
        self._tid = 0
        self._detached = None
        self._eos_values: dict[int, int] = {}
        self._eos_allowed: dict[int, list] = {}
        self._deadline = 0.0  # monotonic time the running exchange's first reply is due by
        self.shutter_seconds = 0.0  # set by set_exposure: a capture's events may come that late

    @property
    def _capture_wait(self) -> float:
        """Seconds to wait for a capture's image: the timeout after the shutter closes."""
        return self.timeout + self.shutter_seconds

    # -- naming and errors -------------------------------------------------------------------
    @property
    def name(self) -> str:
        model = self._info.model if self._info else "PTP camera"
        if self._dev is None:
            return f"camera {model}"
        return (f"camera {model} (USB {self._dev.idVendor:04x}:{self._dev.idProduct:04x}, "
                f"bus {self._dev.bus} address {self._dev.address})")

    @property
    def _ms(self) -> int:
        return max(1, int(self.timeout * 1000))

    def _raise_usb(self, exc: usb.core.USBError, what: str):
        if isinstance(exc, usb.core.USBTimeoutError):
            self._stale = True
            raise CameraTimeout(f"{self.name}: {what} timed out after {self.timeout:g} s "
                                f"(camera asleep or hung?)") from exc
        if _is_disconnect(exc):
            name = self.name
            self._drop_device()
            raise CameraDisconnected(f"{name}: disconnected during {what}; reconnect it and "
                                     f"capture again (nothing was deleted from it)") from exc
        self._stale = True
        raise CameraProtocolError(f"{self.name}: USB error during {what}: {exc}") from exc

    @contextmanager
    def _usb(self, what: str):
        try:
            yield
        except usb.core.USBError as exc:
            self._raise_usb(exc, what)
        except ptp.PtpDecodeError as exc:
            self._stale = True
            raise CameraProtocolError(f"{self.name}: {what}: {exc}") from exc

    # -- open / close ------------------------------------------------------------------------
    def open(self) -> "PtpCamera":
        if self._dev is not None:
            return self
        dev = usb.core.find(backend=self.backend, custom_match=self._matches)
        if dev is None:
            ids = "any" if self.vendor_id is None else f"{self.vendor_id:04x}:" + (
                "*" if self.product_id is None else f"{self.product_id:04x}")
            raise CameraNotFound(f"no USB PTP camera found (USB id {ids}); is it on, in "
                                 f"PTP/PC mode, and connected?")
        self._dev = dev
        try:
            self._claim(dev)
            self._open_session()
            self._info = ptp.DeviceInfo.unpack(self._data(Op.GetDeviceInfo))
            self.path = self._choose_path()
            self._prepare_path()
        except BaseException:
            self._release()
            raise
        log.info("%s opened, capture path %s", self.name, self.path)
        return self

    def _matches(self, dev) -> bool:
        if self.vendor_id is not None and dev.idVendor != self.vendor_id:
            return False
        if self.product_id is not None and dev.idProduct != self.product_id:
            return False
        return any(usb.util.find_descriptor(cfg, bInterfaceClass=_STILL_IMAGE_CLASS)
                   for cfg in dev)

    def _claim(self, dev):
        with self._usb("USB configuration"):
            try:
                cfg = dev.get_active_configuration()
            except usb.core.USBError:
                dev.set_configuration()
                cfg = dev.get_active_configuration()
            intf = usb.util.find_descriptor(cfg, bInterfaceClass=_STILL_IMAGE_CLASS)
            self._intf = intf.bInterfaceNumber
            if self._kernel_driver_active(dev):
                dev.detach_kernel_driver(self._intf)
                self._detached = self._intf
        try:
            usb.util.claim_interface(dev, self._intf)
        except usb.core.USBError as exc:
            if exc.errno == errno.EBUSY or exc.backend_error_code == -6:
                raise CameraInterfaceClaimed(
                    f"{self.name}: USB interface {self._intf} is claimed by another program "
                    f"(typically gvfs-gphoto2-volume-monitor, gphoto2, shotwell or a file "
                    f"manager); close it, e.g. 'pkill -f gvfs-gphoto2-volume-monitor'") from exc
            if exc.errno == errno.EACCES:
                raise CameraError(f"{self.name}: permission denied on the USB device; add a "
                                  f"udev rule for it or run as a member of its group") from exc
            self._raise_usb(exc, "claiming the interface")
        self._find_endpoints(intf)

    def _kernel_driver_active(self, dev) -> bool:
        try:
            return bool(dev.is_kernel_driver_active(self._intf))
        except NotImplementedError:  # backends without the notion (Windows, openusb)
            return False

    def _find_endpoints(self, intf):
        def ep(direction, kind):
            return usb.util.find_descriptor(intf, custom_match=lambda e: (
                usb.util.endpoint_direction(e.bEndpointAddress) == direction
                and usb.util.endpoint_type(e.bmAttributes) == kind))
        self._ep_in = ep(usb.util.ENDPOINT_IN, usb.util.ENDPOINT_TYPE_BULK)
        self._ep_out = ep(usb.util.ENDPOINT_OUT, usb.util.ENDPOINT_TYPE_BULK)
        self._ep_int = ep(usb.util.ENDPOINT_IN, usb.util.ENDPOINT_TYPE_INTR)
        if self._ep_in is None or self._ep_out is None:
            raise CameraProtocolError(f"{self.name}: still-image interface lacks bulk endpoints")
        self._buf = array.array("B", bytes(self.chunk_size))
        self._evbuf = array.array("B", bytes(64))
        self._assembly = bytearray()

    def _open_session(self):
        self._tid = 0  # OpenSession travels in transaction 0 (PTP 1.0, 9.2)
        resp = self._transaction(Op.OpenSession, (1,))
        if resp.code == RC.SessionAlreadyOpened:
            log.info("%s: a PTP session was already open; reusing it", self.name)
        else:
            self._check(resp, Op.OpenSession)

    def close(self) -> None:
        if self._dev is None:
            return
        try:
            if not self._stale:
                self._transaction(Op.CloseSession, retry_busy=False)
        except CameraError as exc:
            log.warning("%s: CloseSession failed: %s", self.name, exc)
        finally:
            self._release()

    def _release(self):
        dev, self._dev = self._dev, None
        if dev is None:
            return
        try:
            usb.util.release_interface(dev, self._intf)
            if self._detached is not None:
                dev.attach_kernel_driver(self._detached)
        except (usb.core.USBError, NotImplementedError, AttributeError):
            pass  # the device may be gone already; nothing left to release then
        finally:
            self._detached = None
            usb.util.dispose_resources(dev)

    def _drop_device(self):
        dev, self._dev = self._dev, None
        self._stale = False
        if dev is not None:
            usb.util.dispose_resources(dev)

    @property
    def device_info(self) -> dict:
        i = self._info
        if i is None:
            return {}
        version = i.standard_version
        return {"manufacturer": i.manufacturer, "model": i.model, "serial": i.serial_number,
                "ptp_version": f"{version // 100}.{version % 100:02d}",
                "device_version": i.device_version, "vendor_extension_id": i.vendor_extension_id,
                "vendor_extension_desc": i.vendor_extension_desc,
                "operations": list(i.operations), "events": list(i.events),
                "capture_formats": list(i.capture_formats),
                "image_formats": list(i.image_formats), "path": self.path}

    # -- transactions --------------------------------------------------------------------------
    def _next_tid(self) -> int:
        tid = self._tid
        self._tid = tid + 1 if tid < 0xFFFFFFFE else 1
        return tid

    def _transaction(self, code, params=(), *, retry_busy=True, data=None,
                     limit=MAX_DATASET) -> _Response:
        """Run one operation; DeviceBusy is retried with back-off unless ``retry_busy`` is off.

        ``data`` (bytes) is sent to the camera in a data phase (SetDevicePropValue, ...);
        ``limit`` is the most bytes the operation's data phase can hold (a longer claim is a
        protocol error, never an allocation).
        """
        delay, waited = self.busy_backoff, 0.0
        for attempt in range(self.busy_retries + 1):
            resp = self._transact_once(code, params, data, limit)
            if resp.code != RC.DeviceBusy or not retry_busy:
                return resp
            if attempt < self.busy_retries:
                time.sleep(delay)
                waited += delay
                delay = min(delay * 2, 1.0)
        raise CameraBusy(f"{self.name}: {_op_name(code)} still answered DeviceBusy (0x2019) "
                         f"after {self.busy_retries} retries over {waited:.2f} s")

    def _transact_once(self, code, params, out=None, limit=MAX_DATASET) -> _Response:
        tid = self._next_tid()
        what = _op_name(code)
        self._deadline = time.monotonic() + self.timeout
        with self._usb(what):
            self._dev.write(self._ep_out, ptp.pack_command(code, tid, params), self._ms)
            if out is not None:
                self._dev.write(self._ep_out, ptp.pack_container(
                    ptp.ContainerType.DATA, code, tid, (), out), self._ms)
            n = self._dev.read(self._ep_in, self._buf, self._ms)
            length, ctype, rcode, rtid = ptp.unpack_header(memoryview(self._buf)[:n])
            data, head = None, memoryview(self._buf)[:n]
            if ctype == ptp.ContainerType.DATA:
                self._expect(rcode, rtid, code, tid, "data")
                data, head = self._read_data_phase(n, length, limit, what)
            container = ptp.unpack_container(self._complete(head))
        if container.type != ptp.ContainerType.RESPONSE:
            self._stale = True
            raise CameraProtocolError(f"{self.name}: {what}: expected a response container, "
                                      f"got type {container.type}")
        self._expect(container.code, container.transaction_id, None, tid, "response")
        return _Response(container.code, container.params, data, tid)

    def _expect(self, code, tid, want_code, want_tid, kind):
        if tid != want_tid or (want_code is not None and code != want_code):
            self._stale = True
            raise CameraProtocolError(
                f"{self.name}: {kind} container for 0x{code:04X} transaction {tid} arrived "
                f"while waiting for transaction {want_tid}; the channel will be reset")

    def _read_data_phase(self, n, length, limit, what):
        """Collect a data container of ``length`` bytes whose first ``n`` are in the buffer.

        ``length`` is the camera's claim: above ``limit`` (what the operation can return) it
        is refused before anything is allocated, and the whole phase must arrive within the
        exchange's deadline (the timeout plus its size at :data:`MIN_TRANSFER_RATE`).

        Returns (payload bytes, memoryview of bytes already read past the container, which
        some cameras run straight into without a zero-length packet).
        """
        if length == 0xFFFFFFFF:  # PTP 1.0 marks data phases over 4 GiB this way
            raise ptp.PtpDecodeError("data phases over 4 GiB are not supported")
        size = length - ptp.HEADER.size
        if size > limit:
            raise ptp.PtpDecodeError(
                f"the camera announces a data phase of {size} bytes, but {what} returns at "
                f"most {limit} here; refused (a length the device got wrong)")
        deadline = self._deadline + size / MIN_TRANSFER_RATE
        if len(self._assembly) < size:  # kept between frames: fresh pages cost page faults
            self._assembly = bytearray(size)
        out, buf = memoryview(self._assembly)[:size], memoryview(self._buf)
        got = min(n, length) - ptp.HEADER.size
        out[:got] = buf[ptp.HEADER.size:ptp.HEADER.size + got]
        tail = bytes(buf[length:n]) if n > length else b""
        while got < size:
            if time.monotonic() > deadline:
                self._stale = True
                raise CameraTimeout(f"{self.name}: {what}: only {got} of {size} bytes arrived "
                                    f"within {self._deadline_span(size):.2f} s (the exchange's "
                                    f"deadline: the timeout plus the size at "
                                    f"{MIN_TRANSFER_RATE / 1e6:g} MB/s); any image stays on the "
                                    f"camera")
            k = self._dev.read(self._ep_in, self._buf, self._ms)
            if k == 0:
                raise ptp.PtpDecodeError(f"data phase ended after {got} of {size} bytes")
            take = min(k, size - got)
            out[got:got + take] = buf[:take]
            got += take
            if k > take:
                tail = bytes(buf[take:k])
        return bytes(out), memoryview(tail)

    def _deadline_span(self, size) -> float:
        """Seconds an exchange of ``size`` bytes may take in all."""
        return self.timeout + size / MIN_TRANSFER_RATE

    def _complete(self, head) -> bytes:
        """Bytes of the response container: ``head`` plus reads, skipping zero-length packets."""
        buf = bytes(head)
        for _ in range(4):
            if len(buf) >= ptp.HEADER.size and len(buf) >= ptp.unpack_header(buf)[0]:
                return buf[:ptp.unpack_header(buf)[0]]
            n = self._dev.read(self._ep_in, self._buf, self._ms)
            buf += bytes(memoryview(self._buf)[:n])  # n == 0: the ZLP ending a data phase
        raise ptp.PtpDecodeError(f"no complete response container ({len(buf)} bytes)")

    def _check(self, resp: _Response, code, ok=(RC.OK,)) -> _Response:
        if resp.code not in ok:
            self._stale |= resp.code in (RC.SessionNotOpen, RC.InvalidTransactionID)
            raise CameraProtocolError(f"{self.name}: {_op_name(code)} failed: camera answered "
                                      f"{_rc_name(resp.code)}")
        return resp

    def _data(self, code, *params, limit=MAX_DATASET) -> bytes:
        resp = self._check(self._transaction(code, params, limit=limit), code)
        if resp.data is None:
            raise CameraProtocolError(f"{self.name}: {_op_name(code)} returned no data")
        return resp.data

    # -- capture paths -------------------------------------------------------------------------
    def _choose_path(self) -> str:
        ops, info = set(self._info.operations), self._info
        if self.requested_path != "auto":
            return self.requested_path
        if ((info.vendor_extension_id == ptp.VendorExtension.CANON
             or self._dev.idVendor == CANON_VENDOR_ID)
                and {Op.EOS_RemoteReleaseOn, Op.EOS_GetEvent} <= ops):
            return "canon"
        if ((info.vendor_extension_id == ptp.VendorExtension.NIKON
             or self._dev.idVendor == NIKON_VENDOR_ID)
                and {Op.NIKON_InitiateCaptureRecInSdram, Op.NIKON_GetEvent} <= ops):
            return "nikon"
        if Op.InitiateCapture in ops:
            return "generic"
        raise CameraProtocolError(f"{self.name}: supports no remote capture operation known "
                                  f"to psrig (neither InitiateCapture nor Canon/Nikon ones)")

    def _prepare_path(self):
        if self.path == "canon":
            self._check(self._transaction(Op.EOS_SetRemoteMode, (1,)), Op.EOS_SetRemoteMode)
            self._check(self._transaction(Op.EOS_SetEventMode, (1,)), Op.EOS_SetEventMode)
            self._eos_added()  # the first GetEvent dumps the camera state: discard it
        elif self.path == "nikon":
            self._nikon_added()
        else:
            self._drain_events()

    def capture(self) -> CapturedImage:
        """Expose one frame, download it, verify its size and (by default) delete it.

        Raises
        ------
        CameraBusy, CameraTimeout, CameraDisconnected, CameraProtocolError
            The frame is then not returned; the image, if taken, stays on the camera.
        """
        self._ensure_ready()
        try:
            trigger = {"generic": self._trigger_generic, "canon": self._trigger_canon,
                       "nikon": self._trigger_nikon}[self.path]
            return self._download(trigger())
        except CameraError:
            if self._dev is not None:
                self._stale = True
            raise

    def _ensure_ready(self):
        if self._dev is None:
            self.open()
        elif self._stale:
            self._reset()

    def _reset(self):
        """PTP Device Reset class request, then a fresh session: recovers a hung transaction."""
        log.warning("%s: resetting the PTP channel after an error", self.name)
        with self._usb("device reset"):
            self._dev.ctrl_transfer(_PTP_CLASS_OUT, _PTP_RESET_REQUEST, 0, self._intf, None,
                                    self._ms)
            for ep in (self._ep_in, self._ep_out, self._ep_int):
                if ep is not None:
                    self._dev.clear_halt(ep)
        self._stale = False
        self._open_session()
        self._prepare_path()

    def _read_event(self, timeout_s: float):
        """Next event container from the interrupt endpoint, or None after ``timeout_s``."""
        if self._ep_int is None:
            time.sleep(timeout_s)
            return None
        try:
            n = self._dev.read(self._ep_int, self._evbuf, max(1, int(timeout_s * 1000)))
        except usb.core.USBTimeoutError:
            return None
        except usb.core.USBError as exc:
            self._raise_usb(exc, "reading camera events")
        with self._usb("reading camera events"):
            return ptp.unpack_container(memoryview(self._evbuf)[:n])

    def _drain_events(self):
        while self._read_event(0.001) is not None:
            pass

    def _trigger_generic(self) -> list[int]:
        # no drain here: the previous capture consumed its events up to CaptureComplete, and
        # open/reset drain the rest, so a 1 ms drain timeout per frame is not paid
        resp = self._check(self._transaction(Op.InitiateCapture, (0, 0)), Op.InitiateCapture)
        handles, deadline = [], time.monotonic() + self._capture_wait
        while time.monotonic() < deadline:
            ev = self._read_event(deadline - time.monotonic())
            if ev is None:
                continue
            if ev.code == EventCode.ObjectAdded and ev.params:
                if not handles:  # CaptureComplete should follow at once; some never send it
                    deadline = min(deadline, time.monotonic() + 2.0)
                handles.append(ev.params[0])
            elif ev.code == EventCode.CaptureComplete and (handles or ev.transaction_id
                                                           == resp.tid):
                break
        if not handles:
            raise CameraTimeout(f"{self.name}: no ObjectAdded event within "
                                f"{self._capture_wait:g} s of InitiateCapture; any image taken "
                                f"stays on the camera")
        return handles

    def _poll(self, fetch, what: str) -> int:
        """Call ``fetch()`` until it returns a handle, with growing pauses, until the timeout
        (counted from the end of the exposure)."""
        deadline, pause = time.monotonic() + self._capture_wait, 0.001
        while True:
            handle = fetch()
            if handle is not None:
                return handle
            if time.monotonic() >= deadline:
                raise CameraTimeout(f"{self.name}: {what} reported no new image within "
                                    f"{self._capture_wait:g} s; any image taken stays on the "
                                    f"camera")
            time.sleep(pause)
            pause = min(pause * 2, 0.05)

    def _eos_added(self):
        """Poll EOS GetEvent once: the first new object's handle (or None); property values
        and allowed lists in the records are kept for :meth:`set_exposure`."""
        records = ptp.unpack_eos_events(self._data(Op.EOS_GetEvent))
        values, allowed = ptp.eos_prop_records(records)
        self._eos_values.update(values)
        self._eos_allowed.update(allowed)
        for rec in records:
            if isinstance(rec, ptp.EosObjectAdded):
                return rec.handle
        return None

    def _trigger_canon(self) -> int:
        self._eos_added()
        for code in (Op.EOS_RemoteReleaseOn, Op.EOS_RemoteReleaseOff):
            params = (_EOS_FULL_PRESS, 0) if code == Op.EOS_RemoteReleaseOn else (
                _EOS_FULL_PRESS,)
            self._check(self._transaction(code, params), code)
        return [self._poll(self._eos_added, "Canon EOS GetEvent")]

    def _nikon_added(self):
        for code, param in ptp.unpack_nikon_events(self._data(Op.NIKON_GetEvent)):
            if code == EventCode.NIKON_ObjectAddedInSDRAM:
                return param
        return None

    def _trigger_nikon(self) -> int:
        op = Op.NIKON_InitiateCaptureRecInSdram
        self._check(self._transaction(op, (_NIKON_NO_AF,)), op)
        deadline, pause = time.monotonic() + self._capture_wait, 0.001
        while self._transaction(Op.NIKON_DeviceReady, retry_busy=False).code == RC.DeviceBusy:
            if time.monotonic() >= deadline:
                raise CameraBusy(f"{self.name}: still busy {self.timeout:g} s after "
                                 f"InitiateCaptureRecInSdram (DeviceReady answers 0x2019)")
            time.sleep(pause)
            pause = min(pause * 2, 0.05)
        return [self._poll(self._nikon_added, "Nikon GetEvent")]

    def _pick_image(self, handles: list[int]) -> tuple[int, ptp.ObjectInfo]:
        """The first added object that is a file, not a new folder (association)."""
        for handle in handles:
            info = ptp.ObjectInfo.unpack(self._data(Op.GetObjectInfo, handle))
            if info.object_format != ptp.ObjectFormat.Association:
                if len(handles) > 1:
                    log.info("%s: capture added %d objects; downloading %s, the others stay "
                             "on the camera", self.name, len(handles), info.filename)
                return handle, info
        raise CameraProtocolError(f"{self.name}: the capture added only folders "
                                  f"(handles {', '.join(f'0x{h:08X}' for h in handles)})")

    def _download(self, handles: list[int]) -> CapturedImage:
        handle, info = self._pick_image(handles)
        if info.compressed_size != 0xFFFFFFFF and info.compressed_size > MAX_OBJECT:
            raise CameraProtocolError(f"{self.name}: object {info.filename!r} (handle "
                                      f"0x{handle:08X}) claims {info.compressed_size} bytes, more "
                                      f"than the {MAX_OBJECT} psrig downloads; it stays on the camera")
        limit = MAX_OBJECT if info.compressed_size == 0xFFFFFFFF else info.compressed_size
        for attempt in range(1 + self.get_object_retries):
            data = self._data(Op.GetObject, handle, limit=limit)
            if len(data) == info.compressed_size or info.compressed_size == 0xFFFFFFFF:
                break
            log.warning("%s: %s arrived with %d of %d bytes (attempt %d)", self.name,
                        info.filename, len(data), info.compressed_size, attempt + 1)
        else:
            raise CameraProtocolError(
                f"{self.name}: object {info.filename} (handle 0x{handle:08X}) arrived truncated:"
                f" {len(data)} of {info.compressed_size} bytes in each of "
                f"{1 + self.get_object_retries} attempts; it stays on the camera")
        if self.path == "canon":
            self._check(self._transaction(Op.EOS_TransferComplete, (handle,)),
                        Op.EOS_TransferComplete)
        if self.delete_after_download:
            resp = self._transaction(Op.DeleteObject, (handle,))
            if resp.code != RC.OK:  # the frame is safe in hand; a full card is the only risk
                log.warning("%s: DeleteObject %s answered %s", self.name, info.filename,
                            _rc_name(resp.code))
        return CapturedImage(data, info.filename, handle, len(data), info.object_format)

    # -- exposure ------------------------------------------------------------------------------
    def set_exposure(self, exposure: dict) -> dict:
        """Set shutter, iso and aperture on the camera, each checked and read back.

        Parameters
        ----------
        exposure : dict
            A rig's ``exposure:`` section: ``shutter`` (seconds: '1/30', 0.033, 2),
            ``iso`` (100) and ``aperture`` (f-number: 8, 'f/5.6'); any of them may be absent.

        Returns
        -------
        dict
            Per key what the camera reported back after setting it: ``value`` (seconds,
            ISO or f-number, the nominal value the camera shows), ``display`` ('1/30 s',
            'ISO 100', 'f/8'), ``requested`` (the rig's text), ``property`` ('0x500D
            ExposureTime') and ``device_value`` (the raw property value).

        Raises
        ------
        CameraExposureError
            A value the camera does not allow (the message lists the nearest allowed
            values), a property it does not support or will not let the host set, or a
            read-back that differs from the value set.
        CameraConfigError
            An unknown key or a value that is not a number.
        """
        unknown = sorted(set(exposure) - set(exposure_values.EXPOSURE_KEYS))
        if unknown:
            raise CameraConfigError(f"exposure: unknown key(s) {', '.join(unknown)}; known: "
                                    f"{', '.join(exposure_values.EXPOSURE_KEYS)}")
        self._ensure_ready()
        report = {}
        for key in exposure_values.EXPOSURE_KEYS:
            if exposure.get(key) is None:
                continue
            try:
                want = exposure_values.PARSERS[key](exposure[key])
            except ValueError as exc:
                raise CameraConfigError(str(exc)) from None
            setter = self._set_eos if self.path == "canon" else self._set_standard
            record = setter(key, exposure[key], want)
            report[key] = {"requested": exposure[key], **record}
            log.info("%s: exposure.%s set to %s", self.name, key, record["display"])
            if key == "shutter":
                self.shutter_seconds = float(record["value"] or 0.0)
        return report

    def _exposure_error(self, key, requested, message):
        return CameraExposureError(f"{self.name}: exposure.{key}: {requested!r}: {message}")

    def _unsupported(self, key, requested, code, why):
        return self._exposure_error(
            key, requested, f"the camera does not support setting {_KEY_NAME[key]} "
            f"(property 0x{code:04X} {_prop_name(code)}: {why})")

    def _set_standard(self, key, requested, want) -> dict:
        code = _STANDARD[key]
        ops = set(self._info.operations)
        missing = [_op_name(op) for op in (Op.GetDevicePropDesc, Op.SetDevicePropValue,
                                           Op.GetDevicePropValue) if op not in ops]
        if missing:
            raise self._unsupported(key, requested, code, f"no {', '.join(missing)} operation")
        resp = self._transaction(Op.GetDevicePropDesc, (code,))
        if resp.code in (RC.DevicePropNotSupported, RC.ParameterNotSupported):
            raise self._unsupported(key, requested, code, f"GetDevicePropDesc answered "
                                                          f"{_rc_name(resp.code)}")
        self._check(resp, Op.GetDevicePropDesc)
        with self._usb("GetDevicePropDesc"):
            desc = ptp.DevicePropDesc.unpack(resp.data or b"")
        if not desc.writable:
            raise self._exposure_error(key, requested, f"{_KEY_NAME[key]} is read-only on this "
                                       f"camera now (set by the lens or the mode dial? use M)")
        device = self._standard_value(key, requested, want, desc)
        with self._usb("SetDevicePropValue"):
            payload = ptp.pack_value(desc.datatype, device)
        resp = self._transaction(Op.SetDevicePropValue, (code,), data=payload)
        self._check_set(key, requested, want, code, resp, Op.SetDevicePropValue,
                        lambda: self._allowed_standard(key, desc), device)
        with self._usb("GetDevicePropValue"):
            got = ptp.unpack_value(ptp.Reader(self._data(Op.GetDevicePropValue, code)),
                                   desc.datatype)
        value = exposure_values.decode_standard(key, got)
        return self._verified(key, requested, code, device, got, value)

    def _standard_value(self, key, requested, want, desc) -> int:
        """The device value to set: the allowed value matching ``want`` (or an error)."""
        if desc.form == ptp.FormFlag.ENUMERATION:
            pairs = self._allowed_standard(key, desc)
            device, nearest = choose_value(key, want, pairs)
            if device is None:
                raise self._refused(key, requested, want, nearest, pairs)
            return device
        device = exposure_values.encode_standard(key, want)
        if desc.form == ptp.FormFlag.RANGE:
            low, high, step = desc.range
            snapped = min(max(device, low), high)
            snapped = low + round((snapped - low) / max(step, 1)) * max(step, 1)
            decode = exposure_values.decode_standard
            ok = desc.allows(device) or (exposure_values.stop_distance(key, want, decode(key, snapped))
                                         <= exposure_values.TOLERANCE[key] and desc.allows(snapped))
            if not ok:
                span = (f"{format_exposure(key, decode(key, low))} .. "
                        f"{format_exposure(key, decode(key, high))}")
                raise self._exposure_error(
                    key, requested, f"{format_exposure(key, want)} is outside what the camera "
                    f"allows ({span}, steps of {step}); nearest allowed: "
                    f"{format_exposure(key, decode(key, snapped))}")
            return device if desc.allows(device) else snapped
        return device

    def _allowed_standard(self, key, desc) -> list:
        values = desc.values or ([] if desc.range is None else list(desc.range[:2]))
        return [(v, exposure_values.decode_standard(key, v)) for v in values if v > 0]

    def _refused(self, key, requested, want, nearest, pairs):
        shown = ", ".join(format_exposure(key, value) for _, value in nearest)
        values = sorted(v for _, v in pairs)
        span = (f"{len(values)} allowed, {format_exposure(key, values[0])} .. "
                f"{format_exposure(key, values[-1])}") if values else "none allowed"
        return self._exposure_error(
            key, requested, f"{format_exposure(key, want)} is not one of the {_PLURAL[key]} "
            f"this camera allows now; nearest allowed: {shown} ({span})")

    def _check_set(self, key, requested, want, code, resp, op, allowed, device):
        """Turn the answer to a Set operation into a named error."""
        if resp.code == RC.InvalidDevicePropValue:
            pairs = [p for p in allowed() if p[0] != device]
            _, nearest = choose_value(key, want, pairs)
            raise self._exposure_error(
                key, requested, f"the camera refused {format_exposure(key, want)} "
                f"({_rc_name(resp.code)}); nearest allowed: "
                f"{', '.join(format_exposure(key, v) for _, v in nearest) or 'unknown'}")
        if resp.code in (RC.DevicePropNotSupported, RC.ParameterNotSupported):
            raise self._unsupported(key, requested, code, f"{_op_name(op)} answered "
                                                          f"{_rc_name(resp.code)}")
        if resp.code == RC.AccessDenied:
            raise self._exposure_error(key, requested, f"the camera denied setting "
                                       f"{_KEY_NAME[key]} ({_rc_name(resp.code)}); is it in M mode?")
        self._check(resp, op)

    def _verified(self, key, requested, code, device, got, value) -> dict:
        if got != device:
            raise self._exposure_error(
                key, requested, f"set to device value {device} "
                f"({format_exposure(key, _decode(key, code, device))}) but the camera reports "
                f"{got} ({format_exposure(key, value) if value else 'auto'})")
        return {"value": value, "display": format_exposure(key, value),
                "property": f"0x{code:04X} {_prop_name(code)}", "device_value": int(got)}

    def _set_eos(self, key, requested, want) -> dict:
        code = exposure_values.EOS_SCALES[key]["code"]
        if Op.EOS_SetDevicePropValueEx not in set(self._info.operations):
            raise self._unsupported(key, requested, code, "no EOS_SetDevicePropValueEx operation")
        self._eos_added()  # fresh values and allowed lists

        def allowed():
            codes = self._eos_allowed.get(code) or exposure_values.eos_table(key)
            return [(c, exposure_values.eos_decode(key, c)) for c in codes if c != 0]

        pairs = allowed()
        device, nearest = choose_value(key, want, pairs)
        if device is None:
            raise self._refused(key, requested, want, nearest, pairs)
        resp = self._transaction(Op.EOS_SetDevicePropValueEx,
                                 data=ptp.pack_eos_set_prop(code, device))
        self._check_set(key, requested, want, code, resp, Op.EOS_SetDevicePropValueEx, allowed,
                        device)
        # the camera reports the new value in a PropValueChanged record of a later GetEvent
        deadline, pause = time.monotonic() + self.timeout, 0.001
        self._eos_values.pop(code, None)
        while True:
            self._eos_added()
            if code in self._eos_values or time.monotonic() >= deadline:
                break
            time.sleep(pause)
            pause = min(pause * 2, 0.05)
        if code not in self._eos_values:
            raise self._exposure_error(key, requested, f"the camera did not report "
                                       f"{_KEY_NAME[key]} back within {self.timeout:g} s")
        got = self._eos_values[code]
        return self._verified(key, requested, code, device, got,
                              exposure_values.eos_decode(key, got))


# -- exposure helpers ---------------------------------------------------------------------------
_KEY_NAME = {"shutter": "shutter time", "iso": "ISO speed", "aperture": "aperture"}
_PLURAL = {"shutter": "shutter times", "iso": "ISO speeds", "aperture": "apertures"}
_STANDARD = {"shutter": PropCode.ExposureTime, "iso": PropCode.ExposureIndex,
             "aperture": PropCode.FNumber}


def _prop_name(code: int) -> str:
    try:
        return PropCode(code).name
    except ValueError:
        return "property"


def _decode(key, code, device):
    """Nominal value of a device value: Canon EOS codes (0xD...) or a standard property's."""
    if code >= 0xD000:
        return exposure_values.eos_decode(key, device)
    return exposure_values.decode_standard(key, device)


#: keys a rig's ``camera:`` section may hold (rig.config can validate against these)
CONFIG_KEYS = ("driver", "vendor_id", "product_id", "path", "timeout", "busy_retries",
                "chunk_size", "delete_after_download", "busy_backoff")


def _boolean(value) -> bool:
    """YAML booleans only: a string such as 'no' must not silently become True."""
    if not isinstance(value, bool):
        raise ValueError(value)
    return value


_CONVERT = {"path": str, "timeout": float, "busy_retries": int, "chunk_size": int,
            "delete_after_download": _boolean, "busy_backoff": float}


def _usb_id(config: dict, key: str):
    value = config.get(key)
    if value is None or isinstance(value, int) and not isinstance(value, bool):
        return value
    try:
        return int(str(value), 0)
    except ValueError:
        raise CameraConfigError(f"camera: {key} {value!r} is not a USB id "
                                f"(e.g. 0x04a9)") from None


def make_camera(config: dict, backend=None) -> Camera:
    """Build a camera from a rig's ``camera:`` section.

    Parameters
    ----------
    config : dict
        ``driver: ptp`` with optional ``vendor_id``, ``product_id`` (ints or '0x04a9'
        strings), ``path``, ``timeout`` (s), ``busy_retries``, ``chunk_size`` (bytes),
        ``delete_after_download``, ``busy_backoff`` (s).
    backend : usb.backend.IBackend, optional
        pyusb backend, e.g. a simulated camera's.
    """
    if not isinstance(config, dict):
        raise CameraConfigError(f"camera: expected a mapping, got {type(config).__name__}")
    unknown = sorted(set(config) - set(CONFIG_KEYS))
    if unknown:
        raise CameraConfigError(f"camera: unknown key(s) {', '.join(unknown)}; "
                                f"known: {', '.join(CONFIG_KEYS)}")
    driver = config.get("driver", "ptp")
    if driver != "ptp":
        raise CameraConfigError(f"camera: driver {driver!r} is not known (known: ptp)")
    kwargs = {}
    for key, convert in _CONVERT.items():
        if key in config:
            try:
                kwargs[key] = convert(config[key])
            except (TypeError, ValueError):
                raise CameraConfigError(f"camera: {key} {config[key]!r} is not a valid "
                                        f"{convert.__name__}") from None
    return PtpCamera(vendor_id=_usb_id(config, "vendor_id"),
                     product_id=_usb_id(config, "product_id"), backend=backend, **kwargs)
