"""The normals stage's files: RGB albedo from RGB frames, named normal channels, one status
palette, the per-pixel observation counts."""

import numpy as np
import OpenImageIO as oiio
import pytest

from pipeline.core.imageio import read_image, write_image, write_mask
from pipeline.importers import import_images
from pipeline.core.paths import ALBEDO, NORMALS, OBSERVATIONS
from pipeline.photometric import STATUS, STATUS_NAMES, normals_session
from pipeline.photometric.methods import STATUS_PALETTE
from pipeline.photometric.stage import STATUS_COLOURS
from tests.pipeline.tiny_session import lights, sphere

#: colour of the left and right halves of the object (linear RGB reflectance)
LEFT, RIGHT = np.array([0.8, 0.4, 0.2]), np.array([0.2, 0.5, 0.7])


def colour_session(tmp_path, grey=False):
    """A Lambertian hemisphere, left half orange, right half blue (or grey frames)."""
    normals, mask = sphere()
    dirs = lights()
    colour = np.broadcast_to(np.where((np.arange(mask.shape[1]) < mask.shape[1] // 2)[:, None], LEFT, RIGHT),
                             mask.shape + (3,))
    src = tmp_path / "src"
    src.mkdir()
    for k, l in enumerate(dirs):
        shading = np.clip(normals @ l, 0, None) * mask
        frame = shading[..., None] * (colour.mean(axis=2, keepdims=True) if grey else colour)
        write_image(src / f"img{k + 1}.png", np.repeat(frame, 3, axis=2) if grey else frame)
    (src / "lights.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in dirs))
    write_mask(src / "mask.png", mask)
    session = import_images(tmp_path / "s", str(src / "img*.png"), mask=src / "mask.png",
                            lights=src / "lights.txt")
    from pipeline.decode import decode_session

    decode_session(session)
    return session, mask, colour


def test_albedo_is_rgb_for_rgb_frames_with_the_grey_albedo_as_channel_mean(tmp_path):
    session, mask, colour = colour_session(tmp_path)
    normals_session(session, method="lambert", show_progress=False)
    albedo = read_image(session.path(ALBEDO))
    assert albedo.shape[2] == 3
    inside = mask & (np.abs(np.arange(mask.shape[1]) - mask.shape[1] / 2 + 0.5) > 2)[None, :]
    ratio = albedo[inside] / albedo[inside].mean(axis=1, keepdims=True)
    expected = colour[inside] / colour[inside].mean(axis=1, keepdims=True)
    # the frames are 16-bit PNGs: quantisation and the half-tone edge of the mask are all
    np.testing.assert_allclose(ratio, expected, atol=0.02)


def test_albedo_stays_one_channel_for_grey_frames(tmp_path):
    session, mask, _ = colour_session(tmp_path, grey=True)
    normals_session(session, method="lambert", show_progress=False)
    albedo = read_image(session.path(ALBEDO))
    # the frames are RGB files with equal channels: the ratio is 1 and the channels agree
    assert albedo.shape[2] in (1, 3)
    np.testing.assert_allclose(albedo[mask].max(axis=1), albedo[mask].min(axis=1), rtol=1e-3, atol=1e-4)


def test_normal_channels_are_named_and_statuses_share_the_palette(tmp_path):
    session, mask, _ = colour_session(tmp_path)
    normals_session(session, method="lambert", show_progress=False)
    spec = oiio.ImageInput.open(str(session.path(NORMALS))).spec()
    assert tuple(spec.channelnames) == ("normal.x", "normal.y", "normal.z")
    normals = read_image(session.path(NORMALS))
    assert normals[mask][:, 2].min() > 0  # z toward the camera still comes third
    vis = read_image(session.path("normals/status_vis.png"))
    ok = np.round(vis[mask] * 255).astype(int)
    assert (ok == STATUS_PALETTE["ok"]).all(axis=1).mean() > 0.9
    used = read_image(session.path(OBSERVATIONS))
    assert used.shape[:2] == mask.shape
    counts = np.round(used[:, :, 0] * 65535).astype(int)
    assert counts[mask].max() <= len(lights()) and counts[mask].min() >= 3 and (counts[~mask] == 0).all()


@pytest.mark.parametrize("code", sorted(STATUS_NAMES))
def test_every_status_has_its_palette_colour_and_unknown_codes_are_grey(code):
    assert tuple(STATUS_COLOURS[code]) == STATUS_PALETTE.get(STATUS_NAMES[code], (128, 128, 128))
    assert tuple(STATUS_COLOURS[max(STATUS.values()) + 1]) == (128, 128, 128)
