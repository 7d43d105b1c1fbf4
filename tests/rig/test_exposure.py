"""Exposure over PTP: value codecs, PtpCamera.set_exposure against the simulated camera (generic,
Canon EOS, Nikon), the simulated sensor's response to the shutter, and capture_session."""

import io

import numpy as np
import pytest
import tifffile

from pipeline.core.session import Session
from rig import exposure as exposure_values, ptp
from rig.camera import CameraConfigError, CameraExposureError, PtpCamera, choose_value
from rig.capture import CaptureError, capture_session
from rig.config import ConfigError, get_rig, parse_rigs
from rig.ptp import DataType, EventCode, OperationCode as Op, PropCode
from rig.sim.rig import SimulatedRig
from rig.sim.usb_camera import REFERENCE_SHUTTER, make_backend

BEHAVIOURS = ("generic", "canon", "nikon")
SHUTTER_CODE = {"generic": PropCode.ExposureTime, "nikon": PropCode.ExposureTime,
                "canon": PropCode.EOS_ShutterSpeed}
APERTURE_CODE = {"generic": PropCode.FNumber, "nikon": PropCode.FNumber,
                 "canon": PropCode.EOS_Aperture}
ISO_CODE = {"generic": PropCode.ExposureIndex, "nikon": PropCode.ExposureIndex,
            "canon": PropCode.EOS_ISOSpeed}


def camera(backend, **kw):
    return PtpCamera(backend=backend, timeout=1.0, busy_backoff=0.001, **kw)


def backend(behaviour):
    return make_backend(lambda: b"\x00" * 64, behaviour=behaviour)


# -- parsing and codecs -----------------------------------------------------------------------

@pytest.mark.parametrize("text, seconds", [("1/30", 1 / 30), (0.033, 0.033), ("2", 2.0), (2, 2.0),
                                           ("1/30s", 1 / 30), (" 1 / 125 ", 1 / 125),
                                           ("0.5", 0.5), ("30", 30.0)])
def test_parse_shutter(text, seconds):
    assert exposure_values.parse_shutter(text) == pytest.approx(seconds, rel=1e-12)


@pytest.mark.parametrize("bad", ["fast", "1/0", 0, -1, "-1/30", True, "", "1/30/2", float("inf")])
def test_parse_shutter_refuses(bad):
    with pytest.raises(ValueError, match="exposure.shutter"):
        exposure_values.parse_shutter(bad)


def test_parse_aperture_and_iso():
    assert [exposure_values.parse_aperture(v) for v in (8, "f/5.6", "F11", "2.8")] == [8.0, 5.6, 11.0, 2.8]
    assert exposure_values.parse_iso("200") == 200 and exposure_values.parse_iso(100.0) == 100
    with pytest.raises(ValueError, match="exposure.iso.*whole"):
        exposure_values.parse_iso(100.5)
    with pytest.raises(ValueError, match="exposure.aperture"):
        exposure_values.parse_aperture("wide")


def test_value_widths_follow_the_datatype():
    assert ptp.pack_value(DataType.UINT16, 800) == b"\x20\x03"
    assert ptp.pack_value(DataType.UINT32, 333) == (333).to_bytes(4, "little")
    assert ptp.pack_value(DataType.INT8, -1) == b"\xff"
    with pytest.raises(ValueError, match="UINT16"):
        ptp.pack_value(DataType.UINT16, 70000)


def test_device_prop_desc_roundtrip():
    enum = ptp.DevicePropDesc(PropCode.FNumber, DataType.UINT16, True, 800, 560,
                              ptp.FormFlag.ENUMERATION, values=[280, 560, 800])
    raw = enum.pack()
    # code, type, GetSet, factory, current, form, count, 3 values
    assert len(raw) == 2 + 2 + 1 + 2 + 2 + 1 + 2 + 3 * 2
    assert ptp.DevicePropDesc.unpack(raw) == enum
    assert enum.allows(560) and not enum.allows(500)
    rng = ptp.DevicePropDesc(PropCode.ExposureTime, DataType.UINT32, False, 333, 333,
                             ptp.FormFlag.RANGE, range=(5, 300000, 5))
    back = ptp.DevicePropDesc.unpack(rng.pack())
    assert back == rng and back.writable is False
    assert rng.allows(335) and not rng.allows(333) and not rng.allows(300005)
    with pytest.raises(ptp.PtpDecodeError):
        ptp.DevicePropDesc.unpack(raw[:-1])


