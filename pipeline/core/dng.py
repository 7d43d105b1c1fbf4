"""A minimal writer of DNG files, readable by LibRaw / rawpy.

The simulated camera and the decoder's tests write raw frames with it, so everything that the
decoder must honour (CFA order, per-channel black levels, white level) is written explicitly.
One IFD holds the uncompressed 16-bit data with the DNG tags LibRaw needs to interpret it: a
Bayer or X-Trans mosaic (PhotometricInterpretation 32803 = CFA, :func:`write_dng`), or linear
values (34892 = LinearRaw, :func:`write_linear_dng`): three per pixel (a demosaiced "linear
DNG") or one (a monochrome sensor).
"""

import struct

import io
from fractions import Fraction

import numpy as np
import tifffile

from .atomic import atomic_write_bytes
from .errors import InputError

__all__ = ["write_dng", "write_dng_file", "write_linear_dng", "CFA_ORDERS", "MIN_SIZE", "cfa_indices", "XTRANS"]

#: Bayer orders: the colours of the 2x2 repeat cell, row-major (top-left, top-right, ...).
CFA_ORDERS = ("RGGB", "BGGR", "GRBG", "GBRG")
#: Smallest height and width LibRaw accepts.
MIN_SIZE = 22
_COLOUR_CODE = {"R": 0, "G": 1, "B": 2}  # TIFF/EP CFAPattern codes
_IDENTITY = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
#: Fujifilm's X-Trans 6x6 colour filter array (0 R, 1 G, 2 B), row-major: ``cfa=XTRANS``
XTRANS = ((1, 1, 0, 1, 1, 2), (1, 1, 2, 1, 1, 0), (2, 0, 1, 0, 2, 1),
          (1, 1, 2, 1, 1, 0), (1, 1, 0, 1, 1, 2), (0, 2, 1, 2, 0, 1))
_LINEAR_RAW = 34892

# TIFF / DNG tag codes
_NEW_SUBFILE_TYPE = 254
_MAKE, _MODEL, _ORIENTATION = 271, 272, 274
_CFA_REPEAT_DIM, _CFA_PATTERN = 33421, 33422
_DNG_VERSION, _DNG_BACKWARD, _UNIQUE_MODEL = 50706, 50707, 50708
_CFA_PLANE_COLOR, _CFA_LAYOUT = 50710, 50711
_BLACK_REPEAT_DIM, _BLACK_LEVEL, _WHITE_LEVEL = 50713, 50714, 50717
_COLOR_MATRIX1, _AS_SHOT_NEUTRAL, _ILLUMINANT1 = 50721, 50728, 50778
_D65 = 21


def cfa_indices(cfa):
    """Colour index (0 = R, 1 = G, 2 = B) of each cell of a 2x2 Bayer pattern.

    Parameters
    ----------
    cfa : str
        One of :data:`CFA_ORDERS` (case-insensitive).

    Returns
    -------
    ndarray (2, 2) int
    """
    order = str(cfa).upper()
    if order not in CFA_ORDERS:
        raise InputError(f"cfa: unknown Bayer order {cfa!r}; expected one of {', '.join(CFA_ORDERS)}")
    return np.array([_COLOUR_CODE[c] for c in order]).reshape(2, 2)


def _rationals(values, signed=False, denominator=10000):
    """Flatten numbers into (numerator, denominator) pairs for a (S)RATIONAL tag."""
    pairs = []
    for value in values:
        frac = Fraction(float(value)).limit_denominator(denominator)
        if not signed and frac < 0:
            raise InputError(f"DNG tag value {value} must not be negative")
        pairs += [frac.numerator, frac.denominator]
    return pairs


def _black_levels(black_level):
    levels = np.broadcast_to(np.asarray(black_level, dtype=np.float64).ravel(), (4,)) \
        if np.size(black_level) in (1, 4) else None
    if levels is None:
        raise InputError(f"black_level: expected one value or 4 (in CFA order), got {black_level!r}")
    if (levels < 0).any():
        raise InputError(f"black_level: must be >= 0, got {list(levels)}")
    return levels


