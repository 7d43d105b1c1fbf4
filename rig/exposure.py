"""Exposure values of a rig's ``exposure:`` section: parsing, matching and display.

Shutter times in seconds, ISO speeds and f-numbers; the PTP standard encodings (0.1 ms units,
f-number x 100, ISO) and Canon EOS stop codes (computed from the stop, not tabled); the nominal
third-stop series cameras show; and the rule that matches a request to what a camera allows
(1/12 stop for shutter and aperture, exact for ISO). No USB here: :mod:`rig.camera` uses these
to set the values over PTP, :mod:`rig.config` to validate a rig file, and the simulated camera
to describe what it allows.
"""

from __future__ import annotations

import math

from rig.ptp import PropCode

__all__ = ["EXPOSURE_KEYS", "PARSERS", "parse_shutter", "parse_aperture", "parse_iso", "NOMINAL_SERIES",
           "EOS_SCALES", "eos_encode", "eos_decode", "eos_table", "nominal", "encode_standard",
           "decode_standard", "stop_distance", "TOLERANCE", "choose_value", "format_shutter",
           "format_aperture", "format_exposure"]

EXPOSURE_KEYS = ("shutter", "iso", "aperture")
"""Keys of a rig's ``exposure:`` section that are set on the camera."""


def _number(value, key: str) -> float:
    if isinstance(value, bool):
        raise ValueError(f"exposure.{key}: {value!r} is not a number")
    if isinstance(value, (int, float)):
        number = float(value)
    else:
        text = str(value).strip().lower()
        num, slash, den = text.partition("/")
        try:
            number = float(num) / float(den) if slash else float(text)
        except (ValueError, ZeroDivisionError):
            raise ValueError(f"exposure.{key}: {value!r} is not a number") from None
    if not number > 0 or number == float("inf"):
        raise ValueError(f"exposure.{key}: {value!r} must be a positive number")
    return number


def parse_shutter(value) -> float:
    """Shutter time in seconds from '1/30', '1/30s', 0.033, 2 or '2' (seconds).

    Raises
    ------
    ValueError
        Naming ``exposure.shutter`` and the value.
    """
    text = value if isinstance(value, (int, float)) else str(value).strip().lower()
    if isinstance(text, str) and text.endswith("s"):
        text = text[:-1].strip()
    return _number(text, "shutter")


def parse_aperture(value) -> float:
    """f-number from 8, 5.6, '8', 'f/8' or 'F8'."""
    text = value if isinstance(value, (int, float)) else str(value).strip().lower()
    if isinstance(text, str):
        text = text.removeprefix("f/").removeprefix("f")
    return _number(text, "aperture")


def parse_iso(value) -> int:
    """ISO speed from 100 or '100' (a whole number)."""
    number = _number(value, "iso")
    if number != round(number):
        raise ValueError(f"exposure.iso: {value!r} is not a whole number")
    return int(round(number))


#: key -> parser of a rig file's value (seconds, ISO, f-number); ValueError naming the key
PARSERS = {"shutter": parse_shutter, "iso": parse_iso, "aperture": parse_aperture}

# The nominal third-stop series printed on cameras; Canon codes decode to the nearest entry.
NOMINAL_SERIES = {
    "shutter": (30, 25, 20, 15, 13, 10, 8, 6, 5, 4, 3.2, 2.5, 2, 1.6, 1.3, 1, 0.8, 0.6, 0.5, 0.4,
                0.3, 1 / 4, 1 / 5, 1 / 6, 1 / 8, 1 / 10, 1 / 13, 1 / 15, 1 / 20, 1 / 25, 1 / 30,
                1 / 40, 1 / 50, 1 / 60, 1 / 80, 1 / 100, 1 / 125, 1 / 160, 1 / 200, 1 / 250,
                1 / 320, 1 / 400, 1 / 500, 1 / 640, 1 / 800, 1 / 1000, 1 / 1250, 1 / 1600,
                1 / 2000, 1 / 2500, 1 / 3200, 1 / 4000, 1 / 5000, 1 / 6400, 1 / 8000),
    "aperture": (1.0, 1.1, 1.2, 1.4, 1.6, 1.8, 2.0, 2.2, 2.5, 2.8, 3.2, 3.5, 4.0, 4.5, 5.0, 5.6,
                 6.3, 7.1, 8.0, 9.0, 10, 11, 13, 14, 16, 18, 20, 22, 25, 29, 32),
    "iso": (50, 64, 80, 100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000, 1250, 1600,
            2000, 2500, 3200, 4000, 5000, 6400, 8000, 10000, 12800, 16000, 20000, 25600),
}

