"""Decoding: raw and image frames -> linear float32 frames with saturation masks.

>>> from pipeline.decode import decode_session, decode_frame

Where things live: :mod:`.formats` (image or raw, by content), :mod:`.frame` (one file),
:mod:`.raw` (LibRaw through rawpy: the mosaic and postprocess paths, registered in
:data:`RAW_METHODS`, and the other sensor layouts), :mod:`.image` (anything OpenImageIO reads),
:mod:`.transfer` (the transfer function a file declares), :mod:`.exr` (the linear EXR built in
numpy, uncompressed or ZIP), :mod:`.pool` (worker processes), :mod:`.stage` (the ``decode``
stage), :mod:`.record` (what its record says was assumed), :mod:`.hdr` (merging an exposure
bracket) and :mod:`.merge` (the stage's merge tasks). Transfer functions are in
:mod:`pipeline.core.gamma`; which frames are one bracket, :mod:`pipeline.core.brackets`.
Measurements: docs/decoding.md.
"""

from .formats import FrameFormat, frame_format, readable_formats
from .frame import COMPRESSIONS, check_options, decode_frame, frame_size
from .raw import METHODS as RAW_METHODS
from .record import describe as describe_record, describe_failures, frames_decoded, recorded_kwargs
from .stage import DECODE, REFERENCE_KINDS, DecodeStage, decode_session

__all__ = ["decode_session", "decode_frame", "frame_size", "check_options", "RAW_METHODS", "REFERENCE_KINDS",
           "COMPRESSIONS", "frame_format", "FrameFormat", "readable_formats", "describe_record", "describe_failures",
           "frames_decoded", "recorded_kwargs", "DecodeStage", "DECODE"]