# Canon codes as listed in libgphoto2's config.c tables
CANON_CODES = [("shutter", 1 / 30, 0x60), ("shutter", 1 / 125, 0x70), ("shutter", 2, 0x30),
               ("shutter", 1 / 13, 0x55), ("shutter", 0.3, 0x45), ("shutter", 1 / 25, 0x5D),
               ("shutter", 30, 0x10), ("shutter", 1 / 4000, 0x98),
               ("aperture", 5.6, 0x30), ("aperture", 8, 0x38), ("aperture", 7.1, 0x35),
               ("aperture", 1.8, 0x15), ("aperture", 22, 0x50),
               ("iso", 100, 0x48), ("iso", 125, 0x4B), ("iso", 640, 0x5D), ("iso", 6400, 0x78)]


@pytest.mark.parametrize("key, value, code", CANON_CODES)
def test_canon_stop_codes(key, value, code):
    assert exposure_values.eos_encode(key, value) == code
    assert exposure_values.eos_decode(key, code) == pytest.approx(value)


def test_eos_property_records_roundtrip():
    raw = ptp.pack_eos_events([ptp.pack_eos_avail_list(0xD102, [0x60, 0x68]),
                               ptp.pack_eos_prop_value(0xD102, 0x60)])
    values, allowed = ptp.eos_prop_records(ptp.unpack_eos_events(raw))
    assert values == {0xD102: 0x60} and allowed == {0xD102: [0x60, 0x68]}
    assert ptp.unpack_eos_set_prop(ptp.pack_eos_set_prop(0xD101, 0x38)) == (0xD101, 0x38)


def test_choose_value_tolerance():
    pairs = [(333, 1 / 30), (250, 1 / 40), (167, 1 / 60)]
    assert choose_value("shutter", 0.033, pairs)[0] == 333      # 0.014 stop off: 1/30
    device, nearest = choose_value("shutter", 1 / 35, pairs)    # 0.2 stop from both
    assert device is None and [d for d, _ in nearest] == [167, 250, 333]
    assert choose_value("iso", 120, [(100, 100.0), (125, 125.0)])[0] is None  # ISO is exact


# -- PtpCamera against the simulated camera -------------------------------------------------------

@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_set_and_read_back(behaviour):
    be = backend(behaviour)
    with camera(be) as cam:
        assert cam.path == behaviour
        report = cam.set_exposure({"shutter": "1/60", "iso": 200, "aperture": 5.6})
        image = cam.capture()  # capture still works after the data-out transactions
    props = be.camera.props
    shutter = props[SHUTTER_CODE[behaviour]].current
    if behaviour == "canon":
        assert (shutter, props[PropCode.EOS_ISOSpeed].current,
                props[PropCode.EOS_Aperture].current) == (0x68, 0x50, 0x30)
        assert Op.EOS_SetDevicePropValueEx in be.camera.log
        assert Op.SetDevicePropValue not in be.camera.log
    else:
        assert (shutter, props[PropCode.ExposureIndex].current,
                props[PropCode.FNumber].current) == (167, 200, 560)
        assert Op.SetDevicePropValue in be.camera.log and Op.GetDevicePropValue in be.camera.log
    assert report["shutter"]["device_value"] == shutter
    assert report["shutter"]["display"] == "1/60 s" and report["shutter"]["requested"] == "1/60"
    assert report["iso"]["value"] == 200 and report["aperture"]["display"] == "f/5.6"
    assert report["aperture"]["property"].startswith(f"0x{APERTURE_CODE[behaviour]:04X}")
    assert image.size == 64


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_decimal_and_whole_second_shutters(behaviour):
    be = backend(behaviour)
    with camera(be) as cam:
        assert cam.set_exposure({"shutter": 0.033})["shutter"]["display"] == "1/30 s"
        assert cam.set_exposure({"shutter": "2"})["shutter"]["value"] == 2.0
    assert be.camera.shutter_seconds() == pytest.approx(2.0)


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
@pytest.mark.parametrize("key, value, listed", [
    ("shutter", "1/7", ["1/8 s", "1/6 s"]), ("shutter", 60, ["30 s"]),
    ("iso", 120, ["ISO 100", "ISO 125"]), ("aperture", 1.4, ["f/2.8"])])
