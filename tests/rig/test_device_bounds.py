"""Device-controlled sizes and names (issue 19, items 6, 7 and 9's rig part).

Each misbehaviour is a fault of the simulated devices, met by the real drivers: a PTP length
lie, a data phase that trickles in, a light controller flooding bytes without a newline or
answering with a 4,300-digit number; odd camera file names; an orphan symlink in raw/.
"""

import os
import resource
import time

import pytest
import serial
import yaml

from pipeline.cli import main
from rig.camera import CameraProtocolError, CameraTimeout, PtpCamera
from rig.capture import capture_session
from rig.config import get_rig
from rig.lights import LightProtocolError, SerialLightController
from rig.rawtype import RawTypeError, raw_extension
from rig.sim.firmware import SimulatedLightFirmware
from rig.sim.rig import SimulatedRig
from rig.sim.usb_camera import make_backend

QUIET = {"progress": False, "echo": lambda line: None}
RIGS = """
rigs:
  small:
    lights: {driver: sim, count: 3, timeout: 0.4, rings: [{elevation: 50, count: 3}]}
    camera: {driver: sim, path: generic, timeout: 0.5}
    frames: {dark: 1, ambient: 0, sphere: false}
    scene: {shape: [48, 64]}
"""


@pytest.fixture
def small_rig(tmp_path):
    path = tmp_path / "rigs.yaml"
    path.write_text(RIGS, encoding="utf-8")
    return get_rig("small", path), path


def _peak_rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


# -- PTP lengths and deadlines -------------------------------------------------------------------

@pytest.mark.parametrize("fault, claim", [("length_lie", "1073741824"), ("length_max", "4294967268")])
def test_a_ptp_length_lie_is_refused_without_allocating(fault, claim):
    backend = make_backend(lambda: b"II*\x00" + bytes(28))
    camera = PtpCamera(backend=backend, timeout=0.5)
    backend.inject(fault, 1, op=0x1001)  # GetDeviceInfo's 32-byte-ish reply claims more
    before = _peak_rss_mb()
    with pytest.raises(CameraProtocolError, match=rf"announces a data phase of {claim} bytes, "
                                                  r"but GetDeviceInfo returns at most 16777216"):
        camera.open()
    assert _peak_rss_mb() - before < 100  # no GiB allocated


def test_a_lie_on_getobject_is_bounded_by_the_object_size():
    backend = make_backend(lambda: b"II*\x00" + bytes(2000))
    with PtpCamera(backend=backend, timeout=0.5) as camera:
        backend.inject("length_lie", 1, op=0x1009)
        with pytest.raises(CameraProtocolError, match="GetObject returns at most 2004"):
            camera.capture()
        assert len(backend.objects) == 1  # not deleted: the frame stays on the camera
        assert camera.capture().size == 2004  # the channel recovers


def test_every_exchange_has_a_total_deadline():
    """Packets each well inside the per-transfer timeout, but far too slow in all."""
    payload = os.urandom(512 * 40)
    backend = make_backend(lambda: payload)
    with PtpCamera(backend=backend, timeout=0.5, chunk_size=512) as camera:
        backend.inject("trickle", 1, op=0x1009)  # 40 reads x 0.05 s = 2 s for 20 kB
        start = time.monotonic()
        with pytest.raises(CameraTimeout, match=r"GetObject: only \d+ of 20480 bytes arrived "
                                                r"within 0.52 s"):
            camera.capture()
        assert time.monotonic() - start < 1.5


# -- light-controller replies ---------------------------------------------------------------------

@pytest.fixture
def firmware():
    with SimulatedLightFirmware(4, watchdog=5.0) as fw:
        yield fw


def _controller(firmware, retries=1):
    return SerialLightController(firmware.port, timeout=0.3, write_timeout=0.3, reset_delay=0.0,
                                 retries=retries)


def test_a_newline_less_flood_does_not_hang_readline(firmware):
    with _controller(firmware, retries=0) as lights:
        firmware.inject("flood")
        start = time.monotonic()
        with pytest.raises(LightProtocolError, match=r"command 'ON 1': a reply of more than 128 "
                                                     r"bytes without a line end"):
            lights.on(1)
        assert time.monotonic() - start < 2.0
    with _controller(firmware) as lights:  # one flooded reply, then the retry gets through
        firmware.inject("flood")
        lights.on(2)
        assert firmware.lit == 2


def test_a_4300_digit_number_is_a_clear_protocol_error(firmware, monkeypatch):
    send = firmware._send_bytes

    def tail_late(data, wait=True):   # the reply's tail still on its way when the driver gives up
        if len(data) > 1000:
            send(data[:200])
            time.sleep(0.1)
            data = data[200:]
        send(data, wait)

    monkeypatch.setattr(firmware, "_send_bytes", tail_late)
    with _controller(firmware, retries=0) as lights:
        firmware.inject("huge_number")
        with pytest.raises(LightProtocolError, match=r"STATE\?.*more than 128 bytes"):
            lights.state()
        # the reply's tail is dropped with it: the next command gets its own answer
        lights.on(3)
        assert lights.state() == 3 == firmware.lit
        # a shorter absurd number fits the line but not the protocol's 4 digits
        with serial.Serial() as _:
            pass
    with SimulatedLightFirmware(4, ident="PSRIG-LIGHTS 1 " + "9" * 100) as odd:
        with pytest.raises(LightProtocolError, match=r"unexpected reply 'PSRIG-LIGHTS 1 9999"):
            SerialLightController(odd.port, timeout=0.3, reset_delay=0.0, retries=0).open()


