"""A camera driven by libgphoto2 (python-gphoto2): ``camera: {driver: gphoto2}``.

Install with ``pip install 'psrig[gphoto2]'`` (the wheels bundle libgphoto2 and its camlibs).
Capture: ``gp_camera_capture`` (image), ``file_get`` of the new file (the raw as the camera
stored it), ``file_delete``. Exposure: shutter, ISO and aperture through gphoto2's config tree
(``shutterspeed``, ``iso``, ``aperture`` / ``f-number`` widgets); a value the camera does not
offer is refused with the nearest offered ones, as :class:`rig.camera.PtpCamera` does.
gphoto2's errors become psrig's camera errors: busy -> CameraBusy, timeout -> CameraTimeout,
I/O -> CameraDisconnected, model/port/file not found -> CameraNotFound, not supported ->
CameraProtocolError (CameraExposureError when setting exposure).
"""

import importlib

from rig import exposure as exposure_values
from rig.camera import (Camera, CameraBusy, CameraDisconnected, CameraError, CameraExposureError,
                        CameraNotFound, CameraProtocolError, CameraTimeout, CapturedImage)
from rig.exposure import choose_value, format_exposure

__all__ = ["Gphoto2Camera", "WIDGETS", "error_class"]

#: config-tree widget names tried for each exposure key, in order
WIDGETS = {"shutter": ("shutterspeed", "shutterspeed2", "exposuretime"),
           "iso": ("iso", "isospeed"),
           "aperture": ("aperture", "f-number", "fnumber")}
_BUSY, _TIMEOUT = (-110,), (-10,)
_IO = (-7, -31, -34, -35, -37, -51, -53, -60)
_NOT_FOUND = (-52, -105, -107, -108, -5)
_UNSUPPORTED = (-6, -2)


def error_class(code):
    """psrig's camera error class for a gphoto2 error code."""
    if code in _BUSY:
        return CameraBusy
    if code in _TIMEOUT:
        return CameraTimeout
    if code in _IO:
        return CameraDisconnected
    if code in _NOT_FOUND:
        return CameraNotFound
    return CameraProtocolError


def _parse(key, text):
    """The nominal value of a widget choice ('1/30', '0.0200s', 'f/5.6', '100', 'Auto')."""
    text = str(text).strip()
    try:
        return exposure_values.nominal(key, exposure_values.PARSERS[key](text))
    except ValueError:
        return None  # 'Auto', 'Bulb' ...: never matched to a number