#: Canon EOS stop codes: code = zero + 8 * stops, third stops at +3 and +5, half stops at +4;
#: stops of a physical value v are ``sign * log2(v / unit) * per``. Code 0 means 'auto'.
EOS_SCALES = {
    "shutter": {"code": PropCode.EOS_ShutterSpeed, "zero": 0x38, "unit": 1.0, "sign": -1,
                "per": 1},   # Tv: 0x38 = 1 s, +8 = half the time
    "aperture": {"code": PropCode.EOS_Aperture, "zero": 0x08, "unit": 1.0, "sign": 1,
                 "per": 2},  # Av: 0x08 = f/1, +8 = f-number x sqrt(2)
    "iso": {"code": PropCode.EOS_ISOSpeed, "zero": 0x48, "unit": 100.0, "sign": 1,
            "per": 1},       # Sv: 0x48 = ISO 100, +8 = double
}
_EOS_THIRD_STEP = (0, 3, 5)


def _stops(key: str, value: float) -> float:
    s = EOS_SCALES[key]
    return s["sign"] * s["per"] * math.log2(value / s["unit"])


def eos_encode(key: str, value: float) -> int:
    """Canon code of the third stop nearest ``value`` (seconds, f-number or ISO)."""
    thirds = round(3 * _stops(key, value))
    whole, third = divmod(thirds, 3)
    return EOS_SCALES[key]["zero"] + 8 * whole + _EOS_THIRD_STEP[third]


def eos_decode(key: str, code: int) -> float | None:
    """The nominal value (seconds, f-number or ISO) of a Canon code; None for 0 (auto)."""
    if code == 0:
        return None
    s = EOS_SCALES[key]
    whole, eighths = divmod(code - s["zero"], 8)
    stops = whole + eighths / 8.0
    for step, fraction in ((3, 1 / 3), (5, 2 / 3)):  # codes +3/+5 are exact thirds, not 3/8
        if eighths == step:
            stops = whole + fraction
    exact = s["unit"] * 2.0 ** (s["sign"] * stops / s["per"])
    return nominal(key, exact)


def nominal(key: str, value: float) -> float:
    """The nominal series value nearest ``value`` when within 1/6 stop (half the series'
    spacing; 1/30 is 1/32 rounded, 0.09 stop off), else ``value`` itself."""
    series = NOMINAL_SERIES[key]
    best = min(series, key=lambda v: abs(math.log2(v / value)))
    per = 2 if key == "aperture" else 1
    return float(best) if abs(per * math.log2(best / value)) <= 1 / 6 else float(value)


def format_shutter(seconds: float) -> str:
    """'1/30' below 0.3 s (as cameras print it), else seconds, e.g. '0.5', '2'."""
    if seconds < 0.3 - 1e-9:
        return f"1/{1 / seconds:.0f}" if abs(1 / seconds - round(1 / seconds)) < 0.05 \
            else f"1/{1 / seconds:.1f}"
    return f"{seconds:g}"


def format_aperture(fnumber: float) -> str:
    return f"f/{fnumber:g}"


#: Largest distance (stops) between a request and the allowed value it is taken as. Camera
#: lists mix third and half stops, 1/6 stop apart at the closest, so 1/12 stop can only mean
#: one of them; it admits 0.033 for 1/30 s. ISO values are exact numbers: no tolerance.
TOLERANCE = {"shutter": 1 / 12, "aperture": 1 / 12, "iso": 0.0}


def stop_distance(key: str, a: float, b: float) -> float:
    """|a - b| in stops (an aperture stop is a factor sqrt(2) of the f-number)."""
    return abs((2 if key == "aperture" else 1) * math.log2(a / b))


def encode_standard(key: str, value: float) -> int:
    """PTP standard property value: 0.1 ms units, f-number x 100, or ISO."""
    return int(round(value * {"shutter": 1e4, "aperture": 100, "iso": 1}[key]))


def decode_standard(key: str, device: int) -> float:
    value = device / {"shutter": 1e4, "aperture": 100.0, "iso": 1.0}[key]
    return nominal(key, value) if value > 0 else value


def eos_table(key: str) -> list[int]:
    """Canon codes of the nominal third-stop series: the fallback allowed list."""
    return sorted({eos_encode(key, v) for v in NOMINAL_SERIES[key]})


def choose_value(key: str, want: float, pairs):
    """Pick the allowed value matching a request.

    Parameters
    ----------
    key : {'shutter', 'iso', 'aperture'}
    want : float
        Requested seconds, ISO or f-number.
    pairs : list of (device value, nominal value)
        What the camera allows.

    Returns
    -------
    device : int or None
        The device value whose nominal value is within the key's tolerance (1/12 stop for
        shutter and aperture, exact for ISO) of ``want``; None if there is none.
    nearest : list of (device value, nominal value)
        Up to three allowed values nearest ``want``, in increasing value.
    """
    ranked = sorted(pairs, key=lambda p: stop_distance(key, want, p[1]))
    nearest = sorted(ranked[:3], key=lambda p: p[1])
    if ranked and stop_distance(key, want, ranked[0][1]) <= TOLERANCE[key] + 1e-9:
        return ranked[0][0], nearest
    return None, nearest


def format_exposure(key: str, value) -> str:
    """'1/30 s', 'ISO 100', 'f/8' (value in seconds, ISO or f-number)."""
    if value is None:
        return "auto"
    if key == "shutter":
        return f"{format_shutter(value)} s"
    if key == "iso":
        return f"ISO {value:g}"
    return format_aperture(value)