def test_a_flood_during_capture_ends_in_a_resumable_error(small_rig, tmp_path, monkeypatch, capsys):
    _, path = small_rig
    monkeypatch.setenv("PSRIG_SIM_FAULTS", "flood:2@object_001")
    code = main(["capture", str(tmp_path / "s"), "--rig", "small", "--config", str(path)])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert "frame object_001 (light 1)" in err and "more than 128 bytes" in err and "--resume" in err
    monkeypatch.delenv("PSRIG_SIM_FAULTS")
    assert main(["capture", str(tmp_path / "s"), "--rig", "small", "--config", str(path),
                 "--resume"]) == 0


# -- camera file names ----------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["IMG\x00_0001.DNG", "../../outside.DNG", "sub/dir\\x.DNG",
                                  "IMG_0001.EXR", ""])
def test_the_camera_file_name_never_reaches_the_filesystem(small_rig, tmp_path, name):
    rig_config, _ = small_rig
    with SimulatedRig(rig_config) as sim:
        sim.backend.camera.next_names = [name] * 4
        session = capture_session(tmp_path / "s", rig_config, sim=sim, **QUIET)
    files = sorted(p.name for p in (tmp_path / "s" / "raw").iterdir())
    assert files == ["dark_000.dng", "object_000.dng", "object_001.dng", "object_002.dng"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rigs.yaml", "s"]  # nothing outside
    manifest = yaml.safe_load((tmp_path / "s" / "session.yaml").read_text())
    recorded = manifest["frames"][1]["camera_file"]
    assert recorded == name.replace("\x00", "\\x00") and "\x00" not in recorded
    assert session.frames()[1]["file"] == "raw/object_000.dng"


def test_raw_types_from_content():
    from pipeline.core.dng import write_dng
    import numpy as np

    dng = write_dng(np.zeros((32, 32), np.uint16))
    assert raw_extension(dng) == "dng"
    assert raw_extension(b"II*\x00\x10\x00\x00\x00CR\x02\x00" + bytes(20)) == "cr2"
    assert raw_extension(b"\x00\x00\x00\x18ftypcrx " + bytes(20)) == "cr3"
    assert raw_extension(b"FUJIFILMCCD-RAW 0201") == "raf"
    assert raw_extension(b"\xff\xd8\xff\xe0" + bytes(8)) == "jpg"
    assert raw_extension(b"II*\x00\x08\x00\x00\x00\x00\x00", fallback="nef") == "nef"
    with pytest.raises(RawTypeError, match=r"starts with b'v=1 EXR"):
        raw_extension(b"v=1 EXR junk")


def test_unknown_content_is_refused_naming_the_frame(small_rig, tmp_path):
    rig_config, _ = small_rig
    with SimulatedRig(rig_config) as sim:
        sim.backend.camera.render = lambda: b"\x76\x2f\x31\x01" + bytes(100)  # an OpenEXR file
        with pytest.raises(Exception, match=r"frame dark_000: the camera delivered a file "
                                            r"\(IMG_0001.DNG\) that is not a raw or image format"):
            capture_session(tmp_path / "s", rig_config, sim=sim, **QUIET)


# -- an orphan symlink in raw/ on --resume ----------------------------------------------------------

@pytest.mark.parametrize("target", ["outside", "inside"])
def test_an_orphan_symlink_in_raw_is_named_on_resume(small_rig, tmp_path, capsys, target):
    _, path = small_rig
    session = tmp_path / "s"
    assert main(["capture", str(session), "--rig", "small", "--config", str(path)]) == 0
    (session / "raw" / "object_001.dng").unlink()
    manifest = yaml.safe_load((session / "session.yaml").read_text())
    manifest["frames"] = [f for f in manifest["frames"] if f["id"] != "object_001"]
    manifest["frame_count"] = len(manifest["frames"])   # as a kill before the save leaves it
    (session / "session.yaml").write_text(yaml.safe_dump(manifest))
    # pointing nowhere outside the session, or nowhere inside it (a write would replace it)
    os.symlink(tmp_path / "gone.dng" if target == "outside" else "gone.dng",
               session / "raw" / "object_001.dng")
    capsys.readouterr()
    assert main(["capture", str(session), "--rig", "small", "--config", str(path), "--resume"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "raw/object_001.dng is a symbolic link to" in err and "gone.dng" in err
    assert "does not exist (an orphan link)" in err
    assert (session / "raw" / "object_001.dng").is_symlink()  # left for the user to look at
