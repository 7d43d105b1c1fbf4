"""Decoding: raw and image frames -> linear float32 frames with saturation masks.

>>> from pipeline.decode import decode_session, decode_frame

Where things live: :mod:`.frame` (one file, by its kind), :mod:`.raw` (LibRaw through rawpy:
the mosaic and postprocess paths, registered in :data:`RAW_METHODS`), :mod:`.image` (PNG, TIFF,
EXR, JPG), :mod:`.exr` (the linear EXR written in one buffer), :mod:`.pool` (worker processes),
:mod:`.stage` (the ``decode`` stage). Transfer functions are in :mod:`pipeline.gamma`.
Measurements: docs/decoding.md.
"""

from .frame import check_options, decode_frame, frame_size
from .raw import METHODS as RAW_METHODS
from .stage import REFERENCE_KINDS, decode_session

__all__ = ["decode_session", "decode_frame", "frame_size", "check_options", "RAW_METHODS", "REFERENCE_KINDS"]
