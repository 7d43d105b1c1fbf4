"""PtpCamera end to end against the simulated USB PTP camera (real pyusb code path)."""

import errno
import hashlib
import time

import pytest
import usb.core

from rig.camera import (CameraBusy, CameraConfigError, CameraDisconnected, CameraError,
                        CameraInterfaceClaimed, CameraNotFound, CameraProtocolError,
                        CameraTimeout, PtpCamera, make_camera)
from rig.ptp import OperationCode as Op
from rig.sim.usb_camera import BULK_MPS, make_backend

CHUNK = 64 * 1024
BEHAVIOURS = ("generic", "canon", "nikon")


class Frames:
    """A render callable: every exposure yields new, distinct, reproducible bytes."""

    def __init__(self, size):
        self.size, self.made = size, []

    def __call__(self):
        n = len(self.made)
        block = hashlib.sha256(f"frame {n}".encode()).digest()
        data = (block * (self.size // 32 + 1))[:self.size]
        self.made.append(data)
        return data


def camera(backend, **kw):
    kw.setdefault("chunk_size", CHUNK)
    kw.setdefault("busy_backoff", 0.001)
    kw.setdefault("timeout", 1.0)
    return PtpCamera(backend=backend, **kw)


SIZES = {
    "several_chunks": 5 * CHUNK + 123,
    "packet_multiple": 300 * BULK_MPS - 12,     # container ends on a packet boundary: ZLP
    "chunk_multiple": 3 * CHUNK - 12,           # the last read fills the buffer: ZLP pending
    "tiny": 100,
    "empty": 0,
}


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
@pytest.mark.parametrize("size", SIZES.values(), ids=SIZES.keys())
def test_capture_returns_exact_bytes(behaviour, size):
    render = Frames(size)
    be = make_backend(render, behaviour=behaviour)
    with camera(be) as cam:
        img = cam.capture()
        assert cam.path == behaviour
    assert img.data == render.made[0] and img.size == size == len(img.data)
    assert img.filename.endswith("0001.DNG") and img.format_code == 0x3811
    assert be.captures == 1 and be.objects == {}          # downloaded, then deleted
    assert not be.claimed


def test_zero_length_packet_is_consumed(monkeypatch):
    be = make_backend(Frames(SIZES["chunk_multiple"]))
    real, zero_reads = be.bulk_read, []

    def counting(*args):
        n = real(*args)
        zero_reads.append(n == 0)
        return n

    monkeypatch.setattr(be, "bulk_read", counting)
    with camera(be) as cam:
        first, second = cam.capture(), cam.capture()
    assert any(zero_reads)            # the ZLP really was on the wire
    assert first.data != second.data and be.captures == 2


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_capture_sequence_no_duplicates(behaviour):
    render = Frames(2 * CHUNK + 7)
    be = make_backend(render, behaviour=behaviour)
    with camera(be) as cam:
        imgs = [cam.capture() for _ in range(4)]
    assert [i.data for i in imgs] == render.made
    assert len({i.filename for i in imgs}) == 4 and len({i.object_handle for i in imgs}) == 4


def test_vendor_sequences_are_used():
    canon = make_backend(Frames(1000), behaviour="canon")
    with camera(canon) as cam:
        cam.capture()
    log = canon.camera.log
    assert log.index(Op.EOS_SetRemoteMode) < log.index(Op.EOS_SetEventMode) < log.index(
        Op.EOS_RemoteReleaseOn) < log.index(Op.EOS_RemoteReleaseOff) < log.index(Op.GetObject)
    assert Op.EOS_TransferComplete in log and Op.InitiateCapture not in log
    nikon = make_backend(Frames(1000), behaviour="nikon")
    with camera(nikon) as cam:
        cam.capture()
    log = nikon.camera.log
    assert log.count(Op.NIKON_DeviceReady) == 3      # busy, busy, ready
    assert log.index(Op.NIKON_InitiateCaptureRecInSdram) < log.index(Op.GetObject)
    assert Op.InitiateCapture not in log


def test_auto_path_needs_vendor_operations():
    # a Canon USB id on a camera without the EOS operations stays on the generic path
    be = make_backend(Frames(10), behaviour="generic", vendor_id=0x04A9)
    with camera(be) as cam:
        assert cam.path == "generic" and cam.capture().size == 10
        info = cam.device_info
    assert info["manufacturer"] == "psrig" and Op.InitiateCapture in info["operations"]
    assert info["serial"] == "SIM0001"


def test_keep_on_camera():
    be = make_backend(Frames(500))
    with camera(be, delete_after_download=False) as cam:
        img = cam.capture()
    assert be.objects[img.object_handle].data == img.data


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_busy_retried_with_backoff(behaviour):
    render = Frames(CHUNK + 1)
    be = make_backend(render, behaviour=behaviour)
    with camera(be, busy_backoff=0.01) as cam:
        be.inject("busy", count=3)
        t0 = time.monotonic()
        img = cam.capture()
        elapsed = time.monotonic() - t0
    assert img.data == render.made[0] and be.captures == 1
    assert elapsed >= 0.01 + 0.02 + 0.04 - 1e-3      # doubling back-off, not a fixed pause


def test_busy_on_get_object_then_success():
    render = Frames(3 * CHUNK)
    be = make_backend(render)
    with camera(be) as cam:
        be.inject("busy", count=2, op=Op.GetObject)
        img = cam.capture()
    assert img.data == render.made[0] and be.camera.log.count(Op.GetObject) == 1


def test_busy_forever_is_camera_busy():
    be = make_backend(Frames(100))
    with camera(be, busy_retries=4) as cam:
        be.inject("busy", count=None)
        with pytest.raises(CameraBusy, match="0x2019"):
            cam.capture()
    assert be.captures == 0


@pytest.mark.parametrize("op", [None, Op.GetObject])
def test_timeout_then_resume(op):
    render = Frames(4 * CHUNK + 3)
    be = make_backend(render)
    with camera(be) as cam:
        be.inject("timeout", op=op)
        with pytest.raises(CameraTimeout, match="timed out"):
            cam.capture()
        lost = dict(be.objects)
        img = cam.capture()                       # resets the channel, reopens the session
    assert be.resets == 1
    assert img.data == render.made[-1] and img.size == len(render.made[-1])
    assert be.objects == lost                     # a frame taken before the timeout stays put


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_missing_object_event_times_out(behaviour):
    be = make_backend(Frames(100), behaviour=behaviour)
    with camera(be, timeout=0.2) as cam:
        be.inject("no_event")
        with pytest.raises(CameraTimeout, match="stays on the camera"):
            cam.capture()
        assert len(be.objects) == 1
        assert cam.capture().data == be.camera.render.made[-1]


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_disconnect_mid_transfer(behaviour):
    render = Frames(6 * CHUNK)
    be = make_backend(render, behaviour=behaviour)
    with camera(be) as cam:
        be.inject("disconnect")
        with pytest.raises(CameraDisconnected, match="disconnected during GetObject"):
            cam.capture()
        assert [o.data for o in be.objects.values()] == render.made   # still on the card
        with pytest.raises(CameraNotFound):
            cam.capture()
        be.reconnect()
        img = cam.capture()
    assert img.data == render.made[-1] and len(render.made) == 2


def test_truncated_object_is_retried():
    render = Frames(5 * CHUNK + 11)
    be = make_backend(render)
    with camera(be) as cam:
        be.inject("truncated", count=1)
        img = cam.capture()
    assert img.data == render.made[0] and be.camera.log.count(Op.GetObject) == 2


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_truncated_forever_is_an_error_never_a_short_frame(behaviour):
    render = Frames(5 * CHUNK + 11)
    be = make_backend(render, behaviour=behaviour)
    with camera(be) as cam:
        be.inject("truncated", count=None)
        with pytest.raises(CameraProtocolError, match="truncated"):
            cam.capture()
    [kept] = be.objects.values()
    assert kept.data == render.made[0]              # not deleted: nothing lost


def test_session_already_open_is_accepted():
    render = Frames(1234)
    be = make_backend(render)
    be.inject("session_open")
    with camera(be) as cam:
        img = cam.capture()
    assert img.data == render.made[0]
    assert be.camera.log[0] == Op.OpenSession


def test_interface_claimed_by_another_program():
    be = make_backend(Frames(10))
    be.inject("claimed")
    with pytest.raises(CameraInterfaceClaimed, match="another program.*gvfs"):
        camera(be).open()
    with camera(be) as cam:                   # once the other program lets go
        assert cam.capture().size == 10


def test_kernel_driver_detached_and_reattached():
    be = make_backend(Frames(10))
    be.inject("kernel_driver")
    with camera(be) as cam:
        cam.capture()
        assert be.kernel_driver_detached == 1 and be.kernel_driver_attached == 0
    assert be.kernel_driver_attached == 1


def test_not_found_names_the_id():
    be = make_backend(Frames(10), behaviour="canon")
    with pytest.raises(CameraNotFound, match="04b0"):
        camera(be, vendor_id=0x04B0).open()


def test_chunk_size_rounded_to_packets():
    render = Frames(3000)
    be = make_backend(render)
    with camera(be, chunk_size=1000) as cam:  # 1000 would overflow a 512-byte endpoint
        assert cam.capture().data == render.made[0]


def test_usb_error_codes_map_to_errors():
    from rig.camera import _is_disconnect
    assert _is_disconnect(usb.core.USBError("x", -4, errno.ENODEV))
    assert not _is_disconnect(usb.core.USBError("x", -6, errno.EBUSY))


def test_make_camera_from_rig_config():
    render = Frames(777)
    be = make_backend(render, behaviour="nikon")
    cam = make_camera({"driver": "ptp", "vendor_id": "0x04b0", "product_id": 0x0428,
                       "path": "auto", "timeout": 2}, backend=be)
    with cam:
        assert cam.capture().data == render.made[0] and cam.path == "nikon"
    with pytest.raises(CameraConfigError, match="exposure"):
        make_camera({"driver": "ptp", "exposure": 1})
    with pytest.raises(CameraConfigError, match="gphoto"):
        make_camera({"driver": "gphoto"})
    with pytest.raises(CameraConfigError, match="vendor_id"):
        make_camera({"vendor_id": "canon"})
    with pytest.raises(CameraConfigError, match="timeout"):
        make_camera({"timeout": "soon"})
    with pytest.raises(CameraConfigError, match="path"):
        make_camera({"path": "sony"})
    assert issubclass(CameraConfigError, CameraError)


def test_make_camera_rejects_string_boolean():
    with pytest.raises(CameraConfigError, match="delete_after_download"):
        make_camera({"delete_after_download": "no"})
    cam = make_camera({"delete_after_download": False, "busy_retries": 2})
    assert cam.delete_after_download is False and cam.busy_retries == 2


@pytest.mark.parametrize("size", [SIZES["packet_multiple"], SIZES["chunk_multiple"],
                                  SIZES["several_chunks"]])
def test_firmware_without_zero_length_packets(size, monkeypatch):
    render = Frames(size)
    be = make_backend(render)
    be.send_zlp = False
    real, reads = be.bulk_read, []
    monkeypatch.setattr(be, "bulk_read", lambda *a: reads.append(real(*a)) or reads[-1])
    with camera(be) as cam:
        imgs = [cam.capture(), cam.capture()]
    assert [i.data for i in imgs] == render.made
    assert 0 not in reads


def test_busy_while_opening_is_retried():
    be = make_backend(Frames(10), behaviour="canon")
    be.inject("busy", count=3)
    with camera(be) as cam:
        assert cam.capture().size == 10
    assert be.camera.log[:2] == [Op.OpenSession, Op.GetDeviceInfo]


def test_new_folder_object_is_skipped():
    render = Frames(2000)
    be = make_backend(render)
    with camera(be) as cam:
        be.inject("new_folder")
        img = cam.capture()
    assert img.data == render.made[0] and img.filename == "IMG_0001.DNG"
    [folder] = be.objects.values()            # the folder stays; only the image is deleted
    assert folder.object_format == 0x3001


def test_out_of_step_channel_is_reset_then_capture_resumes():
    render = Frames(3 * CHUNK)
    be = make_backend(render)
    with camera(be) as cam:
        be.inject("stale_response", op=Op.GetObjectInfo)
        with pytest.raises(CameraProtocolError, match="transaction"):
            cam.capture()
        img = cam.capture()
    assert be.resets == 1 and img.data == render.made[-1]
    assert len(be.objects) == 1                # the first frame was never lost: still there


def test_error_response_names_operation():
    be = make_backend(Frames(10), behaviour="generic")
    with pytest.raises(CameraProtocolError, match="EOS_SetRemoteMode.*OperationNotSupported"):
        camera(be, path="canon").open()         # a generic camera has no EOS operations
    assert not be.claimed                       # the failed open released the interface


def test_sim_rejects_unknown_fault_and_behaviour():
    be = make_backend(Frames(10))
    with pytest.raises(ValueError, match="unknown fault"):
        be.inject("gremlins")
    with pytest.raises(ValueError, match="behaviour"):
        make_backend(Frames(10), behaviour="sony")
    assert camera(be).device_info == {}          # nothing known before open
