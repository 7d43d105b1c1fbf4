"""Options of the ``decode`` stage (:mod:`pipeline.decode`); ``psrig run`` spells the raw path
``--decode-method``."""

from dataclasses import dataclass

from ..core.errors import InputError
from ..core.options import Options, option

__all__ = ["DecodeOptions", "COMPRESSIONS", "parse_gamma_text"]

#: how linear/ EXRs are written (:func:`pipeline.decode.exr.encode_exr`)
COMPRESSIONS = ("auto", "zip", "none")


def parse_gamma_text(text):
    """``--gamma``'s text: 'auto', 'srgb', 'linear' or an exponent."""
    from ..core.gamma import parse_gamma   # numpy: only when a value is parsed

    try:
        return parse_gamma(text)
    except InputError as exc:
        raise ValueError(str(exc)) from None


@dataclass(frozen=True)
class DecodeOptions(Options):
    """What ``psrig decode`` and ``psrig run`` set of decoding."""

    kind = "decode option"
    method: str = option("mosaic", "mosaic: from the raw mosaic with per-channel black levels, unbiased; "
                                   "postprocess: LibRaw's linear pipeline", choices=("mosaic", "postprocess"))
    channels: str = option("rgb", "one grey channel instead of RGB", choices=("rgb", "grey"), flag="--grey",
                           const="grey", default_text="RGB")
    binning: int = option(1, "2: half size, 2x2 cells averaged without demosaicing", choices=(1, 2), flag="--bin",
                          kind=int, parse=int)
    gamma: object = option("auto", "transfer function of 8- and 16-bit image frames: auto (what each file "
                                   "declares; for 8-bit files that declare none, the transfer under which the object "
                                   "frames best fit a rank-3 (Lambertian) stack, sRGB when none fits clearly better; "
                                   "linear for 16-bit), srgb, linear, or an exponent such as 2.2; printed with the "
                                   "evidence and recorded", parse=parse_gamma_text, kind=str, metavar="G")
    compression: str = option("auto", "linear/ EXRs: auto (lossless ZIP for the frames it shrinks to 1/1.8 or "
                                      "less, such as frames from 8/16-bit files), zip, none", choices=COMPRESSIONS)
    half: bool = option(False, "half-float EXRs: half the disk, but lossy (11-bit mantissa)", kind=bool)
