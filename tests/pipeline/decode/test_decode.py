"""pipeline.decode: linear raw decoding, saturation, dark/ambient subtraction, failures, reruns."""

import hashlib

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.decode import decode_frame, decode_session
from pipeline.core.dng import CFA_ORDERS, cfa_indices, write_dng, write_dng_file
from pipeline.core.errors import SessionError, StageError
from pipeline.core.imageio import read_image, read_mask, write_image
from pipeline.core.session import Session

from tests import SHARED_DATA

WHITE = 16383
BLACKS = {"RGGB": (500, 517, 529, 544), "BGGR": (530, 505, 515, 498),
          "GRBG": (512, 600, 480, 505), "GBRG": (497, 523, 541, 509)}
DATA = SHARED_DATA


def mosaic_of(scene, cfa, blacks, white=WHITE):
    """Bayer raw DN of a linear scene (H, W, 3): black + scene * (white - black), per cell."""
    height, width, _ = scene.shape
    colours = np.tile(cfa_indices(cfa), (height // 2, width // 2))
    cell = np.broadcast_to(np.asarray(blacks, float).ravel(), (4,)).reshape(2, 2)
    black = np.tile(cell, (height // 2, width // 2))
    value = np.take_along_axis(scene, colours[:, :, None], axis=2)[:, :, 0]
    return np.clip(np.rint(black + value * (white - black)), 0, white).astype(np.uint16)


def ramp_scene(height=48, width=64, low=-0.01, high=0.95):
    """A planar ramp per channel (different directions and slopes), dipping below black."""
    y, x = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    planes = [low + (high - low) * x, low + (high - low) * (0.7 * y + 0.3 * x),
              low + (high - low) * (1 - x) * 0.8]
    return np.stack(planes, axis=2)


def fit(truth, measured):
    """Slope, intercept and R^2 of measured against truth."""
    slope, intercept = np.polyfit(truth.ravel(), measured.ravel(), 1)
    residual = measured.ravel() - (slope * truth.ravel() + intercept)
    r2 = 1 - residual.var() / measured.ravel().var()
    return slope, intercept, r2


def assert_linear(truth, measured):
    for channel in range(3):
        slope, intercept, r2 = fit(truth[..., channel], measured[..., channel])
        assert abs(slope - 1) < 1e-3, (channel, slope)
        assert abs(intercept) < 1e-3, (channel, intercept)
        assert r2 > 0.99999, (channel, r2)


@pytest.mark.parametrize("cfa", CFA_ORDERS)
def test_mosaic_path_is_linear_in_every_cfa_order(tmp_path, cfa):
    scene = ramp_scene()
    path = tmp_path / "ramp.dng"
    write_dng_file(path, mosaic_of(scene, cfa, BLACKS[cfa]), cfa=cfa, black_level=BLACKS[cfa])
    linear, saturated, info = decode_frame(path)
    assert linear.dtype == np.float32 and linear.shape == scene.shape
    assert info["cfa"] == cfa and info["black"] == list(BLACKS[cfa]) and info["white"] == WHITE
    # bilinear interpolation of a planar ramp is exact away from the border
    assert_linear(scene[2:-2, 2:-2], linear[2:-2, 2:-2])
    assert linear.min() < -0.005, "sub-black values must stay negative (unbiased)"
    assert not saturated.any()


@pytest.mark.parametrize("cfa", CFA_ORDERS)
def test_binned_mosaic_is_linear_and_half_size(tmp_path, cfa):
    scene = np.repeat(np.repeat(ramp_scene(24, 32), 2, axis=0), 2, axis=1)  # flat 2x2 cells
    path = tmp_path / "ramp.dng"
    write_dng_file(path, mosaic_of(scene, cfa, BLACKS[cfa]), cfa=cfa, black_level=BLACKS[cfa])
    linear, saturated, _ = decode_frame(path, binning=2)
    assert linear.shape == (24, 32, 3) and saturated.shape == (24, 32)
    assert_linear(scene[::2, ::2], linear)


@pytest.mark.parametrize("binning", [1, 2])
@pytest.mark.parametrize("cfa", CFA_ORDERS)
def test_postprocess_path_is_linear(tmp_path, cfa, binning):
    blacks = np.array(BLACKS[cfa], float)
    greens = cfa_indices(cfa).ravel() == 1
    blacks[greens] = blacks[greens].mean()  # LibRaw scales both greens alike
    # flat 8x8 patches: AHD demosaicing reaches a few pixels, so only patch centres are exact
    scene = np.repeat(np.repeat(ramp_scene(8, 10, low=0.02), 8, axis=0), 8, axis=1)
    path = tmp_path / "ramp.dng"
    write_dng_file(path, mosaic_of(scene, cfa, blacks), cfa=cfa, black_level=blacks)
    linear, _, _ = decode_frame(path, method="postprocess", binning=binning)
    step = 8 // binning
    assert linear.shape == (64 // binning, 80 // binning, 3)
    centres = (slice(step // 2, None, step), slice(step // 2, None, step))
    assert_linear(scene[4::8, 4::8], linear[centres])


def test_grey_is_the_mean_of_rgb(tmp_path):
    scene = ramp_scene()
    path = tmp_path / "ramp.dng"
    write_dng_file(path, mosaic_of(scene, "RGGB", 512), black_level=512)
    rgb, _, _ = decode_frame(path)
    grey, _, _ = decode_frame(path, channels="grey")
    assert grey.shape == rgb.shape[:2] + (1,)
    assert np.allclose(grey[..., 0], rgb.mean(axis=2), atol=1e-6)


@pytest.mark.parametrize("method, binning", [("mosaic", 1), ("mosaic", 2), ("postprocess", 1)])
def test_saturated_photosites_are_flagged(tmp_path, method, binning):
    scene = np.full((48, 64, 3), 0.3)
    raw = mosaic_of(scene, "GRBG", 512)
    raw[20, 30] = WHITE          # one clipped photosite
    raw[40, 10] = WHITE + 100    # above the white level also counts
    path = tmp_path / "sat.dng"
    write_dng_file(path, raw, cfa="GRBG", black_level=512)
    _, saturated, _ = decode_frame(path, method=method, binning=binning)
    if binning == 2:
        assert saturated[10, 15] and saturated[20, 5] and saturated.sum() == 2
    else:
        assert saturated[20, 30] and saturated[40, 10]
        assert saturated[19:22, 29:32].all(), "neighbours interpolated from it are invalid too"
        assert not saturated[:15].any() and not saturated[:, 40:].any()


# ---------------------------------------------------------------------- sessions
def flat_dng(value, blacks=(512, 520, 505, 530), shape=(32, 48), cfa="RGGB", noise=None):
    scene = np.full(shape + (3,), value, float)
    raw = mosaic_of(scene, cfa, blacks).astype(np.int32)
    if noise is not None:
        raw += noise
    return write_dng(np.clip(raw, 0, WHITE).astype(np.uint16), cfa=cfa, black_level=blacks)


def lit_session(tmp_path, *, dark=None, ambient=None, lights=3):
    session = Session.create(tmp_path / "session")
    if dark is not None:
        session.add_frame("dark", flat_dng(dark))
    if ambient is not None:
        session.add_frame("ambient", flat_dng(ambient))
    for light in range(lights):
        session.add_frame("object", flat_dng(0.2 + 0.1 * light + (ambient or dark or 0)), light=light)
    return session


def raw_hashes(session):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in (session.root / "raw").iterdir()}


def test_session_writes_contract_outputs(tmp_path):
    session = lit_session(tmp_path)
    record = decode_session(session, jobs=1, progress=False)
    assert record["status"] == "ok" and record["failed"] == {}
    assert record["params"] == {"method": "mosaic", "channels": "rgb", "binning": 1, "gamma": "auto",
                                "compression": "auto", "half": False}
    for frame in session.frames():
        linear = read_image(session.linear_path(frame))
        assert linear.shape == (32, 48, 3)
        assert np.allclose(linear, 0.2 + 0.1 * frame["light"], atol=1e-4)
        assert not read_mask(session.saturation_path(frame)).any()
        assert session.rel(session.linear_path(frame)) in record["outputs"]
    assert set(record["inputs"]) == {f["file"] for f in session.frames()} | {"session.yaml#decode"}


def test_dark_frame_is_subtracted_from_lit_frames(tmp_path):
    session = lit_session(tmp_path, dark=0.05)
    record = decode_session(session, jobs=1, progress=False)
    assert record["subtracted"] == {"kind": "dark", "frames": ["dark_000"],
                                    "by_kind": {"object": {"kind": "dark", "frames": ["dark_000"]}}}
    assert np.allclose(read_image(session.linear_path("dark_000")), 0.05, atol=1e-4)
    for light in range(3):
        assert np.allclose(read_image(session.linear_path(f"object_{light:03d}")), 0.2 + 0.1 * light,
                           atol=1e-4)


def test_a_reshot_dark_frame_is_subtracted_anew(tmp_path):
    """The dark frame shot again (a new raw file in the manifest): the lit frames it is
    subtracted from are decoded again, not kept with the old one's subtracted."""
    session = lit_session(tmp_path, dark=0.05)
    decode_session(session, jobs=1, progress=False)
    session.path("raw/dark_again.dng").write_bytes(flat_dng(0.07))
    dark = session.frame("dark_000")
    dark.update(file="raw/dark_again.dng",
                sha256=hashlib.sha256(session.path("raw/dark_again.dng").read_bytes()).hexdigest())
    session.save()
    decode_session(session, jobs=1, progress=False)
    assert np.allclose(read_image(session.linear_path("object_001")), 0.3 - 0.02, atol=1e-4)


def test_ambient_is_preferred_to_dark(tmp_path):
    session = lit_session(tmp_path, dark=0.01, ambient=0.08)
    record = decode_session(session, jobs=1, progress=False)
    assert record["subtracted"]["kind"] == "ambient" and record["subtracted"]["frames"] == ["ambient_000"]
    assert np.allclose(read_image(session.linear_path("object_002")), 0.4, atol=1e-4)


def test_ambient_frames_apply_only_to_the_kinds_they_were_shot_for(tmp_path):
    """A capture's ambient frame is shot with the object in view; the sphere frames, shot in
    another scene, get the dark frame instead."""
    session = Session.create(tmp_path / "session")
    session.add_frame("dark", flat_dng(0.01))
    session.add_frame("ambient", flat_dng(0.08), applies_to=["object"])
    session.add_frame("object", flat_dng(0.38), light=0)
    session.add_frame("sphere", flat_dng(0.31), light=0)
    record = decode_session(session, jobs=1, progress=False)
    assert record["subtracted"]["by_kind"] == {"object": {"kind": "ambient", "frames": ["ambient_000"]},
                                               "sphere": {"kind": "dark", "frames": ["dark_000"]}}
    assert np.allclose(read_image(session.linear_path("object_000")), 0.30, atol=1e-4)
    assert np.allclose(read_image(session.linear_path("sphere_000")), 0.30, atol=1e-4)
    again = decode_session(session, jobs=1, progress=False, force=False)
    assert again["subtracted"] == record["subtracted"]


def test_noisy_dark_keeps_unbiased_negative_values(tmp_path):
    rng = np.random.default_rng(3)
    session = Session.create(tmp_path / "session")
    session.add_frame("dark", flat_dng(0.0, noise=rng.normal(0, 8, (32, 48)).round().astype(int)))
    decode_session(session, jobs=1, progress=False)
    dark = read_image(session.linear_path("dark_000"))
    assert dark.min() < 0 and abs(dark.mean()) < 2e-4


@pytest.mark.parametrize("damage", ["truncated", "corrupt", "unsupported", "missing"])
def test_bad_frame_fails_alone_and_rerun_decodes_only_it(tmp_path, damage):
    session = lit_session(tmp_path, lights=3)
    good = flat_dng(0.3)
    bad = {"truncated": good[: len(good) // 2], "corrupt": b"\x00" * 64 + good[64:200],
           "unsupported": b"not a raw file at all\n" * 20, "missing": good}[damage]
    frame = session.add_frame("object", bad, light=3, suffix=".nef")
    raw_file = session.path(frame["file"])
    if damage == "missing":
        raw_file.unlink()
    before = raw_hashes(session)
    record = decode_session(session, jobs=1, progress=False)
    assert record["status"] == "partial"
    assert list(record["failed"]) == ["object_003"]
    assert "object_003" in record["failed"]["object_003"]
    assert not session.linear_path("object_003").exists()
    assert Session.open(session.root).stage("decode")["failed"] == record["failed"]
    assert raw_hashes(session) == before
    if damage != "missing":
        return
    raw_file.write_bytes(good)  # the file comes back (e.g. a remounted disk)
    stamps = {f["id"]: session.linear_path(f).stat().st_mtime_ns for f in session.frames()[:3]}
    record = decode_session(session, jobs=1, progress=False)
    assert record["status"] == "ok" and session.linear_path("object_003").is_file()
    assert stamps == {i: session.linear_path(i).stat().st_mtime_ns for i in stamps}


def test_failed_frame_reported_by_cli_with_exit_1(tmp_path, capsys):
    session = lit_session(tmp_path, lights=1)
    session.add_frame("object", b"garbage" * 50, light=1)
    assert main(["decode", str(session.root), "--jobs", "1"]) == 1
    assert "object_001" in capsys.readouterr().err


def test_different_sizes_are_a_clear_error(tmp_path):
    session = lit_session(tmp_path, lights=1)
    session.add_frame("object", flat_dng(0.3, shape=(40, 48)), light=1)
    with pytest.raises(StageError, match="differ in size"):
        decode_session(session, jobs=1, progress=False)
    assert not any((session.root / "linear").iterdir())


def test_raw_file_changed_after_capture_stops(tmp_path):
    session = lit_session(tmp_path, lights=2)
    path = session.path(session.frame("object_001")["file"])
    path.write_bytes(flat_dng(0.9))
    with pytest.raises(SessionError, match="object_001"):
        decode_session(session, jobs=1, progress=False)


def test_current_stage_is_skipped_and_force_redoes(tmp_path):
    session = lit_session(tmp_path, lights=2)
    first = decode_session(session, jobs=1, progress=False)
    stamp = session.linear_path("object_000").stat().st_mtime_ns
    again = decode_session(session, jobs=1, progress=False)
    assert again["finished"] == first["finished"]
    assert session.linear_path("object_000").stat().st_mtime_ns == stamp
    other = decode_session(session, jobs=1, progress=False, binning=2)
    assert other["params"]["binning"] == 2
    assert read_image(session.linear_path("object_000")).shape == (16, 24, 3)
    decode_session(session, jobs=1, progress=False, binning=2, force=True)
    assert session.linear_path("object_000").stat().st_mtime_ns != stamp


def test_process_pool_matches_in_process(tmp_path):
    session = lit_session(tmp_path, dark=0.02, lights=3)
    decode_session(session, jobs=1, progress=False)
    serial = [read_image(session.linear_path(f)) for f in session.frames()]
    record = decode_session(session, jobs=2, force=True, progress=False)
    assert record["status"] == "ok"
    for frame, expected in zip(session.frames(), serial):
        assert np.array_equal(read_image(session.linear_path(frame)), expected)


# ---------------------------------------------------------------------- image pass-through
def test_8bit_png_gets_inverse_gamma_and_is_flagged_not_raw(tmp_path):
    codes = np.array([[0, 10, 128, 255]] * 24, np.uint8).repeat(6, axis=1)
    source = tmp_path / "photo.png"
    write_image(source, np.repeat(codes[:, :, None], 3, axis=2), bits=8)
    session = Session.create(tmp_path / "session")
    session.add_frame("object", source=source, light=0)
    record = decode_session(session, jobs=1, progress=False)
    assert record["frames_not_raw"] == ["object_000"]
    linear = read_image(session.linear_path("object_000"))
    srgb = np.where(codes / 255 <= 0.04045, codes / 255 / 12.92, ((codes / 255 + 0.055) / 1.055) ** 2.4)
    assert np.allclose(linear[..., 1], srgb, atol=1e-6)
    assert np.array_equal(read_mask(session.saturation_path("object_000")), codes == 255)
    powered, _, info = decode_frame(source, gamma=2.2)
    assert np.allclose(powered[..., 0], (codes / 255) ** 2.2, atol=1e-6) and info["raw"] is False


def test_16bit_png_passes_through_linear(tmp_path):
    values = np.random.default_rng(0).integers(0, 65536, (24, 30, 3)).astype(np.uint16)
    values[3, 4, 2] = 65535
    source = tmp_path / "frame.png"
    write_image(source, values)
    linear, saturated, info = decode_frame(source)
    assert info["raw"] is False and info["bits"] == 16
    assert np.allclose(linear, values / 65535.0, atol=1e-7)
    assert np.array_equal(saturated, (values == 65535).any(axis=2))


def test_diligent_frames_decode_as_linear(tmp_path):
    folder = DATA / "diligent" / "ballPNG"
    if not folder.is_dir():
        pytest.skip("shared DiLiGenT data not available")
    session = Session.create(tmp_path / "session")
    sources = sorted(folder.glob("0*.png"))[:2]
    for light, source in enumerate(sources):
        session.add_frame("object", source=source, light=light)
    record = decode_session(session, jobs=1, progress=False)
    assert record["status"] == "ok" and len(record["frames_not_raw"]) == 2
    assert np.allclose(read_image(session.linear_path("object_001")), read_image(sources[1]), atol=1e-7)


# ---------------------------------------------------------------------- more session cases
def test_saturation_is_judged_before_subtraction(tmp_path):
    session = Session.create(tmp_path / "session")
    session.add_frame("ambient", flat_dng(0.1))
    raw = mosaic_of(np.full((32, 48, 3), 0.5), "RGGB", (512, 520, 505, 530))
    raw[10, 10] = WHITE
    session.add_frame("object", write_dng(raw, black_level=(512, 520, 505, 530)), light=0)
    decode_session(session, jobs=1, progress=False)
    linear = read_image(session.linear_path("object_000"))
    saturated = read_mask(session.saturation_path("object_000"))
    assert linear[10, 10, 0] < 0.95, "after subtraction the clipped value looks valid..."
    assert saturated[10, 10] and saturated.sum() == 9, "...so it must be flagged from the raw value"


def test_mean_of_several_ambient_frames(tmp_path):
    session = Session.create(tmp_path / "session")
    session.add_frame("ambient", flat_dng(0.04))
    session.add_frame("ambient", flat_dng(0.08))
    session.add_frame("object", flat_dng(0.36), light=0)
    record = decode_session(session, jobs=1, progress=False, channels="grey", binning=2)
    assert record["subtracted"]["frames"] == ["ambient_000", "ambient_001"]
    linear = read_image(session.linear_path("object_000"))
    assert linear.shape == (16, 24, 1) and np.allclose(linear, 0.30, atol=1e-4)


def test_pool_reports_a_bad_frame_and_decodes_the_rest(tmp_path):
    session = lit_session(tmp_path, lights=3)
    session.add_frame("object", flat_dng(0.3)[:3000], light=3)
    record = decode_session(session, jobs=2, progress=False)
    assert record["status"] == "partial" and list(record["failed"]) == ["object_003"]
    assert all(session.linear_path(f"object_{i:03d}").is_file() for i in range(3))


def test_cli_decodes_then_reports_up_to_date(tmp_path, capsys):
    session = lit_session(tmp_path, lights=2)
    assert main(["decode", str(session.root), "--jobs", "1", "--grey", "--bin", "2"]) == 0
    assert "2 frames decoded" in capsys.readouterr().out
    assert read_image(session.linear_path("object_001")).shape == (16, 24, 1)
    assert main(["decode", str(session.root), "--jobs", "1", "--grey", "--bin", "2"]) == 0
    assert "up to date" in capsys.readouterr().out
    assert main(["decode", str(tmp_path / "nowhere")]) == 1
    assert "nowhere" in capsys.readouterr().err
