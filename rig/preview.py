"""Preview frames: one exposure per chosen light, measured before a long capture.

:func:`analyse_raw` reads a raw frame's mosaic (rawpy) and reports per colour channel the
percentiles of the values (black removed, 1.0 = white), the share of clipped photosites, a
shutter time that would put the 99.9th percentile at 80 % of white, and a focus measure (the
variance of the Laplacian of the green channel). :func:`take_preview` shoots the frames through
the rig's drivers (the light held as in a capture) and writes a PNG of each, atomically.
``psrig preview`` prints them; ``psrig capture`` refuses to start when the brightest light's
preview clips more than the rig's ``preview: max_clipped``.
"""

import io
from dataclasses import dataclass, field

import numpy as np

from pipeline.core.errors import PsrigError

__all__ = ["PreviewError", "FrameStats", "analyse_raw", "brightest_light", "default_lights",
           "take_preview", "format_stats", "check_clipping", "TARGET", "PERCENTILES"]

TARGET = 0.8  # the suggested shutter puts the 99.9th percentile here (share of white)
PERCENTILES = (1, 50, 99, 99.9)
CHANNELS = ("R", "G", "B")


class PreviewError(PsrigError):
    """A preview cannot be taken or read, or it clips more than allowed."""


@dataclass
class FrameStats:
    """What one preview frame shows. Values are shares of white (black removed).

    Attributes
    ----------
    light : int or None
    percentiles : dict
        ``{channel: {percentile: value}}``.
    clipped : dict
        ``{channel: share of photosites at or above the white level}``.
    shutter : float or None
        The shutter time (s) the frame was shot at, if known.
    suggested_shutter : float or None
        Shutter (s) putting the 99.9th percentile of the brightest channel at 80 % of white
        (an upper bound when the frame clips).
    focus : float
        Variance of the Laplacian of the green channel (higher: sharper).
    png : str or None
        Where the picture was written.
    """

    light: int | None
    percentiles: dict
    clipped: dict
    shutter: float | None
    suggested_shutter: float | None
    focus: float
    png: str | None = None
    extra: dict = field(default_factory=dict)

    @property
    def worst_clipped(self):
        """(channel, share) of the channel with the most clipped photosites."""
        channel = max(self.clipped, key=self.clipped.get)
        return channel, self.clipped[channel]


def _mosaic(data):
    import rawpy

    try:
        with rawpy.imread(io.BytesIO(bytes(data))) as raw:
            mosaic = raw.raw_image_visible.astype(np.float32)
            colours = raw.raw_colors_visible.copy()
            black = np.asarray(raw.black_level_per_channel, np.float32)
            white = float(raw.white_level)
            names = raw.color_desc.decode("ascii", "replace")
    except Exception as exc:  # LibRaw raises a zoo of its own types for broken files
        raise PreviewError(f"the preview frame cannot be read as a raw file ({type(exc).__name__}: {exc})") from None
    return mosaic, colours, black, white, names


def analyse_raw(data, shutter=None, light=None):
    """Measure a raw frame (bytes as the camera delivered them); returns :class:`FrameStats`."""
    mosaic, colours, black, white, names = _mosaic(data)
    level = black[colours]
    values = (mosaic - level) / np.maximum(white - level, 1.0)
    percentiles, clipped = {}, {}
    for index, name in enumerate(names[:4]):
        channel = name
        site = colours == index
        if not site.any():
            continue
        chosen = values[site]
        clipped.setdefault(channel, []).append((mosaic[site] >= white).mean())
        percentiles.setdefault(channel, []).append(np.percentile(chosen, PERCENTILES))
    clipped = {c: float(np.mean(v)) for c, v in clipped.items()}
    percentiles = {c: dict(zip(PERCENTILES, np.round(np.mean(v, axis=0), 5).tolist()))
                   for c, v in percentiles.items()}
    top = max(p[99.9] for p in percentiles.values())
    suggested = None if shutter is None or top <= 0 else float(shutter) * TARGET / top
    return FrameStats(light, percentiles, clipped, shutter, suggested, _focus(values, colours, names))


def _focus(values, colours, names):
    import cv2

    green = [i for i, n in enumerate(names[:4]) if n == "G"]
    h, w = values.shape
    half = values[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2)
    sites = colours[:2, :2]
    planes = [half[:, i, :, j] for i in range(2) for j in range(2) if sites[i, j] in green]
    plane = np.mean(planes, axis=0) if planes else values
    return float(cv2.Laplacian(plane.astype(np.float32), cv2.CV_32F).var())


