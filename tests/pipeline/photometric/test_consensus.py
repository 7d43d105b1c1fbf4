"""The neighbour consensus of the selection's decisions (pipeline.photometric.consensus): the
vote itself, and the same normals from the serial stage and from tiles whose boundary crosses
the object (a tile reads its halo's decisions)."""

from pathlib import Path

import numpy as np

from pipeline.core.imageio import write_image, write_mask
from pipeline.core.session import Session
from pipeline.importers import import_images
from pipeline.photometric import normals_session
from pipeline.photometric import tiles
from pipeline import runner
from pipeline.photometric.consensus import box_sums, consensus_veto, halo_pixels, vote_rounds
from tests.pipeline.tiny_session import sphere

FILES = ("normals/normals.exr", "normals/albedo.exr", "normals/residual.exr", "normals/brdf.exr",
         "normals/status.png", "normals/uncertainty.exr")


def packed(kept):
    """(K, H, W) bool decisions -> (bits (P, B), flat pixels (P,)) over every pixel."""
    k = kept.shape[0]
    return np.packbits(kept.reshape(k, -1).T, axis=1), np.arange(kept[0].size)


def test_box_sums_count_every_window_exactly():
    rng = np.random.default_rng(1)
    stack = rng.integers(0, 2, (3, 7, 9)).astype(np.uint8)
    got = box_sums(stack, 2)
    padded = np.pad(stack.astype(int), ((0, 0), (2, 2), (2, 2)))
    want = sum(padded[:, i:i + 7, j:j + 9] for i in range(5) for j in range(5))
    assert np.array_equal(got, want)


def test_an_observation_most_neighbours_rejected_is_vetoed():
    kept = np.ones((10, 5, 5), bool)
    kept[3] = False
    kept[3, 2, 2] = True            # only the centre keeps light 3: vetoed there
    kept[7, :, :3] = False          # light 7: the left three columns reject it, but for (2, 2)
    kept[7, 2, 2] = True
    bits, pixels = packed(kept)
    veto = consensus_veto(bits, pixels, (5, 5), 10, radius=1, share=0.5, min_neighbours=3)
    vetoed = np.zeros((5, 5, 10), bool)
    vetoed.reshape(25, 10)[veto.pixels] = veto.get(veto.pixels)
    assert vetoed[2, 2, 3] and vetoed[..., 3].sum() == 1
    # 5 of the 8 neighbours of (2, 2) rejected light 7: vetoed; 2 of (2, 3)'s 8 and 2 of (0, 3)'s 5: kept
    assert vetoed[2, 2, 7] and vetoed[..., 7].sum() == 1
    assert veto.observations == int(vetoed.sum())


def test_few_neighbours_do_not_vote_and_a_halo_is_the_ring_around_a_tile():
    kept = np.zeros((8, 3, 3), bool)
    kept[:, 0, 0] = True           # a corner pixel keeps everything; its 2 neighbours reject all
    mask = np.zeros((3, 3), bool)
    mask[0, :2] = mask[1, 0] = True
    bits, _ = packed(kept)
    pixels = np.flatnonzero(mask)
    veto = consensus_veto(bits[pixels], pixels, (3, 3), 8, radius=1, share=0.5, min_neighbours=3)
    assert veto.pixels.size == 0   # two neighbours only: no vote
    mask = np.ones((6, 6), bool)
    mask[0, 0] = False
    own = np.flatnonzero(mask)[:11]   # rows 0-1 (11 object pixels)
    assert set(halo_pixels(mask, own, 1)) == set(range(12, 18))


def glossy_session(folder, name, size=72, count=16):
    """A glossy hemisphere (about 3000 object pixels: two solver chunks, so two tiles) under a
    cone of lights, with ragged cast shadows under a few of them."""
    normals, mask = sphere(size)
    azimuth = np.linspace(0, 2 * np.pi, count, endpoint=False)
    polar = np.radians(np.where(np.arange(count) % 2, 20.0, 35.0))
    dirs = np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], -1)
    src = Path(folder) / f"{name}_src"
    src.mkdir(parents=True)
    half = dirs + [0.0, 0.0, 1.0]
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    rng = np.random.default_rng(3)
    for k, light in enumerate(dirs):
        diffuse = np.clip(normals @ light, 0, None)
        gloss = 0.3 * np.clip(normals @ half[k], 0, None) ** 20 * (diffuse > 0)
        # ragged cast shadows (patches of 2 x 2 pixels) under every third light: dimmed, not black
        patches = np.kron(rng.random((size // 2 + 1, size // 2 + 1)) < 0.5, np.ones((2, 2)))[:size, :size]
        shadow = np.where((k % 3 == 0) & (patches > 0), 0.45, 1.0)
        image = np.clip((0.6 * diffuse * shadow + gloss) * mask, 0, 1)
        write_image(src / f"img{k + 1:02d}.png", np.repeat(image[..., None], 3, axis=2))
    (src / "lights.txt").write_text("".join(f"{x} {y} {z}\n" for x, y, z in dirs))
    write_mask(src / "mask.png", mask)
    return import_images(Path(folder) / name, str(src / "img*.png"), mask=src / "mask.png",
                         lights=src / "lights.txt").root


def test_tiles_that_cut_the_object_vote_as_the_serial_stage(tmp_path):
    reference, tiled = (glossy_session(tmp_path, name) for name in ("a", "b"))
    for root in (reference, tiled):
        runner.run_session(root, stop="calibrate")
    whole = normals_session(Session.open(reference), show_progress=False)
    votes = whole["selection"]["neighbour_consensus"]
    assert votes["observations_vetoed"] > 0 and votes["pixels_refitted"] > 0
    plan = tiles.plan_normals(Session.open(tiled), {"method": None}, tile_pixels=1)
    assert len(plan.tiles) == 2
    tiles.assemble_normals(plan, [tiles.run_tile(plan, tile) for tile in plan.tiles])
    record = Session.open(tiled).stage("normals")
    assert record["selection"]["neighbour_consensus"] == votes
    for name in FILES:
        assert (Path(tiled) / name).read_bytes() == (Path(reference) / name).read_bytes(), name
    off = normals_session(Session.open(reference), force=True, show_progress=False, neighbour_consensus=False)
    assert "neighbour_consensus" not in off["selection"]
    assert off["params"]["neighbour_consensus"] is False


def test_rounds_vote_on_the_last_decisions_and_a_refit_without_a_normal_is_not_taken():
    kept = np.ones((8, 5, 5), bool)
    kept[3] = False
    kept[3, 2, 2] = True                     # light 3: only the centre keeps it
    bits, pixels = packed(kept)
    calls = []

    def refit(veto, take):
        calls.append(veto.pixels.copy())
        new = np.packbits(kept.reshape(8, -1).T[veto.pixels] & ~veto.get(veto.pixels), axis=1)
        return new, np.full(len(veto.pixels), take)

    taken = vote_rounds(bits, pixels, (5, 5), 8, lambda veto: refit(veto, True), rounds=3)
    assert list(taken.pixels) == [12] and taken.get(taken.pixels)[0, 3] and taken.observations == 1
    assert len(calls) == 1                   # the second round finds nothing left to veto
    calls.clear()
    refused = vote_rounds(bits, pixels, (5, 5), 8, lambda veto: refit(veto, False), rounds=3)
    assert refused.pixels.size == 0 and len(calls) == 1   # not taken, and not tried again