def test_value_not_allowed_names_key_value_and_nearest(behaviour, key, value, listed):
    be = backend(behaviour)
    with camera(be) as cam:
        before = {c: p.current for c, p in be.camera.props.items()}
        with pytest.raises(CameraExposureError) as err:
            cam.set_exposure({key: value})
    message = str(err.value)
    assert f"exposure.{key}: {value!r}" in message and "nearest allowed" in message
    assert all(v in message for v in listed), message
    assert {c: p.current for c, p in be.camera.props.items()} == before  # nothing was set


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_camera_refuses_a_listed_value(behaviour):
    """The camera answers InvalidDevicePropValue (0x201C) although it listed the value."""
    be = backend(behaviour)
    code = SHUTTER_CODE[behaviour]
    target = exposure_values.eos_encode("shutter", 1 / 125) if behaviour == "canon" else 80
    be.camera.props[code].refused = (target,)
    with camera(be) as cam, pytest.raises(CameraExposureError) as err:
        cam.set_exposure({"shutter": "1/125"})
    message = str(err.value)
    assert "exposure.shutter: '1/125'" in message and "InvalidDevicePropValue (0x201C)" in message
    assert "refused 1/125 s" in message and "1/100 s" in message and "1/160 s" in message
    assert be.camera.props[code].current == be.camera.props[code].factory


def test_canon_without_allowed_lists_uses_the_table_and_the_camera_refuses():
    be = backend("canon")
    be.camera._eos_pending = [rec for rec in be.camera._eos_pending
                              if rec[0] != EventCode.EOS_AvailListChanged]
    with camera(be) as cam:
        cam.set_exposure({"shutter": "1/60"})  # in the table and on the camera
        with pytest.raises(CameraExposureError, match=r"exposure.shutter: '1/8000'.*refused "
                                                      r"1/8000 s.*0x201C"):
            cam.set_exposure({"shutter": "1/8000"})  # in the table, not on this camera
    assert be.camera.props[PropCode.EOS_ShutterSpeed].current == 0x68


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_unsupported_property(behaviour):
    be = backend(behaviour)
    be.camera.remove_property(APERTURE_CODE[behaviour])
    with camera(be) as cam:
        with pytest.raises(CameraExposureError) as err:
            cam.set_exposure({"shutter": "1/60", "aperture": 8})
        assert cam.set_exposure({"iso": 400})["iso"]["value"] == 400  # still usable
    message = str(err.value)
    assert "exposure.aperture: 8" in message and "does not support setting aperture" in message
    assert f"0x{APERTURE_CODE[behaviour]:04X}" in message
    assert "DevicePropNotSupported (0x200A)" in message
    assert be.camera.props[SHUTTER_CODE[behaviour]].current != \
        be.camera.props[SHUTTER_CODE[behaviour]].factory  # the shutter before it was set


def test_range_descriptor(monkeypatch):
    """A camera describing ExposureTime as a range (min, max, step) instead of a list."""
    be = backend("nikon")
    prop = be.camera.props[PropCode.ExposureTime]
    prop.values = range(5, 300001, 5)
    monkeypatch.setattr(prop, "desc", lambda code: ptp.DevicePropDesc(
        code, prop.datatype, True, prop.factory, prop.current, ptp.FormFlag.RANGE,
        range=(5, 300000, 5)))
    with camera(be) as cam:
        assert cam.set_exposure({"shutter": "1/100"})["shutter"]["device_value"] == 100
        # 1/30 s = 333.3 units: not on the 5-unit grid; 335 is 0.01 stop away and taken
        assert cam.set_exposure({"shutter": "1/30"})["shutter"]["device_value"] == 335
        with pytest.raises(CameraExposureError, match=r"exposure.shutter: 60: 60 s is outside "
                                                      r"what the camera allows \(1/2000 s \.\. "
                                                      r"30 s, steps of 5\); nearest allowed: 30 s"):
            cam.set_exposure({"shutter": 60})


