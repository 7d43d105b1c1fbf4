"""The in-memory stage solves on the object's box and writes what it writes on the whole frame."""

import filecmp

import numpy as np
import pytest

from pipeline.core.imageio import write_image, write_mask
from pipeline.core.mapped import anonymous_array
from pipeline.decode import decode_session
from pipeline.importers import import_images
from pipeline.photometric import estimate_normals, normals_session
from pipeline.photometric import object_box as module
from pipeline.photometric.flags import PackedFlags
from pipeline.photometric.object_box import crop_stack, object_box, uncrop_result
from tests.pipeline.tiny_session import lights, sphere


def test_the_box_is_the_mask_widened_within_the_frame():
    mask = np.zeros((200, 300), bool)
    mask[50:60, 10:20] = True
    assert object_box(mask, margin=32) == (slice(18, 92), slice(0, 52))
    mask[190, 290] = True   # the box would be nearly the frame: not worth a copy
    assert object_box(mask, margin=32) is None
    assert object_box(np.zeros((5, 5), bool)) is None


def test_the_cropped_stack_is_every_frame_s_box():
    rng = np.random.default_rng(0)
    images = anonymous_array((6, 40, 50), np.float32)
    images[:] = rng.random(images.shape)
    valid = rng.random(images.shape) > 0.2
    box = (slice(3, 31), slice(7, 40))
    expected = images[(slice(None),) + box].copy(), valid[(slice(None),) + box].copy()
    cropped, flags = crop_stack(images, valid, box)
    assert np.array_equal(cropped, expected[0]) and isinstance(flags, PackedFlags)
    assert np.array_equal(np.asarray(flags), expected[1])


def test_the_result_goes_back_into_the_whole_frame():
    normals, mask = sphere(24)
    dirs = lights(8)
    images = np.stack([np.clip(normals @ light, 0, None) * mask for light in dirs]).astype(np.float32)
    whole = np.zeros((8, 60, 70), np.float32)
    whole[:, 20:44, 30:54] = images
    big_mask = np.zeros((60, 70), bool)
    big_mask[20:44, 30:54] = mask
    expected = estimate_normals(whole, dirs, big_mask, method="lambert")
    box = (slice(10, 50), slice(25, 60))
    got = uncrop_result(estimate_normals(whole[:, box[0], box[1]], dirs, big_mask[box], method="lambert"), box,
                        big_mask)
    for name in ("normals", "status", "albedo", "residual", "used", "lit", "leverage", "uncertainty", "mask"):
        assert np.array_equal(getattr(got, name), getattr(expected, name), equal_nan=name != "mask"), name


@pytest.fixture
def framed_session(tmp_path):
    """A glossy sphere in a quarter of a wider frame, 12 lights, clipped highlights, no mask."""
    normals, mask = sphere(40)
    dirs = lights(12)
    rng = np.random.default_rng(1)
    src = tmp_path / "src"
    src.mkdir()
    for k, light in enumerate(dirs):
        half = (light + [0, 0, 1]) / np.linalg.norm(light + [0, 0, 1])
        shade = np.clip(normals @ light, 0, None) * 0.7 + 1.2 * np.clip(normals @ half, 0, None) ** 30
        frame = rng.uniform(0, 0.004, (90, 110, 3))
        frame[30:70, 55:95] += (shade * mask)[..., None] * [0.9, 0.7, 0.5]
        write_image(src / f"img{k + 1:02d}.png", np.clip(frame, 0, 1))
    (src / "lights.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in dirs))
    session = import_images(tmp_path / "s", str(src / "img*.png"), lights=src / "lights.txt")
    decode_session(session)
    return session


@pytest.mark.parametrize("method", ["lambert", "biquadratic"])
def test_normals_on_the_box_are_those_of_the_whole_frame(framed_session, tmp_path, monkeypatch, method):
    outputs = {}
    for saving in (module.BOX_MIN_SAVING, 2.0):   # 2.0: never crop
        monkeypatch.setattr(module, "BOX_MIN_SAVING", saving)
        cropped = []
        real_crop = module.crop_stack
        monkeypatch.setattr("pipeline.photometric.stage.crop_stack",
                            lambda *a: cropped.append(1) or real_crop(*a))
        record = normals_session(framed_session, method=method, force=True, show_progress=False)
        assert bool(cropped) == (saving < 1) and record["mask"]["source"] == "brightness"
        outputs[saving] = tmp_path / f"out-{saving}"
        framed_session.path("normals").rename(outputs[saving])
    folder, whole = outputs.values()
    assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in whole.iterdir())
    for path in folder.iterdir():
        assert filecmp.cmp(path, whole / path.name, shallow=False), path.name
