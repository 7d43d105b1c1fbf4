"""What the decode stage record says beyond its parameters, and how to read older records.

A frame's info (from :func:`pipeline.decode.frame.decode_frame` and the EXR writer) holds what
was assumed or chosen for it: the transfer function of an image file and why, the sensor layout
and decoding path of a raw file, how its EXR was written. :func:`assumed` gathers them into the
stage record, :func:`describe` into the lines ``psrig decode`` and ``psrig run`` print.
"""

from ..core.brackets import format_seconds
from ..core.gamma import NAMES
from .transfer import describe_transfer

__all__ = ["assumed", "describe", "describe_merged", "describe_failures", "frames_decoded", "recorded_kwargs"]


def assumed(infos):
    """Record keys summarising the frames' infos ({frame id: info}).

    Returns
    -------
    dict
        ``transfer``: {'<transfer> (<why>)': [frame ids]} of image files; ``postprocessed``:
        {sensor: [frame ids]} of raw files decoded by LibRaw's postprocess because the mosaic
        path is for Bayer sensors; ``compression`` {'zip' / 'none': count} and
        ``linear_bytes`` (total EXR bytes written or kept).
    """
    transfer, postprocessed, compression, size = {}, {}, {}, 0
    for frame_id, info in infos.items():
        if "transfer" in info:
            key = f"{describe_transfer(info['transfer'])} ({info['transfer_from']})"
            transfer.setdefault(key, []).append(frame_id)
        if info.get("raw") and info.get("sensor", "bayer") != "bayer":
            postprocessed.setdefault(info["sensor"], []).append(frame_id)
        written = info.get("exr") or {}
        if written:
            compression[written["compression"]] = compression.get(written["compression"], 0) + 1
            size += written["bytes"]
    out = {"transfer": transfer, "postprocessed": postprocessed}
    if compression:
        out.update(compression=compression, linear_bytes=size)
    return out


def _formats(record, ids):
    frames = record.get("frames") or {}
    names = sorted({f"{frames[i].get('bits', '?')}-bit {str(frames[i].get('format', 'image')).upper()}"
                    for i in ids if i in frames})
    return ", ".join(names) or "image"


def describe(record):
    """Lines telling what a decode record assumed: transfer functions (naming ``--gamma``
    where one was assumed), raw files that took LibRaw's postprocess, the EXR size."""
    lines = []
    decision = record.get("transfer_decision")
    if decision:
        lines.append(decision["message"])
    for key, ids in (record.get("transfer") or {}).items():
        what = f"{len(ids)} frame(s) ({_formats(record, ids)}) decoded as {key}"
        if decision and key.endswith(f"({decision['why']})"):
            # the decision's line says why; the files' line says which
            what = f"{len(ids)} frame(s) ({_formats(record, ids)}) decoded as {key.split(' (')[0]} (decided from the data, above)"
        elif "assumed" in key:
            what += "; if that is wrong, give --gamma srgb|linear|EXPONENT (psrig decode or psrig run)"
        lines.append(what)
    for sensor, ids in (record.get("postprocessed") or {}).items():
        lines.append(f"{len(ids)} raw frame(s) from a {sensor} sensor decoded by LibRaw's linear postprocess "
                     "(the mosaic path is for Bayer sensors; dark values are clipped at black)")
    lines += describe_merged(record.get("merged"))
    if record.get("adopted"):
        lines.append(f"{len(record['adopted'])} frame(s) decoded by a run that was stopped before recording them "
                     "were kept (their receipts and outputs' hashes checked)")
    if record.get("linear_bytes"):
        counts = record.get("compression") or {}
        done = sum(counts.values())
        lines.append(f"linear/: {record['linear_bytes'] / 1e6:.1f} MB for {done} frame(s) "
                     f"({', '.join(f'{n} {kind}' for kind, n in sorted(counts.items()))})")
    return lines


def describe_merged(merged):
    """Lines saying what a decode record's ``merged`` ({group: info}) did."""
    if not merged:
        return []
    pixels, total, saturated = {}, 0, 0.0
    for info in merged.values():
        for frame_id, share in info["from"].items():
            label = format_seconds(info["shutters"][frame_id])
            pixels[label] = pixels.get(label, 0.0) + share
        total += 1
        saturated += info["saturated_in_all"]
    reference = format_seconds(next(iter(merged.values()))["reference_shutter"])
    shares = ", ".join(f"{100 * share / total:.1f} % from {label}" for label, share in pixels.items())
    lines = [f"{total} exposure bracket(s) merged into one frame each, scaled to {reference}: of their pixels "
             f"{shares}; {100 * saturated / total:.2f} % saturated in every exposure (flagged)"]
    return lines


def frames_decoded(record):
    """How many frame files a decode record decoded (or kept): those in ``linear/`` and the
    exposures of brackets that were only merged."""
    merged = record.get("merged") or {}
    return len(record.get("frames") or {}) + sum(len(info.get("exposures") or {}) for info in merged.values())


def recorded_kwargs(params):
    """Keyword options of :func:`pipeline.decode.decode_session` that reproduce a record's params.

    Records written before the EXR options existed wrote uncompressed float32 and took 8-bit
    files as sRGB ('srgb', their default) and 16-bit ones as linear, which is what 'auto' does
    for files that declare nothing; they are read as such, so that ``psrig run`` keeps their
    outputs (``psrig decode SESSION`` rewrites them compressed).
    """
    kwargs = dict(params)
    if "compression" not in kwargs:
        kwargs.setdefault("compression", "none")
        if kwargs.get("gamma") == "srgb":
            kwargs["gamma"] = "auto"
    if kwargs.get("gamma") not in NAMES and kwargs.get("gamma") is not None:
        kwargs["gamma"] = float(kwargs["gamma"])
    return kwargs


def describe_failures(failed, named=3):
    """One line per distinct reason of a record's ``failed`` {frame id: reason}, naming its
    frames (the first ``named``, then a count): a crashed pool fails every frame alike, and
    66 identical lines hide what happened."""
    frames_by_reason = {}
    for frame_id, reason in (failed or {}).items():
        frames_by_reason.setdefault(reason, []).append(frame_id)
    lines = []
    for reason, ids in frames_by_reason.items():
        if len(ids) == 1 and ids[0] in reason:
            lines.append(reason)
            continue
        more = f" and {len(ids) - named} more" if len(ids) > named else ""
        lines.append(f"{', '.join(ids[:named])}{more}: {reason}")
    return lines