def test_read_only_property_and_unknown_key():
    be = backend("generic")
    be.camera.props[PropCode.FNumber].writable = False
    with camera(be) as cam:
        with pytest.raises(CameraExposureError, match=r"exposure.aperture: 8: aperture is "
                                                      r"read-only"):
            cam.set_exposure({"aperture": 8})
        with pytest.raises(CameraConfigError, match="unknown key.*focus"):
            cam.set_exposure({"focus": 1})
        with pytest.raises(CameraConfigError, match="exposure.shutter"):
            cam.set_exposure({"shutter": "fast"})


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_read_back_differing_from_the_value_set_is_an_error(behaviour, monkeypatch):
    """A camera that answers OK but keeps another value (e.g. snaps it) is caught."""
    be = backend(behaviour)
    sim = be.camera
    code = ISO_CODE[behaviour]
    op = "_op_EOS_SetDevicePropValueEx" if behaviour == "canon" else "_op_SetDevicePropValue"
    real = getattr(sim, op)

    def snapping(tid, *params, data=None):
        result = real(tid, *params, data=data)
        sim.props[code].current = sim.props[code].values[0]  # ISO 100, whatever was asked
        if behaviour == "canon":
            sim._eos_pending.append(ptp.pack_eos_prop_value(code, sim.props[code].current))
        return result

    monkeypatch.setattr(sim, op, snapping)
    with camera(be) as cam, pytest.raises(CameraExposureError,
                                          match=r"exposure.iso: 400: set to device value .*"
                                                r"ISO 400.*camera reports .*ISO 100"):
        cam.set_exposure({"iso": 400})


@pytest.mark.parametrize("behaviour", ["generic", "canon"])
def test_busy_set_is_retried_with_its_data_phase(behaviour):
    be = backend(behaviour)
    op = Op.EOS_SetDevicePropValueEx if behaviour == "canon" else Op.SetDevicePropValue
    with camera(be) as cam:
        be.inject("busy", 2, op=op)
        cam.set_exposure({"iso": 800})
    assert be.camera.props[ISO_CODE[behaviour]].current == (0x60 if behaviour == "canon" else 800)
    # both busy answers were consumed (each after its data phase), then the set ran once
    assert "busy" not in be.faults.armed and be.camera.log.count(op) == 1


# -- the simulated sensor and capture_session -----------------------------------------------------

RIGS = """
rigs:
  sim:
    lights: {driver: sim, count: 4, timeout: 0.4, write_timeout: 0.4,
             rings: [{elevation: 45, count: 4}]}
    camera: {driver: sim, path: generic}
    frames: {dark: 1, ambient: 0, sphere: false}
    scene: {shape: [48, 64]}
  sim-exp:
    lights: {driver: sim, count: 4, timeout: 0.4, write_timeout: 0.4,
             rings: [{elevation: 45, count: 4}]}
    camera: {driver: sim, path: canon}
    exposure: {shutter: 1/15, iso: 100, aperture: f/8}
    frames: {dark: 1, ambient: 0, sphere: false}
    scene: {shape: [48, 64]}
"""


@pytest.fixture
def rigs(tmp_path):
    path = tmp_path / "rigs.yaml"
    path.write_text(RIGS, encoding="utf-8")
    return path


def _mosaic(dng: bytes) -> np.ndarray:
    return tifffile.imread(io.BytesIO(dng)).astype(float)


@pytest.mark.parametrize("behaviour", ["generic", "canon"])
def test_sim_signal_scales_with_the_shutter(rigs, behaviour):
    rig = get_rig("sim", rigs)
    with SimulatedRig(rig, behaviour=behaviour) as sim:
        sim.before_frame("object_000", "object")
        sim.lights.on(0)
        scene = sim.scenes["object"]
        black = scene.sensor.black
        default = sim.camera.capture().data
        # no exposure set: bit-identical to the scene's own rendering (today's images)
        assert default == scene.render_dng(0, shot=sim.shot)
        sim.camera.set_exposure({"shutter": "1/15"})
        doubled = _mosaic(sim.camera.capture().data)
        sim.camera.set_exposure({"shutter": 30})
        long = _mosaic(sim.camera.capture().data)
    base = _mosaic(default)
    lit = (base - black > 200) & (doubled < scene.sensor.white)
    ratio = np.median((doubled[lit] - black) / (base[lit] - black))
    expected = 2.0 if behaviour == "canon" else 667 / 333
    assert ratio == pytest.approx(expected, rel=0.03)
    assert np.mean(long[lit] == scene.sensor.white) > 0.99  # 900 x the light: clipped at white
    assert sim.backend.camera.exposure_gain() == pytest.approx(30 / REFERENCE_SHUTTER, rel=2e-3)  # 333 = 1/30 s