def _check_mosaic(mosaic):
    mosaic = np.asarray(mosaic)
    # LibRaw refuses frames narrower or shorter than 22 photosites as "not raw".
    if mosaic.ndim != 2 or min(mosaic.shape) < MIN_SIZE:
        raise InputError(f"mosaic: expected a 2-D array (H, W) of at least {MIN_SIZE}x{MIN_SIZE} "
                         f"(LibRaw's minimum), got shape {mosaic.shape}")
    if mosaic.dtype != np.uint16:
        if not np.issubdtype(mosaic.dtype, np.integer) or mosaic.min() < 0 or mosaic.max() > 65535:
            raise InputError(f"mosaic: expected uint16 values, got {mosaic.dtype}")
        mosaic = mosaic.astype(np.uint16)
    return np.ascontiguousarray(mosaic)


def _cfa_tags(cfa):
    """CFA repeat size and pattern tags of a Bayer order name or a 6x6 pattern (X-Trans)."""
    if isinstance(cfa, str):
        return [(_CFA_REPEAT_DIM, 3, 2, (2, 2)), (_CFA_PATTERN, 1, 4, bytes(cfa_indices(cfa).ravel().astype(np.uint8)))]
    pattern = np.asarray(cfa, np.uint8)
    if pattern.ndim != 2 or not set(np.unique(pattern)) <= {0, 1, 2}:
        raise InputError(f"cfa: expected a Bayer order or a 2-D pattern of 0 / 1 / 2, got {cfa!r}")
    return [(_CFA_REPEAT_DIM, 3, 2, pattern.shape), (_CFA_PATTERN, 1, pattern.size, bytes(pattern.ravel()))]


def _dng_tags(cfa, levels, white_level, camera_model, as_shot_neutral, color_matrix):
    matrix = np.asarray(color_matrix, dtype=np.float64).reshape(-1)
    if matrix.size != 9:
        raise InputError(f"color_matrix: expected 3x3 values, got {matrix.size}")
    neutral = np.asarray(as_shot_neutral, dtype=np.float64).reshape(-1)
    if neutral.size != 3 or (neutral <= 0).any():
        raise InputError(f"as_shot_neutral: expected 3 positive values, got {list(neutral)}")
    if levels.max() >= white_level:
        raise InputError(f"black_level {list(levels)} must be below white_level {white_level}")
    integral = np.all(levels == np.round(levels))
    if cfa is None:   # LinearRaw: one level per sample of a pixel
        levels = levels[:1] if np.all(levels == levels[0]) else levels
    black = (_BLACK_LEVEL, 4, len(levels), [int(v) for v in levels]) if integral \
        else (_BLACK_LEVEL, 5, len(levels), _rationals(levels))
    model = str(camera_model)
    return [
        (_NEW_SUBFILE_TYPE, 4, 1, 0),
        (_MAKE, 2, None, "psrig"),
        (_MODEL, 2, None, model),
        (_ORIENTATION, 3, 1, 1),
        *([] if cfa is None else _cfa_tags(cfa)),
        (_DNG_VERSION, 1, 4, bytes((1, 4, 0, 0))),
        (_DNG_BACKWARD, 1, 4, bytes((1, 1, 0, 0))),
        (_UNIQUE_MODEL, 2, None, model),
        *([] if cfa is None else [(_CFA_PLANE_COLOR, 1, 3, bytes((0, 1, 2))), (_CFA_LAYOUT, 3, 1, 1)]),
        (_BLACK_REPEAT_DIM, 3, 2, (2, 2) if cfa is not None else (1, 1)),
        black,
        (_WHITE_LEVEL, 4, 1, int(white_level)),
        (_COLOR_MATRIX1, 10, 9, _rationals(matrix, signed=True)),
        (_AS_SHOT_NEUTRAL, 5, 3, _rationals(neutral)),
        (_ILLUMINANT1, 3, 1, _D65),
    ]


