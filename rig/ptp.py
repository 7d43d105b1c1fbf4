"""PTP (ISO 15740) over USB: container codec, datasets and operation/response/event codes.

Everything here is pure byte packing, shared by the host driver (:mod:`rig.camera`) and the
simulated camera (:mod:`rig.sim.usb_camera`). All integers are little-endian, as PTP over USB
requires. Codes follow libgphoto2's ``camlibs/ptp2/ptp.h``.

USB bulk container layout: ``length u32 | type u16 | code u16 | transaction_id u32 | payload``;
command/response/event payloads are up to five ``u32`` parameters, a data payload is a dataset.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum

from pipeline.core.errors import PsrigError

__all__ = [
    "HEADER",
    "ContainerType",
    "OperationCode",
    "ResponseCode",
    "EventCode",
    "ObjectFormat",
    "VendorExtension",
    "PtpDecodeError",
    "Container",
    "pack_container",
    "pack_command",
    "pack_response",
    "pack_event",
    "pack_data_header",
    "unpack_header",
    "unpack_container",
    "Reader",
    "pack_string",
    "pack_array",
    "DeviceInfo",
    "ObjectInfo",
    "EosObjectAdded",
    "pack_eos_events",
    "unpack_eos_events",
    "pack_nikon_events",
    "unpack_nikon_events",
    "format_for_filename",
    "DataType",
    "PropCode",
    "FormFlag",
    "DevicePropDesc",
    "pack_value",
    "unpack_value",
    "pack_eos_prop_value",
    "pack_eos_avail_list",
    "pack_eos_set_prop",
    "unpack_eos_set_prop",
    "eos_prop_records",
]

HEADER = struct.Struct("<IHHI")
"""Container header: length (bytes, header included), type, code, transaction id."""


class ContainerType(IntEnum):
    """USB container types (PTP_USB_CONTAINER_*)."""

    COMMAND = 0x0001
    DATA = 0x0002
    RESPONSE = 0x0003
    EVENT = 0x0004


class OperationCode(IntEnum):
    """Operation codes: PTP 1.0 plus the Canon EOS and Nikon ones the capture paths use."""

    GetDeviceInfo = 0x1001
    OpenSession = 0x1002
    CloseSession = 0x1003
    GetStorageIDs = 0x1004
    GetStorageInfo = 0x1005
    GetNumObjects = 0x1006
    GetObjectHandles = 0x1007
    GetObjectInfo = 0x1008
    GetObject = 0x1009
    GetThumb = 0x100A
    DeleteObject = 0x100B
    InitiateCapture = 0x100E
    GetDevicePropDesc = 0x1014
    GetDevicePropValue = 0x1015
    SetDevicePropValue = 0x1016
    GetPartialObject = 0x101B
    # Canon EOS
    EOS_GetStorageIDs = 0x9101
    EOS_GetObjectInfo = 0x9103
    EOS_GetObject = 0x9104
    EOS_DeleteObject = 0x9105
    EOS_RemoteRelease = 0x910F
    EOS_SetDevicePropValueEx = 0x9110
    EOS_GetRemoteMode = 0x9113
    EOS_SetRemoteMode = 0x9114
    EOS_SetEventMode = 0x9115
    EOS_GetEvent = 0x9116
    EOS_TransferComplete = 0x9117
    EOS_KeepDeviceOn = 0x911D
    EOS_RemoteReleaseOn = 0x9128
    EOS_RemoteReleaseOff = 0x9129
    # Nikon
    NIKON_InitiateCaptureRecInSdram = 0x90C0
    NIKON_AfDrive = 0x90C1
    NIKON_ChangeCameraMode = 0x90C2
    NIKON_DelImageSDRAM = 0x90C3
    NIKON_GetEvent = 0x90C7
    NIKON_DeviceReady = 0x90C8


class ResponseCode(IntEnum):
    """Response codes (PTP 1.0/1.1)."""

    Undefined = 0x2000
    OK = 0x2001
    GeneralError = 0x2002
    SessionNotOpen = 0x2003
    InvalidTransactionID = 0x2004
    OperationNotSupported = 0x2005
    ParameterNotSupported = 0x2006
    IncompleteTransfer = 0x2007
    InvalidStorageId = 0x2008
    InvalidObjectHandle = 0x2009
    DevicePropNotSupported = 0x200A
    InvalidObjectFormatCode = 0x200B
    StoreFull = 0x200C
    ObjectWriteProtected = 0x200D
    StoreReadOnly = 0x200E
    AccessDenied = 0x200F
    NoThumbnailPresent = 0x2010
    SelfTestFailed = 0x2011
    PartialDeletion = 0x2012
    StoreNotAvailable = 0x2013
    SpecificationByFormatUnsupported = 0x2014
    NoValidObjectInfo = 0x2015
    InvalidCodeFormat = 0x2016
    UnknownVendorCode = 0x2017
    CaptureAlreadyTerminated = 0x2018
    DeviceBusy = 0x2019
    InvalidParentObject = 0x201A
    InvalidDevicePropFormat = 0x201B
    InvalidDevicePropValue = 0x201C
    InvalidParameter = 0x201D
    SessionAlreadyOpened = 0x201E
    TransactionCanceled = 0x201F
    SpecificationOfDestinationUnsupported = 0x2020


class EventCode(IntEnum):
    """Event codes: standard, Canon EOS (GetEvent record types) and Nikon (GetEvent entries)."""

    CancelTransaction = 0x4001
    ObjectAdded = 0x4002
    ObjectRemoved = 0x4003
    StoreAdded = 0x4004
    StoreRemoved = 0x4005
    DevicePropChanged = 0x4006
    ObjectInfoChanged = 0x4007
    DeviceInfoChanged = 0x4008
    RequestObjectTransfer = 0x4009
    StoreFull = 0x400A
    DeviceReset = 0x400B
    StorageInfoChanged = 0x400C
    CaptureComplete = 0x400D
    UnreportedStatus = 0x400E
    EOS_RequestGetEvent = 0xC101
    EOS_ObjectAddedEx = 0xC181
    EOS_ObjectRemoved = 0xC182
    EOS_RequestObjectTransfer = 0xC186
    EOS_PropValueChanged = 0xC189
    EOS_AvailListChanged = 0xC18A
    NIKON_ObjectAddedInSDRAM = 0xC101
    NIKON_CaptureCompleteRecInSdram = 0xC102


class ObjectFormat(IntEnum):
    """Object format codes of image files."""

    Undefined = 0x3000
    Association = 0x3001
    EXIF_JPEG = 0x3801
    TIFF = 0x380D
    DNG = 0x3811
    CANON_CRW = 0xB101
    CANON_CRW3 = 0xB103
    CANON_CR3 = 0xB108


class VendorExtension(IntEnum):
    """DeviceInfo VendorExtensionID values."""

    EASTMAN_KODAK = 0x00000001
    MICROSOFT = 0x00000006
    NIKON = 0x0000000A
    CANON = 0x0000000B


class PtpDecodeError(PsrigError, ValueError):
    """Bytes from a camera do not form a valid PTP container or dataset."""


@dataclass
class Container:
    """One decoded USB container.

    Attributes
    ----------
    type : ContainerType
    code : int
        Operation, response or event code.
    transaction_id : int
    params : tuple of int
        Up to five ``u32`` parameters (command, response, event containers).
    payload : bytes
        Dataset bytes (data containers only).
    """

    type: int
    code: int
    transaction_id: int
    params: tuple = ()
    payload: bytes = b""


def pack_container(ctype: int, code: int, tid: int, params=(), payload: bytes = b"") -> bytes:
    """Pack a container: parameters or a payload follow the 12-byte header."""
    if len(params) > 5:
        raise ValueError(f"PTP containers carry at most 5 parameters, got {len(params)}")
    body = struct.pack(f"<{len(params)}I", *params) + bytes(payload)
    return HEADER.pack(HEADER.size + len(body), ctype, code, tid) + body


def pack_command(code: int, tid: int, params=()) -> bytes:
    """Pack a command container (host -> camera)."""
    return pack_container(ContainerType.COMMAND, code, tid, params)


def pack_response(code: int, tid: int, params=()) -> bytes:
    """Pack a response container (camera -> host)."""
    return pack_container(ContainerType.RESPONSE, code, tid, params)


def pack_event(code: int, tid: int, params=()) -> bytes:
    """Pack an event container (interrupt endpoint), at most three parameters."""
    return pack_container(ContainerType.EVENT, code, tid, params[:3])


def pack_data_header(code: int, tid: int, payload_len: int) -> bytes:
    """The 12-byte header of a data container whose payload (bytes) is sent separately."""
    return HEADER.pack(HEADER.size + payload_len, ContainerType.DATA, code, tid)


def unpack_header(buf) -> tuple[int, int, int, int]:
    """Decode a header: returns (length, type, code, transaction_id)."""
    if len(buf) < HEADER.size:
        raise PtpDecodeError(f"PTP container of {len(buf)} bytes is shorter than its header")
    length, ctype, code, tid = HEADER.unpack_from(buf, 0)
    if length < HEADER.size or ctype not in tuple(ContainerType):
        raise PtpDecodeError(f"malformed PTP container header: length {length}, type {ctype}")
    return length, ctype, code, tid


def unpack_container(buf) -> Container:
    """Decode one complete container (command, response, event or data)."""
    length, ctype, code, tid = unpack_header(buf)
    if len(buf) != length:
        raise PtpDecodeError(f"PTP container says {length} bytes but {len(buf)} arrived")
    body = bytes(buf[HEADER.size:length])
    if ctype == ContainerType.DATA:
        return Container(ctype, code, tid, (), body)
    if len(body) % 4 or len(body) > 20:
        raise PtpDecodeError(f"PTP container 0x{code:04X}: {len(body)} parameter bytes")
    return Container(ctype, code, tid, struct.unpack(f"<{len(body) // 4}I", body))


class Reader:
    """Cursor over a dataset; every read checks bounds and raises :class:`PtpDecodeError`."""

    def __init__(self, data, what: str = "dataset"):
        self.data = bytes(data)
        self.pos = 0
        self.what = what

    def _take(self, fmt: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise PtpDecodeError(f"{self.what} ends at byte {len(self.data)}, "
                                 f"needed {size} more at byte {self.pos}")
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return values

    def u8(self) -> int:
        return self._take("B")[0]

    def u16(self) -> int:
        return self._take("H")[0]

    def u32(self) -> int:
        return self._take("I")[0]

    def string(self) -> str:
        """PTP string: u8 count of UTF-16LE code units including the NUL, 0 = empty."""
        n = self.u8()
        if n == 0:
            return ""
        units = self._take(f"{n}H")
        return "".join(map(chr, units)).rstrip("\x00")

    def array16(self) -> list[int]:
        """PTP array of u16: u32 count then the elements."""
        n = self.u32()
        return list(self._take(f"{n}H")) if n else []

    def array32(self) -> list[int]:
        n = self.u32()
        return list(self._take(f"{n}I")) if n else []


def pack_string(text: str) -> bytes:
    """Encode a PTP string (at most 254 characters plus the terminating NUL)."""
    if not text:
        return b"\x00"
    units = text.encode("utf-16-le") + b"\x00\x00"
    n = len(units) // 2
    if n > 255:
        raise ValueError(f"PTP string too long ({n - 1} characters): {text[:20]!r}...")
    return bytes([n]) + units


def pack_array(values, fmt: str = "H") -> bytes:
    """Encode a PTP array: u32 count then ``fmt`` elements."""
    values = list(values)
    return struct.pack(f"<I{len(values)}{fmt}", len(values), *values)


@dataclass
class DeviceInfo:
    """GetDeviceInfo dataset (PTP 1.0, 5.5.1)."""

    standard_version: int = 100
    vendor_extension_id: int = 0
    vendor_extension_version: int = 0
    vendor_extension_desc: str = ""
    functional_mode: int = 0
    operations: list = field(default_factory=list)
    events: list = field(default_factory=list)
    device_properties: list = field(default_factory=list)
    capture_formats: list = field(default_factory=list)
    image_formats: list = field(default_factory=list)
    manufacturer: str = ""
    model: str = ""
    device_version: str = ""
    serial_number: str = ""

    def pack(self) -> bytes:
        return b"".join([
            struct.pack("<HIH", self.standard_version, self.vendor_extension_id,
                        self.vendor_extension_version),
            pack_string(self.vendor_extension_desc),
            struct.pack("<H", self.functional_mode),
            pack_array(self.operations), pack_array(self.events),
            pack_array(self.device_properties), pack_array(self.capture_formats),
            pack_array(self.image_formats),
            pack_string(self.manufacturer), pack_string(self.model),
            pack_string(self.device_version), pack_string(self.serial_number),
        ])

    @classmethod
    def unpack(cls, data) -> "DeviceInfo":
        r = Reader(data, "DeviceInfo dataset")
        return cls(r.u16(), r.u32(), r.u16(), r.string(), r.u16(), r.array16(), r.array16(),
                   r.array16(), r.array16(), r.array16(), r.string(), r.string(), r.string(),
                   r.string())


_OI_FIXED = struct.Struct("<IHHIHIIIIIIIHII")


@dataclass
class ObjectInfo:
    """GetObjectInfo dataset (PTP 1.0, 5.5.2). Sizes in bytes, image dimensions in pixels."""

    storage_id: int = 0x00010001
    object_format: int = ObjectFormat.Undefined
    protection_status: int = 0
    compressed_size: int = 0
    thumb_format: int = 0
    thumb_compressed_size: int = 0
    thumb_width: int = 0
    thumb_height: int = 0
    image_width: int = 0
    image_height: int = 0
    image_bit_depth: int = 0
    parent_object: int = 0
    association_type: int = 0
    association_desc: int = 0
    sequence_number: int = 0
    filename: str = ""
    capture_date: str = ""
    modification_date: str = ""
    keywords: str = ""

    def pack(self) -> bytes:
        fixed = _OI_FIXED.pack(
            self.storage_id, self.object_format, self.protection_status,
            # sizes above 4 GiB do not fit PTP 1.0's u32: 0xFFFFFFFF means "see elsewhere"
            min(self.compressed_size, 0xFFFFFFFF), self.thumb_format,
            self.thumb_compressed_size, self.thumb_width, self.thumb_height, self.image_width,
            self.image_height, self.image_bit_depth, self.parent_object,
            self.association_type, self.association_desc, self.sequence_number)
        return fixed + b"".join(map(pack_string, (self.filename, self.capture_date,
                                                  self.modification_date, self.keywords)))

    @classmethod
    def unpack(cls, data) -> "ObjectInfo":
        r = Reader(data, "ObjectInfo dataset")
        fixed = r._take(_OI_FIXED.format[1:])
        return cls(*fixed, r.string(), r.string(), r.string(), r.string())


# Canon EOS GetEvent records: u32 size, u32 type, then type-specific fields. ObjectAddedEx
# offsets follow libgphoto2 (PTP_ece_OA_*); a record of size 8 and type 0 ends the list.
_EOS_OA = struct.Struct("<IIIIH10xII")  # size, type, handle, storage, ofc @0x10, size @0x1C, parent
_EOS_OA_NAME = 0x28


@dataclass
class EosObjectAdded:
    """One Canon EOS ObjectAddedEx record: the handle, format, size (bytes) and file name."""

    handle: int
    storage_id: int
    object_format: int
    size: int
    parent: int
    filename: str


def pack_eos_events(records) -> bytes:
    """Pack EOS GetEvent data: ``records`` are EosObjectAdded or (type, payload bytes)."""
    out = []
    for rec in records:
        if isinstance(rec, EosObjectAdded):
            name = rec.filename.encode("ascii") + b"\x00"
            size = _EOS_OA_NAME + len(name)
            head = _EOS_OA.pack(size, EventCode.EOS_ObjectAddedEx, rec.handle, rec.storage_id,
                                rec.object_format, rec.size, rec.parent)
            out.append(head[:_EOS_OA_NAME].ljust(_EOS_OA_NAME, b"\x00") + name)
        else:
            etype, payload = rec
            out.append(struct.pack("<II", 8 + len(payload), etype) + payload)
    out.append(struct.pack("<II", 8, 0))
    return b"".join(out)


def unpack_eos_events(data) -> list:
    """Decode EOS GetEvent data into EosObjectAdded records and (type, payload) tuples."""
    data = bytes(data)
    pos, records = 0, []
    while pos + 8 <= len(data):
        size, etype = struct.unpack_from("<II", data, pos)
        if size == 8 and etype == 0:
            break
        if size < 8 or pos + size > len(data):
            raise PtpDecodeError(f"EOS event record at byte {pos}: size {size} "
                                 f"overruns {len(data)} bytes")
        rec = data[pos:pos + size]
        if etype == EventCode.EOS_ObjectAddedEx and size > _EOS_OA_NAME:
            _, _, handle, storage, ofc, osize, parent = _EOS_OA.unpack_from(
                rec.ljust(_EOS_OA.size, b"\x00"))
            name = rec[_EOS_OA_NAME:].split(b"\x00", 1)[0].decode("ascii", "replace")
            records.append(EosObjectAdded(handle, storage, ofc, osize, parent, name))
        else:
            records.append((etype, rec[8:]))
        pos += size
    return records


def pack_nikon_events(events) -> bytes:
    """Pack Nikon GetEvent data: u16 count, then (u16 code, u32 param) per event."""
    events = list(events)
    return struct.pack("<H", len(events)) + b"".join(
        struct.pack("<HI", code, param) for code, param in events)


def unpack_nikon_events(data) -> list[tuple[int, int]]:
    """Decode Nikon GetEvent data into (code, param) pairs."""
    r = Reader(data, "Nikon GetEvent data")
    return [(r.u16(), r.u32()) for _ in range(r.u16())]


_FORMATS = {".dng": ObjectFormat.DNG, ".jpg": ObjectFormat.EXIF_JPEG,
            ".jpeg": ObjectFormat.EXIF_JPEG, ".tif": ObjectFormat.TIFF,
            ".tiff": ObjectFormat.TIFF, ".cr2": ObjectFormat.CANON_CRW3,
            ".crw": ObjectFormat.CANON_CRW, ".cr3": ObjectFormat.CANON_CR3}


def format_for_filename(name: str) -> int:
    """Object format code a camera would report for a file name (Undefined if unknown)."""
    suffix = name[name.rfind("."):].lower() if "." in name else ""
    return int(_FORMATS.get(suffix, ObjectFormat.Undefined))


# -- device properties -------------------------------------------------------------------------
# DevicePropDesc dataset (PTP 1.0, 5.5.3): u16 code, u16 datatype, u8 GetSet, factory default
# value, current value, u8 FormFlag, then the form: a range (min, max, step) or an enumeration
# (u16 count, values). Values are little-endian and as wide as their datatype.

class DataType(IntEnum):
    """PTP datatype codes of property values (PTP_DTC_*); arrays and 128-bit types omitted."""

    INT8 = 0x0001
    UINT8 = 0x0002
    INT16 = 0x0003
    UINT16 = 0x0004
    INT32 = 0x0005
    UINT32 = 0x0006
    INT64 = 0x0007
    UINT64 = 0x0008
    STR = 0xFFFF


_DT_FORMAT = {DataType.INT8: "b", DataType.UINT8: "B", DataType.INT16: "h",
              DataType.UINT16: "H", DataType.INT32: "i", DataType.UINT32: "I",
              DataType.INT64: "q", DataType.UINT64: "Q"}


class PropCode(IntEnum):
    """Device property codes of the exposure settings: PTP standard and Canon EOS."""

    FNumber = 0x5007          # UINT16, f-number x 100
    ExposureTime = 0x500D     # UINT32, units of 0.1 ms
    ExposureIndex = 0x500F    # UINT16, ISO speed
    EOS_Aperture = 0xD101     # Canon APEX-like code (see EOS_SCALES)
    EOS_ShutterSpeed = 0xD102
    EOS_ISOSpeed = 0xD103


class FormFlag(IntEnum):
    """DevicePropDesc FormFlag: which allowed-value form follows."""

    NONE = 0x00
    RANGE = 0x01
    ENUMERATION = 0x02


def _datatype(dtype) -> DataType:
    try:
        return DataType(dtype)
    except ValueError:
        raise PtpDecodeError(f"property datatype 0x{dtype:04X} is not supported") from None


def pack_value(dtype: int, value) -> bytes:
    """Encode one property value of PTP datatype ``dtype`` (an int, or a str for STR)."""
    dtype = _datatype(dtype)
    if dtype == DataType.STR:
        return pack_string(str(value))
    try:
        return struct.pack("<" + _DT_FORMAT[dtype], int(value))
    except struct.error:
        raise ValueError(f"{value!r} does not fit PTP datatype {dtype.name}") from None


def unpack_value(reader: Reader, dtype: int):
    """Read one property value of datatype ``dtype`` from ``reader``."""
    dtype = _datatype(dtype)
    if dtype == DataType.STR:
        return reader.string()
    return reader._take(_DT_FORMAT[dtype])[0]


@dataclass
class DevicePropDesc:
    """GetDevicePropDesc dataset.

    Attributes
    ----------
    code, datatype : int
    writable : bool
        GetSet: the host may set the value (False, e.g., for the aperture of a manual lens).
    factory, current : int or str
    form : FormFlag
    range : tuple (min, max, step) or None
    values : list or None
        The enumeration.
    """

    code: int
    datatype: int
    writable: bool
    factory: object
    current: object
    form: int = FormFlag.NONE
    range: tuple | None = None
    values: list | None = None

    def pack(self) -> bytes:
        out = [struct.pack("<HHB", self.code, self.datatype, int(bool(self.writable))),
               pack_value(self.datatype, self.factory), pack_value(self.datatype, self.current),
               bytes([self.form])]
        if self.form == FormFlag.RANGE:
            out += [pack_value(self.datatype, v) for v in self.range]
        elif self.form == FormFlag.ENUMERATION:
            out.append(struct.pack("<H", len(self.values)))
            out += [pack_value(self.datatype, v) for v in self.values]
        return b"".join(out)

    @classmethod
    def unpack(cls, data) -> "DevicePropDesc":
        r = Reader(data, "DevicePropDesc dataset")
        code, dtype, getset = r.u16(), r.u16(), r.u8()
        factory, current, form = unpack_value(r, dtype), unpack_value(r, dtype), r.u8()
        desc = cls(code, dtype, bool(getset), factory, current, form)
        if form == FormFlag.RANGE:
            desc.range = tuple(unpack_value(r, dtype) for _ in range(3))
        elif form == FormFlag.ENUMERATION:
            desc.values = [unpack_value(r, dtype) for _ in range(r.u16())]
        elif form != FormFlag.NONE:
            raise PtpDecodeError(f"DevicePropDesc 0x{code:04X}: unknown FormFlag {form}")
        return desc

    def allows(self, value) -> bool:
        """Whether the form admits ``value`` (no form: anything the datatype holds)."""
        if self.form == FormFlag.ENUMERATION:
            return value in self.values
        if self.form == FormFlag.RANGE:
            low, high, step = self.range
            return low <= value <= high and (step <= 1 or (value - low) % step == 0)
        return True


# -- Canon EOS properties ------------------------------------------------------------------------
# GetEvent records (libgphoto2 PTP_ece_Prop_*): PropValueChanged = size, type, u32 property,
# u32 value; AvailListChanged = size, type, u32 property, u32 value type (3: 16-bit values),
# u32 count, count x u32 values. SetDevicePropValueEx data = u32 size (12), u32 property,
# u32 value.
_EOS_DESC_U16 = 3


def pack_eos_prop_value(code: int, value: int) -> tuple[int, bytes]:
    """A PropValueChanged record for :func:`pack_eos_events`."""
    return EventCode.EOS_PropValueChanged, struct.pack("<II", code, value)


def pack_eos_avail_list(code: int, values) -> tuple[int, bytes]:
    """An AvailListChanged record (allowed values of a property) for :func:`pack_eos_events`."""
    values = list(values)
    return EventCode.EOS_AvailListChanged, struct.pack(
        f"<III{len(values)}I", code, _EOS_DESC_U16, len(values), *values)


def pack_eos_set_prop(code: int, value: int) -> bytes:
    """Data phase of EOS_SetDevicePropValueEx for a numeric property."""
    return struct.pack("<III", 12, code, value)


def unpack_eos_set_prop(data) -> tuple[int, int]:
    """(property, value) from EOS_SetDevicePropValueEx data."""
    r = Reader(data, "EOS SetDevicePropValueEx data")
    size, code, value = r.u32(), r.u32(), r.u32()
    if size != len(r.data):
        raise PtpDecodeError(f"EOS SetDevicePropValueEx says {size} bytes, {len(r.data)} came")
    return code, value


def eos_prop_records(records) -> tuple[dict, dict]:
    """Property values and allowed lists in unpacked GetEvent records.

    Returns
    -------
    values : dict
        property code -> current value (PropValueChanged records).
    allowed : dict
        property code -> list of allowed values (AvailListChanged records of 16-bit values).
    """
    values, allowed = {}, {}
    for rec in records:
        if isinstance(rec, EosObjectAdded):
            continue
        etype, payload = rec
        if etype == EventCode.EOS_PropValueChanged and len(payload) >= 8:
            code, value = struct.unpack_from("<II", payload)
            values[code] = value
        elif etype == EventCode.EOS_AvailListChanged and len(payload) >= 12:
            code, dtype, count = struct.unpack_from("<III", payload)
            if dtype == _EOS_DESC_U16 and len(payload) >= 12 + 4 * count:
                allowed[code] = list(struct.unpack_from(f"<{count}I", payload, 12))
    return values, allowed
