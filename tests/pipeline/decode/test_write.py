"""How the decode stage writes its outputs: EXR bytes built in numpy, 1-bit masks, hashes
computed in the workers, split atomic writes committed by the calling process."""

import numpy as np
import pytest

from pipeline.decode import pool as decode_pool
from pipeline.core.atomic import atomic_commit, atomic_write_begin, discard_temp
from pipeline.decode import decode_session
from pipeline.decode.exr import ExrBuffer
from pipeline.decode.raw import decode_raw
from pipeline.core.dng import write_dng, write_dng_file
from pipeline.core.imageio import read_image, read_image_native, read_mask, write_image
from pipeline.core.session import Session, file_sha256


@pytest.mark.parametrize("shape, names", [((5, 7), ("R", "G", "B")), ((3, 1), ("Y",)),
                                          ((1, 6), ("R", "G", "B"))])
def test_exr_buffer_is_the_file_openimageio_writes(tmp_path, shape, names):
    pixels = np.random.default_rng(1).normal(size=shape + (len(names),)).astype(np.float32)
    pixels[0, 0, 0] = -0.0
    exr = ExrBuffer(*shape, names)
    exr.fill(pixels, names)
    ours = tmp_path / "ours.exr"
    ours.write_bytes(exr.data.tobytes())
    assert np.array_equal(read_image(ours), pixels)
    reference = tmp_path / "oiio.exr"
    write_image(reference, pixels, compression="none")
    # Same bytes as before the change: hashes of earlier records stay valid.
    assert ours.read_bytes() == reference.read_bytes()


def test_exr_buffer_planes_are_aligned_views_of_the_file(tmp_path):
    exr = ExrBuffer(4, 9, ("R", "G", "B"))
    for name, plane in exr.planes.items():
        assert plane.shape == (4, 9) and plane.dtype == np.float32 and plane.flags.aligned
        assert np.shares_memory(plane, exr.data)
    exr.planes["G"][2, 3] = 7.5
    path = tmp_path / "one.exr"
    path.write_bytes(exr.data.tobytes())
    image = read_image(path)
    assert image[2, 3, 1] == 7.5 and np.count_nonzero(image) == 1


def test_demosaic_into_planes_equals_the_array_path(tmp_path):
    rng = np.random.default_rng(2)
    raw = rng.integers(400, 16383, (24, 30)).astype(np.uint16)
    raw[5, 5] = 16383
    path = tmp_path / "frame.dng"
    write_dng_file(path, raw, cfa="GBRG", black_level=(500, 510, 490, 505))
    rgb, saturated, info = decode_raw(path)
    exr = ExrBuffer(24, 30, ("R", "G", "B"))
    scratch = {}
    for _ in range(2):  # the second call reuses the scratch arrays of the first
        planes, flags, same = decode_raw(path, out=[exr.planes[c] for c in "RGB"], scratch=scratch)
        assert np.array_equal(np.stack(planes, axis=2), rgb)
        assert np.array_equal(flags, saturated) and same == info
    assert set(scratch) == {"linear", "sparse"}
    with pytest.raises(ValueError, match="mosaic path at full size"):
        decode_raw(path, binning=2, out=planes)


def test_mask_is_one_bit_and_reads_back_as_0_255(tmp_path):
    mask = np.random.default_rng(3).random((37, 53)) > 0.8
    path = tmp_path / "sat.png"
    digest = decode_pool.write_saturation(path, mask)
    assert digest == file_sha256(path)
    assert path.read_bytes()[24] == 1, "PNG bit depth (IHDR) should be 1"
    assert np.array_equal(read_mask(path), mask)
    assert set(np.unique(read_image_native(path))) <= {0, 255}


def test_split_atomic_write(tmp_path):
    target = tmp_path / "sub" / "out.bin"
    target.parent.mkdir()
    target.write_bytes(b"old")
    tmp = atomic_write_begin(target, b"new bytes")
    assert tmp.parent == target.parent and tmp.read_bytes() == b"new bytes"
    assert target.read_bytes() == b"old", "nothing replaced before the commit"
    atomic_commit(tmp, target)
    assert target.read_bytes() == b"new bytes" and not tmp.exists()
    dropped = atomic_write_begin(target, b"never")
    discard_temp(dropped)
    assert not dropped.exists() and target.read_bytes() == b"new bytes"
    with pytest.raises(OSError):
        atomic_commit(tmp_path / "missing.tmp", target)
    assert target.read_bytes() == b"new bytes"