def test_capture_sets_exposure_first_and_records_the_camera_values(tmp_path, rigs):
    rig = get_rig("sim-exp", rigs)
    lines = []
    session = capture_session(tmp_path / "s", rig, progress=False, echo=lines.append)
    manifest = Session.open(session.root).manifest
    assert manifest["rig"]["exposure"] == {"shutter": "1/15", "iso": 100, "aperture": "f/8"}
    recorded = manifest["camera"]["exposure"]
    assert recorded["shutter"] == {"requested": "1/15", "value": pytest.approx(1 / 15),
                                   "property": "0xD102 EOS_ShutterSpeed", "device_value": 0x58}
    assert recorded["aperture"]["device_value"] == 0x38 and recorded["iso"]["device_value"] == 0x48
    frames = session.frames()
    assert frames and all(f["exposure"] == {"shutter": "1/15", "iso": 100, "aperture": 8.0}
                          for f in frames)
    assert any("exposure set on the camera: 1/15 s, ISO 100, f/8" in line for line in lines), lines


def test_capture_sets_exposure_once_before_the_dark_frame(tmp_path, rigs):
    rig = get_rig("sim-exp", rigs)
    sim = SimulatedRig(rig)
    capture_session(tmp_path / "s", rig, sim=sim, progress=False, echo=lambda line: None)
    log = sim.backend.camera.log
    sets = [i for i, op in enumerate(log) if op == Op.EOS_SetDevicePropValueEx]
    releases = [i for i, op in enumerate(log) if op == Op.EOS_RemoteReleaseOn]
    assert len(sets) == 3 and len(releases) == 5  # dark + 4 lights
    assert max(sets) < min(releases)


def test_capture_refused_exposure_stops_before_any_frame(tmp_path, rigs):
    rig = get_rig("sim-exp", rigs)
    rig.exposure = {"shutter": "1/7"}
    with pytest.raises(CaptureError, match=r"rig 'sim-exp'.*exposure.shutter: '1/7'.*nearest "
                                           r"allowed: 1/8 s"):
        capture_session(tmp_path / "s", rig, progress=False, echo=lambda line: None)
    assert not (tmp_path / "s").exists()


# -- rig file validation --------------------------------------------------------------------------

@pytest.mark.parametrize("exposure, message", [
    ("{shutter: fast}", r"exposure.shutter: .*'fast' is not a number"),
    ("{iso: 100.5}", r"exposure.iso: .*whole number"),
    ("{focus: 1}", r"exposure.focus: unknown key \(known: shutter, iso, aperture, bracket\)"),
    ("{aperture: 0}", r"exposure.aperture: .*positive"),
])
def test_rig_file_exposure_validation(exposure, message):
    text = ("rigs:\n  r:\n    lights: {driver: sim, count: 4, rings: [{elevation: 45, count: 4}]}\n"
            f"    camera: {{driver: sim}}\n    exposure: {exposure}\n")
    with pytest.raises(ConfigError, match=r"rig 'r': " + message):
        parse_rigs(text, "x.yaml")


def test_rig_file_exposure_values_stay_as_written():
    text = ("rigs:\n  r:\n    lights: {driver: sim, count: 4, rings: [{elevation: 45, count: 4}]}\n"
            "    camera: {driver: sim}\n    exposure: {shutter: 1/30, iso: 100, aperture: 5.6}\n")
    assert parse_rigs(text, "x.yaml")["r"].exposure == {"shutter": "1/30", "iso": 100,
                                                        "aperture": 5.6}
