"""The normals stage's stack read: frames read by threads straight into the stack give the same
bits as reading them one after another (the stack, the saturation masks, the colour sums, the
normals)."""

import numpy as np
import pytest

from pipeline.decode import decode_session
from pipeline.core.errors import StageError
from pipeline.core.imageio import read_image, write_image, write_mask
from pipeline.importers import import_images
from pipeline.core.paths import NORMALS
from pipeline.photometric import normals_session
from pipeline.photometric import stage as stage_module
from pipeline.photometric.stage import ChannelSums, begin_normals, load_object_stack
from tests.pipeline.tiny_session import lights, sphere


def serial_stack(session, frames, lights_set, channels):
    """The stack as the stage read it before the threaded reader: frame by frame, read_image,
    ``linear / gain``, the channel mean, ``np.stack``."""
    images, valid = [], []
    for frame in frames:
        linear = read_image(session.linear_path(frame))
        gain = lights_set.intensities[frame["light"]]
        gain = gain if gain.size == linear.shape[2] else np.full(linear.shape[2], gain.mean())
        scaled = linear / gain.astype(np.float32)
        images.append(scaled.mean(axis=2))
        valid.append(~(read_image(session.saturation_path(frame)) > 0.5).any(axis=2))
        channels.add(scaled, ~valid[-1])
    return np.stack(images), np.stack(valid)


@pytest.fixture
def rgb_session(tmp_path):
    """A glossy RGB hemisphere under 8 lights with per-channel intensities and clipped highlights."""
    normals, mask = sphere(48)
    dirs = lights()
    rng = np.random.default_rng(0)
    colour = np.array([0.9, 0.6, 0.4])
    src = tmp_path / "src"
    src.mkdir()
    for k, light in enumerate(dirs):
        shade = np.clip(normals @ light, 0, None) * mask
        half = (light + [0, 0, 1]) / np.linalg.norm(light + [0, 0, 1])
        gloss = 1.5 * np.clip(normals @ half, 0, None) ** 40 * mask
        frame = shade[..., None] * colour + gloss[..., None] + rng.uniform(0, 0.01, mask.shape + (3,))
        write_image(src / f"img{k + 1}.png", np.clip(frame, 0, 1))
    (src / "lights.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in dirs))
    (src / "intensities.txt").write_text("".join(f"{1 + 0.1 * k} {0.9 + 0.05 * k} {1.2}\n" for k in range(8)))
    write_mask(src / "mask.png", mask)
    session = import_images(tmp_path / "s", str(src / "img*.png"), mask=src / "mask.png",
                            lights=src / "lights.txt", intensities=src / "intensities.txt")
    decode_session(session)
    return session


@pytest.mark.parametrize("workers", [1, 3, 8])
def test_threaded_stack_is_bit_identical_to_the_serial_read(rgb_session, workers):
    run = begin_normals(rgb_session, force=True)
    expected_sums, sums = ChannelSums(), ChannelSums()
    expected = serial_stack(rgb_session, run.frames, run.lights, expected_sums)
    assert (~expected[1]).any(), "the scene must clip somewhere"
    images, valid = load_object_stack(rgb_session, run.frames, run.lights, sums, workers=workers)
    assert images.dtype == np.float32 and images.shape == expected[0].shape
    assert np.array_equal(images.view(np.uint32), expected[0].view(np.uint32))
    assert np.array_equal(valid, expected[1])
    assert np.array_equal(sums.sums.view(np.uint32), expected_sums.sums.view(np.uint32))


def test_stack_fills_given_arrays(rgb_session, tmp_path):
    run = begin_normals(rgb_session, force=True)
    expected = serial_stack(rgb_session, run.frames, run.lights, ChannelSums())
    images = np.lib.format.open_memmap(tmp_path / "stack.npy", "w+", np.float32, expected[0].shape)
    valid = np.lib.format.open_memmap(tmp_path / "valid.npy", "w+", bool, expected[0].shape)
    got = load_object_stack(rgb_session, run.frames, run.lights, out=(images, valid), workers=2)
    assert got[0] is images and np.array_equal(np.asarray(images), expected[0])
    assert np.array_equal(np.asarray(valid), expected[1])


def test_normals_are_identical_whatever_the_read_threads(rgb_session, monkeypatch):
    outputs = []
    for workers in (1, 4):
        monkeypatch.setattr(stage_module, "read_workers", lambda workers=workers: workers)
        normals_session(rgb_session, method="lambert", force=True, show_progress=False)
        outputs.append(rgb_session.path(NORMALS).read_bytes())
    assert outputs[0] == outputs[1]


def test_a_frame_of_another_size_is_refused_by_name(rgb_session):
    run = begin_normals(rgb_session, force=True)
    odd = rgb_session.linear_path(run.frames[5])
    write_image(odd, np.zeros((10, 12, 3), np.float32))
    with pytest.raises(StageError, match=f"{odd.name}: size \\(10, 12\\) differs"):
        load_object_stack(rgb_session, run.frames, run.lights, ChannelSums(), workers=3)


@pytest.mark.parametrize("keep", [[1, 1, 0, 1, 0, 0, 1, 1], [0, 1, 1, 1, 1, 1, 1, 1], [1] * 7 + [0], [1] * 8])
def test_solving_without_frames_sees_their_copy_and_restores_the_stack(keep):
    rng = np.random.default_rng(1)
    images = rng.random((8, 5, 6), np.float32)
    valid = rng.random((8, 5, 6)) > 0.2
    before = images.copy(), valid.copy()
    keep = np.array(keep, bool)
    seen = stage_module.solve_without(images, valid, keep, lambda i, v: (i.copy(), v.copy()))
    assert np.array_equal(seen[0], before[0][keep]) and np.array_equal(seen[1], before[1][keep])
    assert np.array_equal(images, before[0]) and np.array_equal(valid, before[1])
    with pytest.raises(ZeroDivisionError):
        stage_module.solve_without(images, valid, keep, lambda i, v: 1 / 0)
    assert np.array_equal(images, before[0]) and np.array_equal(valid, before[1])


def test_normals_without_frames_are_those_of_the_copied_stack(rgb_session):
    from pipeline.photometric import estimate_normals

    run = begin_normals(rgb_session, force=True)
    images, valid = load_object_stack(rgb_session, run.frames, run.lights)
    lights_used, mask = run.solver_lights(images.shape[1:]), images.max(axis=0) > 0.05
    keep = np.array([1, 1, 0, 1, 1, 1, 0, 1], bool)
    expected = estimate_normals(images[keep], lights_used[keep], mask, valid=valid[keep])
    got = stage_module.solve_without(images, valid, keep,
                                     lambda i, v: estimate_normals(i, lights_used[keep], mask, valid=v))
    assert np.array_equal(got.normals, expected.normals) and np.array_equal(got.status, expected.status)


def test_the_record_says_where_the_stage_time_went(rgb_session):
    record = normals_session(rgb_session, method="lambert", force=True, show_progress=False)
    timings = record["timings"]
    assert set(timings) == {"read", "solve", "registration", "prediction", "write", "cpu"}
    assert set(timings["cpu"]) == {"read", "solve", "registration", "prediction", "write"}
    walls = [v for k, v in timings.items() if k != "cpu"]
    assert all(v >= 0 for v in walls + list(timings["cpu"].values()))
    assert sum(walls) <= record["seconds"] + 0.01