def brightest_light(rig_config):
    """The light that should give the brightest frame: the highest level, then the one
    closest to the camera axis (largest z of its nominal direction)."""
    directions = np.asarray(rig_config.lights.directions)
    levels = np.asarray(rig_config.lights.get("levels") or [255] * len(directions), float)
    return int(np.lexsort((directions[:, 2], levels))[-1])


def default_lights(rig_config):
    """Lights a preview takes when none are named: the brightest."""
    return [brightest_light(rig_config)]


def format_stats(stats):
    """Lines describing one preview frame for a terminal."""
    what = "lights off" if stats.light is None else f"light {stats.light}"
    lines = [f"preview {what}:"]
    for channel, values in stats.percentiles.items():
        shown = ", ".join(f"p{p:g} {v:.3f}" for p, v in values.items())
        lines.append(f"  {channel}: {shown}; clipped {100 * stats.clipped[channel]:.2f} %")
    if stats.suggested_shutter is not None:
        clipped = stats.worst_clipped[1] > 0
        lines.append(f"  suggested shutter: {'at most ' if clipped else ''}"
                     f"{_shutter_text(stats.suggested_shutter)} (now {_shutter_text(stats.shutter)}"
                     f"; puts the 99.9th percentile at {100 * TARGET:.0f} % of white)")
    lines.append(f"  focus (variance of the Laplacian, green): {stats.focus:.3g}")
    if stats.png:
        lines.append(f"  picture: {stats.png}")
    return lines


def _shutter_text(seconds):
    from rig.exposure import format_exposure

    return format_exposure("shutter", seconds)


def check_clipping(stats, max_clipped):
    """Raise :class:`PreviewError` when a channel clips more than ``max_clipped`` (a share)."""
    channel, share = stats.worst_clipped
    if share > max_clipped:
        hint = (f"; a shutter of {_shutter_text(stats.suggested_shutter)} or shorter should fit"
                if stats.suggested_shutter else "")
        raise PreviewError(f"the preview of light {stats.light} clips {100 * share:.2f} % of the "
                           f"{channel} photosites (the rig allows {100 * max_clipped:.2f} %, "
                           f"preview: max_clipped){hint}; shorten the exposure, lower the light "
                           f"levels, or capture anyway with --no-preview-check")


def write_png(path, data):
    """A viewable 8-bit picture of a raw frame (half size, square-root tone curve), atomically."""
    from pipeline.core.imageio import write_image

    mosaic, colours, black, white, names = _mosaic(data)
    level = black[colours]
    values = np.clip((mosaic - level) / np.maximum(white - level, 1.0), 0, 1)
    h, w = values.shape
    half = values[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2)
    sites = colours[:2, :2]
    rgb = np.zeros((h // 2, w // 2, 3), np.float32)
    counts = np.zeros(3)
    for i in range(2):
        for j in range(2):
            channel = "RGB".find(names[sites[i, j]]) if names[sites[i, j]] in "RGB" else 1
            rgb[..., channel] += half[:, i, :, j]
            counts[channel] += 1
    rgb /= np.maximum(counts, 1)
    write_image(path, np.sqrt(rgb), bits=8)
    return str(path)


def take_preview(devices, lights, *, shutter=None, png_folder=None):
    """Shoot one frame per light of ``lights`` with the rig's open devices; [FrameStats].

    ``devices`` has ``lights``, ``camera`` and ``sim`` (a simulated rig or None), as capture's.
    """
    from rig.keepalive import LightHold

    results = []
    for light in lights:
        if devices.sim is not None:
            devices.sim.before_frame(f"preview_{light:03d}", "object")
        devices.lights.on(light)
        with LightHold(devices.lights, light, 60.0) as hold:
            image = devices.camera.capture()
        devices.lights.off()
        if hold.problem():
            raise PreviewError(f"preview of light {light}: {hold.problem()}")
        stats = analyse_raw(image.data, shutter=shutter, light=light)
        if png_folder is not None:
            stats.png = write_png(f"{png_folder}/preview_light_{light:03d}.png", image.data)
        results.append(stats)
    return results
