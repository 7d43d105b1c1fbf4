"""PTP container codec and datasets (rig.ptp)."""

import struct

import pytest

from rig import ptp
from rig.ptp import ContainerType, EventCode, OperationCode as Op, ResponseCode as RC


def test_command_roundtrip_is_little_endian():
    raw = ptp.pack_command(Op.GetObject, 7, (0x01020304,))
    assert raw[:4] == (16).to_bytes(4, "little")
    assert raw[4:6] == b"\x01\x00" and raw[6:8] == b"\x09\x10"
    c = ptp.unpack_container(raw)
    assert (c.type, c.code, c.transaction_id, c.params) == (
        ContainerType.COMMAND, Op.GetObject, 7, (0x01020304,))


def test_response_and_event_params():
    c = ptp.unpack_container(ptp.pack_response(RC.SessionAlreadyOpened, 0, (9, 8)))
    assert c.type == ContainerType.RESPONSE and c.params == (9, 8)
    ev = ptp.unpack_container(ptp.pack_event(EventCode.ObjectAdded, 3, (1, 2, 3, 4, 5)))
    assert ev.type == ContainerType.EVENT and ev.params == (1, 2, 3)  # events carry <= 3
    with pytest.raises(ValueError):
        ptp.pack_command(Op.OpenSession, 1, tuple(range(6)))


def test_data_container_header_and_payload():
    payload = bytes(range(200))
    raw = ptp.pack_data_header(Op.GetObject, 5, len(payload)) + payload
    c = ptp.unpack_container(raw)
    assert c.type == ContainerType.DATA and c.payload == payload
    assert ptp.unpack_header(raw) == (212, ContainerType.DATA, Op.GetObject, 5)


@pytest.mark.parametrize("raw", [
    b"\x0c\x00\x00",                                   # shorter than a header
    struct.pack("<IHHI", 8, 3, 0x2001, 1),             # length below header size
    struct.pack("<IHHI", 12, 9, 0x2001, 1),            # unknown container type
])
def test_malformed_headers_raise(raw):
    with pytest.raises(ptp.PtpDecodeError):
        ptp.unpack_header(raw)


def test_length_mismatch_and_odd_params_raise():
    raw = ptp.pack_response(RC.OK, 1, (5,))
    with pytest.raises(ptp.PtpDecodeError, match="says 16 bytes"):
        ptp.unpack_container(raw[:-1])
    odd = struct.pack("<IHHI", 14, 3, RC.OK, 1) + b"\x00\x00"
    with pytest.raises(ptp.PtpDecodeError):
        ptp.unpack_container(odd)


@pytest.mark.parametrize("text", ["", "A", "IMG_0001.DNG", "Kamera Ä\u00df \u6f22"])
def test_string_roundtrip(text):
    raw = ptp.pack_string(text)
    r = ptp.Reader(raw)
    assert r.string() == text and r.pos == len(raw)


def test_string_too_long_and_array():
    with pytest.raises(ValueError):
        ptp.pack_string("x" * 255)
    r = ptp.Reader(ptp.pack_array([1, 0xFFFF, 3]) + ptp.pack_array([7, 2 ** 32 - 1], "I"))
    assert r.array16() == [1, 0xFFFF, 3] and r.array32() == [7, 2 ** 32 - 1]


def test_device_info_roundtrip():
    info = ptp.DeviceInfo(vendor_extension_id=ptp.VendorExtension.CANON,
                          vendor_extension_desc="x", operations=[0x1001, 0x9116],
                          events=[0x4002], capture_formats=[0x3811], image_formats=[0x3801],
                          manufacturer="Canon Inc.", model="EOS 5D", device_version="3-1.2",
                          serial_number="0123")
    assert ptp.DeviceInfo.unpack(info.pack()) == info


def test_object_info_roundtrip_and_truncation_names_dataset():
    info = ptp.ObjectInfo(object_format=ptp.ObjectFormat.DNG, compressed_size=20_000_123,
                          image_width=6000, image_height=4000, filename="IMG_0042.DNG",
                          capture_date="20240101T101010")
    raw = info.pack()
    assert ptp.ObjectInfo.unpack(raw) == info
    with pytest.raises(ptp.PtpDecodeError, match="ObjectInfo"):
        ptp.ObjectInfo.unpack(raw[:30])


def test_eos_events_roundtrip_with_libgphoto2_offsets():
    added = ptp.EosObjectAdded(0x9001, 0x10001, ptp.ObjectFormat.CANON_CRW3, 123456,
                               0x90000000, "IMG_0001.CR2")
    raw = ptp.pack_eos_events([(EventCode.EOS_PropValueChanged, b"\x01\x02\x03\x04"), added])
    # libgphoto2 PTP_ece_OA_*: handle @8, storage @0x0c, ofc @0x10, size @0x1c, name @0x28
    rec = raw[12:]
    assert struct.unpack_from("<I", rec, 8)[0] == 0x9001
    assert struct.unpack_from("<H", rec, 0x10)[0] == ptp.ObjectFormat.CANON_CRW3
    assert struct.unpack_from("<I", rec, 0x1C)[0] == 123456
    assert rec[0x28:0x28 + 12] == b"IMG_0001.CR2"
    out = ptp.unpack_eos_events(raw)
    assert out == [(EventCode.EOS_PropValueChanged, b"\x01\x02\x03\x04"), added]
    assert ptp.unpack_eos_events(ptp.pack_eos_events([])) == []


def test_eos_events_overrun_raises():
    with pytest.raises(ptp.PtpDecodeError):
        ptp.unpack_eos_events(struct.pack("<II", 64, EventCode.EOS_ObjectAddedEx) + b"\0" * 8)


def test_nikon_events_roundtrip():
    events = [(EventCode.NIKON_ObjectAddedInSDRAM, 0xFFFF0001),
              (EventCode.NIKON_CaptureCompleteRecInSdram, 0)]
    raw = ptp.pack_nikon_events(events)
    assert len(raw) == 2 + 6 * 2
    assert ptp.unpack_nikon_events(raw) == events
    with pytest.raises(ptp.PtpDecodeError):
        ptp.unpack_nikon_events(raw[:-1])


def test_codes_match_libgphoto2():
    """Values as in libgphoto2 camlibs/ptp2/ptp.h."""
    assert (Op.EOS_SetRemoteMode, Op.EOS_SetEventMode, Op.EOS_GetEvent) == (0x9114, 0x9115,
                                                                             0x9116)
    assert (Op.EOS_RemoteReleaseOn, Op.EOS_RemoteReleaseOff) == (0x9128, 0x9129)
    assert (Op.NIKON_InitiateCaptureRecInSdram, Op.NIKON_GetEvent,
            Op.NIKON_DeviceReady) == (0x90C0, 0x90C7, 0x90C8)
    assert (RC.DeviceBusy, RC.SessionAlreadyOpened) == (0x2019, 0x201E)
    assert (EventCode.ObjectAdded, EventCode.CaptureComplete) == (0x4002, 0x400D)
    assert EventCode.EOS_ObjectAddedEx == 0xC181
    assert ptp.ObjectFormat.DNG == 0x3811


@pytest.mark.parametrize("name, code", [("IMG_0001.DNG", 0x3811), ("a.jpg", 0x3801),
                                        ("x.CR2", 0xB103), ("noext", 0x3000), ("y.NEF", 0x3000)])
def test_format_for_filename(name, code):
    assert ptp.format_for_filename(name) == code