def _task(tmp_path, source, frame_id="f"):
    return {"id": frame_id, "source": str(source), "linear": str(tmp_path / f"{frame_id}.exr"),
            "saturation": str(tmp_path / f"{frame_id}_sat.png"), "size": (24, 30),
            "options": {"method": "mosaic", "channels": "rgb", "binning": 1, "gamma": "srgb"},
            "reference": None}


def test_uncommitted_task_leaves_only_temporary_files(tmp_path):
    source = tmp_path / "frame.dng"
    write_dng_file(source, np.full((24, 30), 3000, np.uint16), black_level=512)
    task = _task(tmp_path, source)
    frame_id, info, error, hashes, temps = decode_pool.decode_task(task, commit=False)
    assert error is None and info["raw"]
    assert set(temps) == set(hashes) == {task["linear"], task["saturation"]}
    assert not any((tmp_path / f"f{suffix}").exists() for suffix in (".exr", "_sat.png"))
    for path, tmp in temps.items():
        assert file_sha256(tmp) == hashes[path]
        atomic_commit(tmp, path)
        assert file_sha256(path) == hashes[path]
    decode_pool.release_workspace()


def flat_session(tmp_path, lights=3, dark=True):
    session = Session.create(tmp_path / "session")
    if dark:
        session.add_frame("dark", write_dng(np.full((24, 30), 520, np.uint16), black_level=512))
    for light in range(lights):
        session.add_frame("object", write_dng(np.full((24, 30), 2000 + 500 * light, np.uint16),
                                              black_level=512), light=light)
    return session


@pytest.mark.parametrize("jobs", [1, 2])
def test_recorded_hashes_are_the_files_hashes(tmp_path, jobs):
    session = flat_session(tmp_path)
    record = decode_session(session, jobs=jobs, progress=False)
    assert record["status"] == "ok" and len(record["outputs"]) == 8
    assert record["outputs"] == {rel: file_sha256(session.path(rel)) for rel in record["outputs"]}
    assert not list((session.root / "linear").glob(".*tmp*")), "no temporary file left"
    # one object frame goes missing: the rerun decodes it alone and keeps the other hashes
    session.linear_path("object_001").unlink()
    again = decode_session(session, jobs=jobs, progress=False)
    assert again["outputs"] == record["outputs"]


@pytest.mark.parametrize("jobs", [1, 2])
def test_failed_commit_fails_its_frame_only(tmp_path, monkeypatch, jobs):
    session = flat_session(tmp_path, dark=False)
    real = decode_pool.atomic_commit

    def commit(tmp, path):
        if "object_001.exr" in str(path):
            discard_temp(tmp)
            raise OSError(28, "No space left on device")
        real(tmp, path)

    monkeypatch.setattr(decode_pool, "atomic_commit", commit)
    record = decode_session(session, jobs=jobs, progress=False)
    assert record["status"] == "partial" and list(record["failed"]) == ["object_001"]
    assert "No space left" in record["failed"]["object_001"]
    assert "object_001" in record["failed"]["object_001"]
    assert not session.linear_path("object_001").exists()
    assert not session.saturation_path("object_001").exists(), "its mask is not committed either"
    assert not list((session.root / "linear").glob(".*tmp*"))
    assert session.linear_path("object_002").is_file()


def test_rerun_sweeps_temporaries_an_interrupted_run_left(tmp_path):
    session = flat_session(tmp_path, lights=2)
    record = decode_session(session, jobs=1, progress=False)
    linear = session.root / "linear"
    # as if killed between a worker's write and its commit
    stale = [linear / ".object_001.k3j2.tmp.exr", linear / ".object_001_sat.x9.tmp.png"]
    for path in stale:
        path.write_bytes(b"half written")
    session.linear_path("object_001").unlink()
    # the next writer sweeps them when it takes the session's lock, before anything else
    writer = Session.open(session.root, writer="decode")
    assert not any(path.exists() for path in stale)
    assert writer.swept == {"linear": (2, 2 * len(b"half written"))}
    again = decode_session(writer, jobs=1, progress=False)
    assert again["outputs"] == record["outputs"]
    assert session.linear_path("object_000").is_file()