def write_dng(mosaic, *, cfa="RGGB", black_level=512, white_level=16383,
              camera_model="psrig simulated camera", as_shot_neutral=(1, 1, 1),
              color_matrix=_IDENTITY):
    """Encode a Bayer mosaic as an uncompressed CFA DNG.

    Parameters
    ----------
    mosaic : ndarray (H, W) uint16
        Raw photosite values (digital numbers, black level included), row 0 at the top;
        H, W >= :data:`MIN_SIZE`.
    cfa : str or 2-D pattern
        Bayer order of the 2x2 cell at the top-left: 'RGGB', 'BGGR', 'GRBG' or 'GBRG'; or the
        colours (0 R, 1 G, 2 B) of a larger repeat cell, such as :data:`XTRANS` (then one
        black level for all photosites).
    black_level : float or sequence of 4 floats
        Black level in DN: one for all photosites or one per cell of the 2x2 CFA cell, in CFA
        order (row-major: top-left, top-right, bottom-left, bottom-right).
    white_level : int
        Saturation level in DN (raw value of a clipped photosite).
    camera_model : str
        Stored as Make/Model/UniqueCameraModel.
    as_shot_neutral : 3 floats
        Camera neutral (R, G, B), DNG AsShotNeutral.
    color_matrix : 3x3 floats
        XYZ -> camera matrix, DNG ColorMatrix1 (D65).

    Returns
    -------
    bytes
        The DNG file's content.
    """
    mosaic = _check_mosaic(mosaic)
    levels = _black_levels(black_level)
    if not 0 < int(white_level) <= 65535:
        raise InputError(f"white_level: expected 1..65535, got {white_level}")
    tags = _dng_tags(cfa, levels, int(white_level), camera_model, as_shot_neutral, color_matrix)
    buffer = io.BytesIO()
    with tifffile.TiffWriter(buffer, byteorder="<", bigtiff=False) as tif:
        tif.write(mosaic, photometric=32803, compression=None, metadata=None,
                  software=False, description=None, rowsperstrip=mosaic.shape[0],
                  extratags=tags)
    return buffer.getvalue()


def write_linear_dng(pixels, *, black_level=512, white_level=16383, camera_model="psrig linear camera"):
    """Encode linear raw values as an uncompressed LinearRaw DNG.

    Parameters
    ----------
    pixels : ndarray (H, W, 3) or (H, W) uint16
        Raw values (DN, black level included): three per pixel (a demosaiced linear DNG) or
        one (a monochrome sensor); H, W >= :data:`MIN_SIZE`.
    black_level : float
        Black level, DN, of every sample.
    white_level : int
        Saturation level, DN.
    camera_model : str

    Returns
    -------
    bytes
    """
    pixels = np.asarray(pixels)
    grey = pixels.ndim == 2
    data = _check_mosaic(pixels if grey else pixels[:, :, 0])
    if not grey:
        if pixels.ndim != 3 or pixels.shape[2] != 3:
            raise InputError(f"pixels: expected (H, W, 3) or (H, W), got shape {pixels.shape}")
        data = np.ascontiguousarray(pixels.astype(np.uint16))
    levels = _black_levels(black_level)
    tags = _dng_tags(None, levels, int(white_level), camera_model, (1, 1, 1), _IDENTITY)
    buffer = io.BytesIO()
    with tifffile.TiffWriter(buffer, byteorder="<", bigtiff=False) as tif:
        # tifffile wants 3 samples for LinearRaw: a one-sample file is written as CFA and its
        # PhotometricInterpretation entry rewritten below
        tif.write(data, photometric=32803 if grey else _LINEAR_RAW, compression=None, metadata=None,
                  software=False, description=None, rowsperstrip=data.shape[0], extratags=tags,
                  planarconfig=None if grey else "contig")
    encoded = buffer.getvalue()
    if grey:
        entry = struct.pack("<HHIHH", 262, 3, 1, 32803, 0)
        encoded = encoded.replace(entry, struct.pack("<HHIHH", 262, 3, 1, _LINEAR_RAW, 0), 1)
    return encoded


def write_dng_file(path, mosaic, **options):
    """Write :func:`write_dng` output to ``path`` atomically; options as for :func:`write_dng`."""
    atomic_write_bytes(path, write_dng(mosaic, **options))