class Gphoto2Camera(Camera):
    """A camera through libgphoto2.

    Parameters
    ----------
    model : str, optional
        Model name as ``gphoto2 --auto-detect`` prints it; default the first camera found.
    port : str, optional
        Port, e.g. ``usb:001,007``.
    timeout : float
        Seconds (recorded; libgphoto2 applies its own per-camlib timeouts).
    delete_after_download : bool
        Delete the file from the camera once downloaded.
    gp : module, optional
        The gphoto2 module (tests pass a fake); default ``import gphoto2``.
    """

    def __init__(self, *, model=None, port=None, timeout=10.0, delete_after_download=True, gp=None):
        self.model, self.port, self.timeout = model, port, float(timeout)
        self.delete_after_download = bool(delete_after_download)
        self._gp = gp
        self._camera = None
        self._info = {}

    @property
    def gp(self):
        if self._gp is None:
            try:
                self._gp = importlib.import_module("gphoto2")
            except ImportError:
                raise CameraError("camera.driver gphoto2 needs python-gphoto2: "
                                  "pip install 'psrig[gphoto2]'") from None
        return self._gp

    @property
    def name(self):
        return f"camera {self._info.get('model') or self.model or '(gphoto2)'}"

    def _fail(self, exc, what):
        code = getattr(exc, "code", None)
        cls = error_class(code)
        if isinstance(exc, self.gp.GPhoto2Error):
            raise cls(f"{self.name}: {what}: gphoto2 error {code} ({exc})") from None
        raise exc

    def _call(self, what, func, *args):
        try:
            return func(*args)
        except self.gp.GPhoto2Error as exc:
            self._fail(exc, what)

    def open(self):
        if self._camera is not None:
            return self
        gp = self.gp
        camera = gp.Camera()
        if self.model or self.port:
            self._call("choosing the camera", self._choose, camera)
        self._call("connecting (gp_camera_init)", camera.init)
        self._camera = camera
        summary = str(self._call("reading the summary", camera.get_summary))
        self._info = _summary_fields(summary)
        return self

    def _choose(self, camera):
        gp = self.gp
        if self.model:
            abilities = gp.CameraAbilitiesList()
            abilities.load()
            camera.set_abilities(abilities[abilities.lookup_model(self.model)])
        if self.port:
            ports = gp.PortInfoList()
            ports.load()
            camera.set_port_info(ports[ports.lookup_path(self.port)])

    def close(self):
        camera, self._camera = self._camera, None
        if camera is not None:
            try:
                camera.exit()
            except self.gp.GPhoto2Error:
                pass  # gone already: nothing left to release

    @property
    def device_info(self):
        return dict(self._info, path="gphoto2")

    def capture(self):
        """Capture, download the new file as stored, delete it from the card."""
        self.open()
        gp = self.gp
        path = self._call("capturing (gp_camera_capture)", self._camera.capture, gp.GP_CAPTURE_IMAGE)
        where = f"{path.folder}/{path.name}"
        file = self._call(f"downloading {where}", self._camera.file_get, path.folder, path.name,
                          gp.GP_FILE_TYPE_NORMAL)
        data = bytes(memoryview(self._call(f"reading {where}", file.get_data_and_size)))
        if self.delete_after_download:
            self._call(f"deleting {where}", self._camera.file_delete, path.folder, path.name)
        return CapturedImage(data, path.name, 0, len(data), 0)

    def set_exposure(self, exposure):
        """Set shutter, iso and aperture through the config tree, each checked and read back."""
        self.open()
        report = {}
        for key in exposure_values.EXPOSURE_KEYS:
            if exposure.get(key) is None:
                continue
            report[key] = self._set_one(key, exposure[key])
        return report

    def _widget(self, config, key, requested):
        for name in WIDGETS[key]:
            try:
                return config.get_child_by_name(name)
            except self.gp.GPhoto2Error:
                continue
        raise CameraExposureError(f"{self.name}: exposure.{key}: {requested!r}: the camera offers "
                                  f"no {' / '.join(WIDGETS[key])} setting in its config tree")

    def _set_one(self, key, requested):
        try:
            want = exposure_values.PARSERS[key](requested)
        except ValueError as exc:
            raise CameraExposureError(str(exc)) from None
        config = self._call("reading the config tree", self._camera.get_config)
        widget = self._widget(config, key, requested)
        choices = [widget.get_choice(i) for i in range(widget.count_choices())]
        pairs = [(c, v) for c in choices if (v := _parse(key, c)) is not None]
        choice, nearest = choose_value(key, want, pairs)
        if choice is None:
            shown = ", ".join(format_exposure(key, v) for _, v in nearest) or "none"
            raise CameraExposureError(f"{self.name}: exposure.{key}: {requested!r}: "
                                      f"{format_exposure(key, want)} is not offered by the camera; "
                                      f"nearest allowed: {shown}")
        widget.set_value(choice)
        self._call(f"setting {widget.get_name()}", self._camera.set_config, config)
        got = self._call("reading the config tree", self._camera.get_config)
        value = self._widget(got, key, requested).get_value()
        if value != choice:
            raise CameraExposureError(f"{self.name}: exposure.{key}: set to {choice!r} but the "
                                      f"camera reports {value!r}")
        nominal = _parse(key, value)
        return {"requested": requested, "value": nominal, "display": format_exposure(key, nominal),
                "property": f"gphoto2 {widget.get_name()}", "device_value": value}


def _summary_fields(summary):
    """model, manufacturer, serial from a gphoto2 summary text."""
    fields = {}
    for line in summary.splitlines():
        name, sep, value = line.partition(":")
        key = {"model": "model", "manufacturer": "manufacturer",
               "serial number": "serial"}.get(name.strip().lower())
        if sep and key and key not in fields:
            fields[key] = value.strip()
    return fields