def _filled(shape, names, rng, compressible):
    exr = ExrBuffer(*shape, names)
    pixels = rng.normal(size=shape + (len(names),)).astype(np.float32)
    if compressible:
        pixels = np.round(pixels * 4) / 4   # few distinct values, as decoded 8/16-bit files have
    exr.fill(pixels, names)
    return exr, pixels


@pytest.mark.parametrize("shape, names", [((37, 23), ("R", "G", "B")), ((16, 5), ("Y",)), ((1, 1), ("R", "G", "B"))])
def test_zip_exr_reads_back_bit_for_bit_in_openimageio(tmp_path, shape, names):
    from pipeline.decode.exr import half_rows, zip_exr

    rng = np.random.default_rng(3)
    for compressible in (True, False):   # blocks that do not shrink are stored raw
        exr, pixels = _filled(shape, names, rng, compressible)
        path = tmp_path / "zip.exr"
        path.write_bytes(zip_exr(exr.rows, shape[1], names))
        assert np.array_equal(read_image(path), pixels)
        path.write_bytes(zip_exr(half_rows(exr), shape[1], names, half=True))
        assert read_image_native(path).dtype == np.float16
        assert np.array_equal(read_image(path), pixels.astype(np.float16).astype(np.float32))


def test_auto_compression_zips_what_shrinks_and_leaves_noise_alone():
    from pipeline.decode.exr import encode_exr

    rng = np.random.default_rng(4)
    smooth, _ = _filled((64, 80), ("R", "G", "B"), rng, compressible=True)
    noise, _ = _filled((64, 80), ("R", "G", "B"), rng, compressible=False)
    data, written = encode_exr(smooth)
    assert written["compression"] == "zip" and written["bytes"] == len(data) < smooth.data.size / 2
    data, written = encode_exr(noise)
    assert written["compression"] == "none" and data is noise.data and written["estimated_ratio"] < 1.8
    _, written = encode_exr(noise, "zip")
    assert written["compression"] == "zip" and "estimated_ratio" not in written
    data, written = encode_exr(noise, "none", half=True)
    assert written == {"compression": "none", "pixels": "half", "bytes": len(data)}


def test_session_linear_files_are_compressed_and_recorded(tmp_path):
    session = Session.create(tmp_path / "s")
    for k in range(3):
        values = np.full((40, 50, 3), 1000 * (k + 1), np.uint16)
        values[10:20, 10:30] = 30000
        path = tmp_path / f"f{k}.png"
        write_image(path, values)
        session.add_frame("object", source=path, light=k)
    record = decode_session(session, jobs=1, progress=False)
    sizes = sum(session.linear_path(f).stat().st_size for f in session.frames())
    assert record["compression"] == {"zip": 3} and record["linear_bytes"] == sizes
    assert sizes < 3 * 40 * 50 * 12 / 4
    for k, frame in enumerate(session.frames()):
        assert record["frames"][frame["id"]]["exr"]["compression"] == "zip"
        assert read_image(session.linear_path(frame))[0, 0, 0] == np.float32(1000 * (k + 1)) * np.float32(1 / 65535)
    record = decode_session(session, jobs=1, progress=False, compression="none", force=True)
    assert record["compression"] == {"none": 3}
    assert sum(session.linear_path(f).stat().st_size for f in session.frames()) > 3 * 40 * 50 * 12


def test_a_record_from_before_compression_keeps_its_outputs(tmp_path):
    """psrig run on a session decoded by an earlier version: the linear files stay byte for byte
    (uncompressed, 16-bit as linear), so nothing after decode is redone."""
    from pipeline.runner import run_stage

    session = Session.create(tmp_path / "s")
    for k in range(2):
        path = tmp_path / f"f{k}.png"
        write_image(path, np.full((20, 30, 3), 5000 * (k + 1), np.uint16))
        session.add_frame("object", source=path, light=k)
    decode_session(session, jobs=1, progress=False, compression="none")
    record = session.stage("decode")
    record["params"] = {"method": "mosaic", "channels": "rgb", "binning": 1, "gamma": "srgb"}  # the old form
    session.save()
    before = dict(record["outputs"])
    run_stage(session, "decode", {}, False, 1)
    after = session.stage("decode")
    assert after["outputs"] == before and after["params"]["compression"] == "none"
    assert after["params"]["gamma"] == "auto"
